"""``suture-eval PATH... [--masks predicted|ground_truth] [--sequences predicted|ground_truth] [--json FILE]``

Runs the pipeline's core functions over MCAP bags (or folders of them) and prints
our figures by topology next to the paper's; ``--json`` also writes the summary of
DESIGN.md's evaluation contract. Exit 0 on success, 1 with one line on standard
error otherwise.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence

from suture_bench.evaluate import SOURCES, EvaluationError, evaluate

# The paper's figures (Tables I-III), for the printed comparison.
PAPER = {
    "segmentation": "M-ToSOT IoU 71.1 / 72.1 %, recall 97.3 / 97.5 % (Table I, sets 1 / 2)",
    "reconstruction": "key points: mean 1.43-2.21 mm, worst 4.5 mm (Table II)",
    "grasp": "simulated grasps: mean 1.73 / 2.33 mm, worst < 3.5 mm (Table III)",
}


def _fmt(value: float | None, digits: int = 2, scale: float = 1.0, unit: str = "") -> str:
    return "n/a" if value is None else f"{value * scale:.{digits}f}{unit}"


def render_table(summary: dict) -> str:
    """The human-readable report of a summary."""
    seg = summary["segmentation"]
    lines = [
        f"suture-eval: {summary['frames']} frames, masks={summary['masks']}, "
        f"sequences={summary['sequences']}",
        "",
        f"segmentation  IoU {_fmt(seg['iou'], 3)}  precision {_fmt(seg['precision'], 3)}  "
        f"recall {_fmt(seg['recall'], 3)}  F1 {_fmt(seg['f1'], 3)}    paper: {PAPER['segmentation']}",
        "",
        f"{'topology':18s} {'ordering ok':>11s} {'mean err':>9s} {'worst frm':>9s} {'max err':>9s} "
        f"{'grasp med':>9s} {'grasp max':>9s} {'frames':>6s}",
    ]
    by_recon = summary["reconstruction"]["by_topology"]
    topologies = sorted(set(summary["ordering"]["by_topology"]) | set(by_recon))
    for topology in topologies:
        recon = by_recon.get(topology, {})
        lines.append(
            f"{topology:18s} {_fmt(summary['ordering']['by_topology'].get(topology), 1, 100, ' %'):>11s} "
            f"{_fmt(recon.get('mean_error_mm'), 2, 1, ' mm'):>9s} "
            f"{_fmt(recon.get('worst_frame_mean_error_mm'), 2, 1, ' mm'):>9s} "
            f"{_fmt(recon.get('max_error_mm'), 2, 1, ' mm'):>9s} "
            f"{_fmt(recon.get('grasp_median_error_mm'), 2, 1, ' mm'):>9s} "
            f"{_fmt(recon.get('grasp_max_error_mm'), 2, 1, ' mm'):>9s} {recon.get('frames', 0):>6d}"
        )
    grasp, recon = summary["grasp"], summary["reconstruction"]
    lines += [
        f"{'all':18s} {_fmt(summary['ordering']['success_rate'], 1, 100, ' %'):>11s} "
        f"{_fmt(recon['mean_error_mm'], 2, 1, ' mm'):>9s} {'':>9s} "
        f"{_fmt(recon['max_error_mm'], 2, 1, ' mm'):>9s} "
        f"{_fmt(grasp['median_error_mm'], 2, 1, ' mm'):>9s} {_fmt(grasp['max_error_mm'], 2, 1, ' mm'):>9s}",
        f"paper: {PAPER['reconstruction']}; {PAPER['grasp']}",
        f"grasp within 5 mm: {_fmt(grasp['within_5mm'], 1, 100, ' %')}; errors in mm: mean and worst frame "
        "of the per-frame mean path-to-centreline distance, max of any path point",
        "",
        "latency (median ms per stereo frame): "
        + ", ".join(f"{stage} {_fmt(ms, 1)}" for stage, ms in summary["latency_ms"].items()),
    ]
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
        "--seg-weights",
        metavar="WEIGHTS",
        help="segmentation model for --masks predicted: m_tosot (default, on-site), m_ost (legacy) or a .pt",
    )
    args = parser.parse_args(argv)
    try:
        summary = evaluate(
            args.paths, masks=args.masks, sequences=args.sequences, seg_weights=args.seg_weights
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
