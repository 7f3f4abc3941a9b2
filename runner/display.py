"""Progress on the terminal: one tqdm bar over tasks (current stage and loss in its postfix), or,
with ``--quiet``, one line per finished task (CI logs)."""

from __future__ import annotations

import sys
import time


class Display:
    def __init__(self, total: int, quiet: bool, done: int = 0):
        self.quiet = quiet
        self.total = total
        self.count = done
        self.bar = None
        self._last = 0.0
        if not quiet:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=done, unit="task", dynamic_ncols=True, file=sys.stderr,
                            desc="salsbench")

    def stage(self, label: str, stage: str, **info) -> None:
        if self.bar is None:
            return
        now = time.monotonic()
        if now - self._last < 0.3 and stage == "fitting":
            return
        self._last = now
        text = f"{label} {stage}"
        if info.get("loss") is not None:
            text += f" loss={float(info['loss']):.4g}"
        if info.get("step") is not None:
            text += f" step={info['step']}"
        self.bar.set_postfix_str(text, refresh=True)

    def finished(self, result) -> None:
        self.count += 1
        if self.bar is not None:
            self.bar.update(1)
            if not result.ok:
                self.bar.write(f"FAILED {result.spec.label}: {result.error}", file=sys.stderr)
            return
        line = f"[{self.count}/{self.total}] {result.status:6s} {result.spec.label}"
        m = result.metrics
        if result.ok and m.get("scored") is False:
            line += " no GT: no floor" if result.kind == "floor" else f" not scored (no GT) faces={m.get('n_faces', 0):,}"
        elif result.ok and m:
            parts = [f"{k}={m[k]:.4g}" for k in ("cd", "f1_005", "ecd", "ef1") if isinstance(m.get(k), (int, float))]
            line += " " + " ".join(parts)
        line += f" {result.timings.get('total_s', 0.0):.1f}s"
        if result.cache:
            line += f" (cache: {','.join(result.cache)})"
        if result.cache_rejected:
            line += f" ({len(result.cache_rejected)} damaged cache entr{'y' if len(result.cache_rejected) == 1 else 'ies'} recomputed)"
        if not result.ok:
            line += f" -- {result.error}"
        print(line, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
