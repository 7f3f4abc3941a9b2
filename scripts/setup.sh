#!/usr/bin/env bash
# Set up salsbench in ./.venv on a bare machine (idempotent: re-running only checks).
#   bash scripts/setup.sh          # what run_benchmark.py needs
#   bash scripts/setup.sh --test   # + test tools, Ray (for the executor tests) and headless Chromium
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
want_test=0
for arg in "$@"; do
  case "$arg" in
    --test) want_test=1 ;;
    *) echo "setup.sh: unknown option '$arg' (use --test)" >&2; exit 2 ;;
  esac
done

if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
# torch first and pinned: an unpinned torch would pull a multi-GB CUDA build. 2.13.0 is the CPU
# wheel on these machines; on a CUDA machine install the matching torch yourself before this script.
# torch (and uv) go through pip, which reads this machine's pip configuration (where the CPU wheel
# lies); the rest through uv, which fetches and unpacks in parallel (about 4x pip here), or through
# pip where uv cannot.
if ! .venv/bin/python -c "import torch" >/dev/null 2>&1; then
  .venv/bin/pip install --quiet --no-compile "torch==2.13.0"
fi
extras=""
[ "$want_test" = 1 ] && extras="[test,ray]"
if ! { .venv/bin/pip install --quiet --no-compile uv \
       && .venv/bin/python -m uv pip install --quiet --python .venv/bin/python -e ".${extras}"; }; then
  echo "setup.sh: uv could not install the packages; installing them with pip" >&2
  .venv/bin/pip install --quiet --no-compile -e ".${extras}"
fi
# Byte-code: Python writes each module's .pyc the first time it imports it (only what is imported,
# once). With PYTHONDONTWRITEBYTECODE set it never does, and every process would compile every module
# it imports again: then everything installed is compiled now, on every core.
if [ -n "${PYTHONDONTWRITEBYTECODE:-}" ]; then
  site=$(.venv/bin/python -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
  .venv/bin/python -m compileall -q -j 0 "$site" >/dev/null 2>&1 || true  # a package's Python-2 examples do not compile
fi

if [ "$want_test" = 1 ] && ! command -v chromium >/dev/null 2>&1; then
  # The HTML report is checked in a real headless browser; tests skip (with a reason) without one.
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
      || echo "setup.sh: could not install chromium; the browser test of report.html will be skipped" >&2
  else
    echo "setup.sh: chromium not found; the browser test of report.html will be skipped" >&2
  fi
fi
echo "salsbench: environment ready in .venv"
