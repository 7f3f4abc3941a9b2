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
# pip byte-compiles what it installs in one process; here each install is compiled on every core
# instead (compileall -j 0), torch's while the other packages install: about half the set-up time.
# Files that do not compile (a package's Python-2 examples, say) are left as pip leaves them.
site=$(.venv/bin/python -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
compile_site() { .venv/bin/python -m compileall -q -j 0 "$@" >/dev/null 2>&1 || true; }
if ! .venv/bin/python -c "import torch" >/dev/null 2>&1; then
  .venv/bin/pip install --quiet --no-compile "torch==2.13.0"
fi
compile_site "$site/torch" &
extras=""
[ "$want_test" = 1 ] && extras="[test,ray]"
.venv/bin/pip install --quiet --no-compile -e ".${extras}"
wait
compile_site -x "^$site/torch/" "$site"

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
