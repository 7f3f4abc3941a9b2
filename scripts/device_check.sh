#!/usr/bin/env bash
# GPU check: SALS at the `paper` budget (the paper's 9 x 512 MLP, 100k steps of 10k samples from 10M)
# and at the `cpu` budget on 3 ABC parts of ../shared/data/abc, grid 128, on a CUDA machine; writes
# device_check.md (the two runs side by side with the paper's SALS numbers) into OUT.
#   bash scripts/device_check.sh [OUT]      (OUT default: runs/device-check-<date>; $OUT if set)
# Sized for under 8 minutes on one H200: the 3 paper-budget fits share the GPU (3 process workers),
# then the 3 cpu-budget fits. Set up first with scripts/setup.sh after installing a CUDA torch.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
[ -x "$PY" ] || PY=python3
out="${1:-${OUT:-runs/device-check-$(date +%Y%m%d-%H%M%S)}}"
mkdir -p "$out"
if ! "$PY" -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)"; then
  echo "device_check.sh: no CUDA device (torch.cuda.is_available() is False); this check needs a GPU" >&2
  exit 2
fi
data=../shared/data/abc
[ -d "$data" ] || { echo "device_check.sh: $data not found (../shared beside the checkout)" >&2; exit 2; }
parts="$out/parts.txt"
printf '%s\n' 00000005_d4fe04f0f5f84b52bd4f10e4_trimesh_000 00010218_4769314c71814669ba5d3512_trimesh_013 \
  00992294_c5390f6bb4e80a940dae7c15_trimesh_000 > "$parts"
common=(--dataset abc --data-dir "$data" --list "$parts" --methods sals --grid 128 --quiet
        --cache-dir "$out/cache")
t0=$(date +%s)
"$PY" run_benchmark.py "${common[@]}" --budget paper --executor process --workers 3 --out "$out/paper"
t1=$(date +%s)
"$PY" run_benchmark.py "${common[@]}" --budget cpu --executor local --out "$out/cpu"
t2=$(date +%s)
"$PY" - "$out" "$((t1 - t0))" "$((t2 - t1))" <<'EOF'
import sys
from pathlib import Path

import pandas as pd

out, paper_s, cpu_s = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
rows = []
for budget, wall in (("paper", paper_s), ("cpu", cpu_s)):
    df = pd.read_csv(out / budget / "results.csv")
    ok = df[df["status"] == "ok"]
    rows.append({"budget": budget, "parts ok": f"{len(ok)}/{len(df)}", "CD x1e3 mean": 1e3 * ok["cd"].mean(),
                 "ECD x1e2 median": 1e2 * ok["ecd"].median(), "EF1 mean": ok["ef1"].mean(),
                 "faces mean": ok["n_faces"].mean(), "fit s mean": ok["fit_s"].mean(), "run wall s": int(wall)})
rows.append({"budget": "paper's table (ABC, GPU)", "parts ok": "", "CD x1e3 mean": 4.49, "ECD x1e2 median": 1.97,
             "EF1 mean": 0.601, "faces mean": float("nan"), "fit s mean": float("nan"), "run wall s": ""})
table = pd.DataFrame(rows).to_markdown(index=False, floatfmt=".3g")
text = f"# SALS on a GPU: paper vs cpu budget, 3 ABC parts, grid 128\n\n{table}\n"
(out / "device_check.md").write_text(text)
print(text)
EOF
