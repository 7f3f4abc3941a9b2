#!/usr/bin/env bash
# GPU check of the backbone question: sals, sdf and sdf-ndc fitted at the `paper` budget (the paper's
# 9 x 512 Softplus MLP, 100k steps of 10k samples from 10M) on 2 ABC parts of ../shared/data/abc that
# no published network saw (00010218, 00992294), grid 128, on a CUDA machine, then the same rows at the
# `cpu` budget (feature grid) on the CPU cores of the same machine; writes device_check.md (per
# method: the two budgets side by side, and the paper's numbers) into OUT.
#   bash scripts/device_check.sh [OUT]      (OUT default: runs/device-check-<date>; $OUT if set)
#   STEPS=N bash scripts/device_check.sh    (the paper budget shortened to N steps, recorded in the table)
# Sized for under 10 minutes of one H100/H200: the 2 x 2 paper-budget fits share the GPU (4 process
# workers; sdf-ndc extracts the sdf fits), the cpu-budget run goes beside them on the CPU. Set up
# first with scripts/setup.sh after installing a CUDA torch. Exits 2 with one line where there is no GPU.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
[ -x "$PY" ] || PY=python3
out="${1:-${OUT:-runs/device-check-$(date +%Y%m%d-%H%M%S)}}"
if ! "$PY" -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)"; then
  echo "device_check.sh: no CUDA device (torch.cuda.is_available() is False); this check needs a GPU" >&2
  exit 2
fi
data=../shared/data/abc
[ -d "$data" ] || { echo "device_check.sh: $data not found (../shared beside the checkout)" >&2; exit 2; }
mkdir -p "$out"
parts="$out/parts.txt"
printf '%s\n' 00010218_4769314c71814669ba5d3512_trimesh_013 00992294_c5390f6bb4e80a940dae7c15_trimesh_000 > "$parts"
common=(--dataset abc --data-dir "$data" --list "$parts" --methods sals sdf sdf-ndc --grid 128 --quiet --gallery 0)
steps=()
[ -n "${STEPS:-}" ] && steps=(--budget-param "steps=$STEPS")
t0=$(date +%s)
SALSBENCH_DEVICE=cpu "$PY" run_benchmark.py "${common[@]}" --budget cpu --executor process --workers 4 \
  --cache-dir "$out/cache-cpu" --out "$out/cpu" &
cpu_pid=$!
"$PY" run_benchmark.py "${common[@]}" --budget paper "${steps[@]}" --executor process --workers 4 \
  --cache-dir "$out/cache-gpu" --out "$out/paper"
t1=$(date +%s)
wait "$cpu_pid"
"$PY" - "$out" "$((t1 - t0))" "${STEPS:-100000}" <<'EOF'
import sys
from pathlib import Path

import pandas as pd

out, gpu_wall, steps = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
# the paper's table (50 ABC parts, its GPU fits): CD x1e3 (SALS only), ECD x1e2, EF1 (docs/RESULTS.md, section 3)
paper = {"sals": (4.49, 1.970, 0.601), "sdf": (float("nan"), 7.238, 0.167), "sdf-ndc": (float("nan"), 2.501, 0.526)}
rows = []
for budget, label in (("paper", f"paper, {steps:,} steps, GPU"), ("cpu", "cpu (feature grid), CPU")):
    df = pd.read_csv(out / budget / "results.csv")
    for method, g in df.groupby("method", sort=False):
        ok = g[g["status"] == "ok"]
        rows.append({"method": method, "budget": label, "parts ok": f"{len(ok)}/{len(g)}",
                     "CD x1e3 mean": 1e3 * ok["cd"].mean(), "ECD x1e2 median": 1e2 * ok["ecd"].median(),
                     "EF1 mean": ok["ef1"].mean(), "faces mean": ok["n_faces"].mean(), "fit s mean": ok["fit_s"].mean(),
                     "precision": ",".join(sorted(set(ok["precision"].dropna().astype(str))))})
for method, (cd, ecd, ef1) in paper.items():
    rows.append({"method": method, "budget": "paper's table (50 ABC parts, GPU)", "CD x1e3 mean": cd,
                 "ECD x1e2 median": ecd, "EF1 mean": ef1})
table = pd.DataFrame(rows).sort_values("method", kind="stable").to_markdown(index=False, floatfmt=".3g")
text = (f"# sals, sdf, sdf-ndc: the paper budget on a GPU beside the cpu budget, 2 ABC parts, grid 128\n\n"
        f"GPU run wall: {gpu_wall} s\n\n{table}\n")
(out / "device_check.md").write_text(text)
print(text)
EOF
