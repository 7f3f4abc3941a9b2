"""Command line: ``python -m foundation.metrics GT PRED [--points N] [--preset default|ndc|scene]
[--seed S] [--json] [--no-normalize]`` scores one predicted mesh file against a GT mesh file.

The prediction is data: whatever its file holds (no faces, NaN vertices, out-of-range indices,
faces on a line) is scored as :func:`~foundation.metrics.evaluate` scores it (NaN plus flags) and
printed, exit status 0. Exit status 2, with one line on stderr, is for what is not data: bad flags,
a GT that cannot be scored against, a file that is missing or not a readable mesh file.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from foundation.errors import one_line
from foundation.metrics.evaluate import evaluate
from foundation.metrics.presets import PRESETS, MetricPreset
from foundation.serialize import dumps
from datasets.io import MeshError, canonical_transform, read_mesh_arrays, read_mesh_file


def _format_table(result: dict, preset: MetricPreset, frame_note: str) -> str:
    scale = preset.report_scale
    rows = [("CD", "cd"), ("CD gt->pred", "cd_gt_to_pred"), ("CD pred->gt", "cd_pred_to_gt"), ("NC", "nc")]
    rows += [(f"F1@{t:g}", k) for t, k in zip(preset.f1_thresholds, preset.f1_keys)]
    rows += [("distance median", "dist_median"), ("distance p90", "dist_p90"), ("distance p99", "dist_p99"),
             ("Hausdorff", "hausdorff"), ("IoU", "iou"), ("ECD", "ecd"), ("EF1", "ef1")]
    lines = [preset.describe(result['n_points']), f"seed {result['seed']}, n = {result['n_points']:,} points per mesh; {frame_note}", ""]
    for label, key in rows:
        s = scale.get(key, 1.0)
        name = f"{label} (x{s:g})" if s != 1.0 else label
        lines.append(f"  {name:<22} {result[key] * s:.6g}")
    flag = "  (prediction has no edge points" + (": ECD NaN)" if preset.empty_edge_fallback == 0 else f": {preset.empty_edge_fallback} origin points used)")
    lines.append(f"  {'edge points gt/pred':<22} {result['gt_edge_points']:,} / {result['pred_edge_points']:,}" + (flag if result["ecd_flag"] else ""))
    lines.append("")
    lines.append(
        f"  prediction: {result['n_vertices']:,} vertices, {result['n_faces']:,} faces, {result['boundary_edges']:,} boundary edges, "
        f"{result['nonmanifold_edges']:,} non-manifold edges, {result['components']:,} components, "
        f"watertight {'yes' if result['watertight'] else 'no'}"
    )
    lines.append(f"  Euler characteristic {result['euler_characteristic']}, genus {result['genus']:g} (NaN unless "
                 f"watertight), self-intersecting face pairs {result['self_intersecting_pairs']} "
                 f"({result['self_intersecting_faces']} faces)")
    if result["self_intersections_skipped"]:
        lines.append(f"  self-intersections not searched: {result['self_intersections_skipped']}")
    if result["edge_search_skipped"]:
        lines.append(f"  ECD/EF1 not computed: {result['edge_search_skipped']}")
    if result["empty_prediction"]:
        lines.append("  prediction is EMPTY or degenerate (no usable face, or its faces lie on a line or a point): "
                     "distance metrics NaN, F1 = 0")
    if result["dropped_faces"]:
        lines.append(f"  {result['dropped_faces']:,} prediction faces dropped (out-of-range indices or non-finite vertices)")
    lines.append(f"  time {result['seconds']['total_s']:.2f} s")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m foundation.metrics", description="Score a predicted mesh against a GT mesh."
    )
    parser.add_argument("gt", help="ground-truth mesh file")
    parser.add_argument("pred", help="predicted mesh file")
    parser.add_argument("--points", type=int, default=None, help="samples per mesh (default: the preset's)")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="default",
                        help="the protocol (scene: lengths in metres, the files' unit taken as metres)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument(
        "--no-normalize", action="store_true", help="use both meshes as stored (default: map both by the GT's canonical transform)"
    )
    args = parser.parse_args(argv)
    try:
        if args.points is not None and args.points < 1:
            raise ValueError(f"--points must be >= 1, got {args.points}")
        gt_v, gt_f = read_mesh_arrays(args.gt)
        pred_v, pred_f = read_mesh_file(args.pred)  # the prediction's content is scored, not refused
        metres_per_unit = 1.0  # the files' unit is taken as metres (the scene preset)
        if args.no_normalize:
            frame_note = "meshes used as stored (--no-normalize)"
        else:
            try:
                transform = canonical_transform(gt_v[np.unique(gt_f)])
            except MeshError as exc:
                raise MeshError(f"{args.gt}: {exc}") from None
            gt_v = transform.apply(gt_v)
            with np.errstate(over="ignore", invalid="ignore"):  # beyond float64 there: inf, dropped faces
                pred_v = transform.apply(pred_v)
            frame_note = "both meshes mapped by the GT's canonical transform"
            metres_per_unit = 1.0 / transform.scale
        result = evaluate(gt_v, gt_f, pred_v, pred_f, preset=args.preset, seed=args.seed, n_points=args.points,
                          metres_per_unit=metres_per_unit)
    except (ValueError, MemoryError) as exc:  # MeshError is a ValueError
        print(f"error: {one_line(exc, with_type=False)}", file=sys.stderr)
        return 2
    result["gt"], result["pred"] = str(args.gt), str(args.pred)
    result["normalized"] = not args.no_normalize
    if args.json:
        print(dumps(result, indent=2))
    else:
        print(_format_table(result, PRESETS[args.preset], frame_note))
    return 0


if __name__ == "__main__":
    sys.exit(main())
