# SPDX-License-Identifier: Apache-2.0
"""``suture-eval PATH... [--masks predicted|ground_truth] [--sequences predicted|ground_truth] [--json FILE]
[--report DIR]``

Runs the pipeline's core functions over MCAP bags (or folders of them) and prints
our figures by topology next to the paper's; ``--json`` also writes the summary of
docs/interfaces.md's evaluation contract, ``--report`` a folder of per-frame JSON and
pictures (``suture_bench.report``). Bags without 3D truth are scored on what they carry.
Exit 0 on success, 1 with one line on standard error otherwise.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence

from suture_bench.evaluate import SOURCES, EvaluationError, evaluate

# The paper's figures (Tables I-III), printed next to ours.
PAPER_SEGMENTATION = "M-ToSOT IoU 71.1 / 72.1 %, recall 97.3 / 97.5 % (Table I, sets 1 / 2)"
#: Table II (UR5 touching key points, mm): average and maximum per group.
PAPER_KEYPOINTS = {"straight": (2.21, 3.6), "curved": (1.43, 2.4), "self_intersected": (1.85, 4.1)}
#: Table III (simulated grasps in V-REP, 8 groups, mm): mean and maximum.
PAPER_GRASPS = {"curved": (2.33, 3.2), "self_intersected": (1.73, 2.7)}
PAPER_NOTE = (
    "paper: key points = Table II (UR5 touching 10 key points, ave/max; its phantom groups: 1.62/2.8 and "
    "1.96/4.5); grasps = Table III (V-REP, 8 simulated grasps, mean/max). Ours: key points = mean distance "
    "of 10 evenly spaced path points to the true centreline; grasp = predicted vs true grasp point."
)


def _fmt(value: float | None, digits: int = 2, scale: float = 1.0, unit: str = "") -> str:
    return "n/a" if value is None else f"{value * scale:.{digits}f}{unit}"


def _pair(values: tuple[float, float] | None) -> str:
    return "-" if values is None else f"{values[0]:.2f} / {values[1]:.1f}"


def render_table(summary: dict, title: str = "suture-eval") -> str:
    """The human-readable report of a summary: ours by topology next to the paper, then latency."""
    seg = summary["segmentation"]
    lines = [
        f"{title}: {summary['frames']} frames, masks={summary['masks']}, sequences={summary['sequences']}",
        "",
        f"segmentation  IoU {_fmt(seg['iou'], 3)}  precision {_fmt(seg['precision'], 3)}  "
        f"recall {_fmt(seg['recall'], 3)}  F1 {_fmt(seg['f1'], 3)}    paper: {PAPER_SEGMENTATION}",
        f"              centreline recall {_fmt(seg.get('centreline_recall'), 3)}  "
        f"centreline precision {_fmt(seg.get('centreline_precision'), 3)}  "
        f"clDice {_fmt(seg.get('cldice'), 3)}",
        "",
        f"{'topology':17s} {'ordering':>8s} {'mean err':>8s} {'max err':>8s} {'key pts':>8s} "
        f"{'paper key pts':>13s} {'grasp med':>9s} {'grasp max':>9s} {'paper grasp':>11s} "
        f"{'<= 5 mm':>7s} {'frames':>6s}",
    ]
    by_recon = summary["reconstruction"]["by_topology"]
    by_ordering = summary["ordering"]["by_topology"]
    for topology in sorted(set(by_ordering) | set(by_recon)):
        recon = by_recon.get(topology, {})
        lines.append(
            f"{topology:17s} {_fmt(by_ordering.get(topology), 1, 100, '%'):>8s} "
            f"{_fmt(recon.get('mean_error_mm')):>8s} {_fmt(recon.get('max_error_mm')):>8s} "
            f"{_fmt(recon.get('keypoint_error_mm')):>8s} {_pair(PAPER_KEYPOINTS.get(topology)):>13s} "
            f"{_fmt(recon.get('grasp_median_error_mm')):>9s} {_fmt(recon.get('grasp_max_error_mm')):>9s} "
            f"{_pair(PAPER_GRASPS.get(topology)):>11s} {_fmt(recon.get('within_5mm'), 1, 100, '%'):>7s} "
            f"{recon.get('frames', 0):>6d}"
        )
    grasp, recon = summary["grasp"], summary["reconstruction"]
    lines += [
        f"{'all':17s} {_fmt(summary['ordering']['success_rate'], 1, 100, '%'):>8s} "
        f"{_fmt(recon['mean_error_mm']):>8s} {_fmt(recon['max_error_mm']):>8s} {'':>8s} {'':>13s} "
        f"{_fmt(grasp['median_error_mm']):>9s} {_fmt(grasp['max_error_mm']):>9s} {'':>11s} "
        f"{_fmt(grasp['within_5mm'], 1, 100, '%'):>7s}",
        "ordering: the left view's sequences (the right view's: "
        f"{_fmt(summary['ordering']['right_view']['success_rate'], 1, 100, '%')})",
        "errors in mm; mean err: per-frame mean path-to-centreline distance; max err: any path point; "
        "<= 5 mm: share of all frames (no grasp point = miss; a true grasp point hidden in a view: "
        "refused as not seen = success, grasped = miss)",
        PAPER_NOTE,
        "",
    ]
    if "produced" in grasp:
        refused = ", ".join(f"{reason} {count}" for reason, count in grasp["refused"].items()) or "none"
        hidden = grasp["hidden"]
        consistency = summary["self_consistency"]
        lines += [
            f"grasps produced {grasp['produced']} of {summary['frames']} frames, "
            f"{_fmt(grasp['beyond_10mm'], 0)} more than 10 mm off; refused: {refused}",
            f"true grasp point hidden in {hidden['hidden']} frames: refused as not seen "
            f"{hidden['refused_not_seen']} (successes), grasped {hidden['grasped']} (misses), "
            f"refused otherwise {hidden['refused_otherwise']}",
            "self-consistency (3D path reprojected onto both masks): "
            f"mean {_fmt(consistency['reprojection_mean_px'])} px, "
            f"max {_fmt(consistency['reprojection_max_px'])} px over {consistency['frames']} frames",
            "",
        ]
    lines += [f"{'latency (ms per stereo frame)':30s} {'median':>8s} {'p95':>8s}"]
    p95 = summary.get("latency_p95_ms", {})
    for stage, median in summary["latency_ms"].items():
        lines.append(f"{stage:30s} {_fmt(median, 1):>8s} {_fmt(p95.get(stage), 1):>8s}")
    lines += [f"note: {note}" for note in summary["notes"]]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="suture-eval", description=__doc__.split("\n\n")[1])
    parser.add_argument(
        "paths", nargs="+", metavar="PATH", help="bag directories, .mcap files or folders of them"
    )
    parser.add_argument("--masks", choices=SOURCES, default="predicted")
    parser.add_argument("--sequences", choices=SOURCES, default="predicted")
    parser.add_argument("--json", metavar="FILE", help="also write the JSON summary here")
    parser.add_argument(
        "--report", metavar="DIR", help="also write per-frame JSON, overlays and the 3D plot into DIR"
    )
    parser.add_argument(
        "--max-overlays", type=int, default=20, help="overlay pictures in the report (default 20)"
    )
    parser.add_argument(
        "--seg-weights",
        metavar="WEIGHTS",
        help="segmentation model for --masks predicted: m_onsite_half (on-site; default: its int8 "
        "export), m_onsite (its full-resolution twin), m_ost (legacy), m_ost_hard (legacy, hooks, wide "
        "shafts, threads along the rows), m_tosot (the paper's on-site transfer), m_general (cameras "
        "not seen in training), their _int8 exports, or a .pt/.onnx file",
    )
    parser.add_argument(
        "--no-images",
        action="store_true",
        help="reconstruct from the sequences alone, without the photometric refinement by the images "
        "(reconstruction_node's use_images false)",
    )
    parser.add_argument(
        "--no-low-masks",
        action="store_true",
        help="order the masks alone, without the low masks (segmentation_node's low_threshold 0)",
    )
    parser.add_argument(
        "--no-flip-average",
        action="store_true",
        help="segment each image alone, not averaged with its mirror image (segmentation_node's "
        "flip_average false)",
    )
    parser.add_argument(
        "--mask-cache",
        metavar="FILE",
        help="with --masks predicted: keep every frame's masks in FILE (.npz) on the first run and read "
        "them back on the next, instead of segmenting again (same model and options, same bags)",
    )
    args = parser.parse_args(argv)
    try:
        summary = evaluate(
            args.paths,
            masks=args.masks,
            sequences=args.sequences,
            seg_weights=args.seg_weights,
            use_images=not args.no_images,
            use_low_masks=not args.no_low_masks,
            report=args.report,
            max_overlays=args.max_overlays,
            flip_average=not args.no_flip_average,
            mask_cache=args.mask_cache,
        )
        if args.json:
            with open(args.json, "w") as stream:
                json.dump({k: v for k, v in summary.items() if k != "per_frame"}, stream, indent=2)
    except (EvaluationError, OSError, ValueError, RuntimeError) as error:
        print(f"suture-eval: error: {error}", file=sys.stderr)
        return 1
    print(render_table(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
