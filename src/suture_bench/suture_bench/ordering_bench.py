# SPDX-License-Identifier: Apache-2.0
"""``suture-order-bench``: ordering success per topology and milliseconds per mask, on simulator bags.

Runs :func:`suture_ordering.order_stereo` on the ground-truth masks and tip hints
of the given bags (``/ground_truth/{left,right}/mask``, ``/suture/tip_hint``,
camera_info), scores both views with
:func:`suture_bench.ordering_metrics.ordering_success` against
``/ground_truth/{left,right}/sequence``, and prints per resolution and topology
the success rate and the median milliseconds per view (one mask: cleaning, tip
and search; ``elapsed_ms`` of each view's result). Timing runs on one CPU core: the process is
pinned to one core and OpenCV to one thread (set ``OMP_NUM_THREADS=1 MKL_NUM_THREADS=1`` in the
environment as well if NumPy's BLAS is multithreaded; the search makes no large BLAS calls).
With ``--rounds N`` every frame is ordered N times and each view's time is its fastest round
(other processes on the core only ever add time).

``--baseline CHECKOUT`` times another version of the ordering side by side: the checkout's
interpreter (``CHECKOUT/.venv/bin/python``, or an interpreter given directly) and this one
order the same frames in alternating rounds (:mod:`suture_bench.order_timing`, run as a
script under each), and the bench prints both medians per topology and overall, the CPU time
per view (a stereo pair's thread time / 2, stereo fill included) and how many frames' sequences
differ between the two (by more than 1e-9 px).

Examples::

    suture-order-bench /tmp/ord_crossed /tmp/ord_occluded --failures
    suture-order-bench /tmp/ord_* --rounds 3 --baseline /work/main

Exit status 0 when it ran (whatever the success rate), 1 with one line on
standard error when a bag cannot be read or the baseline cannot be run.
"""

from __future__ import annotations

import argparse
import itertools
import os
import pickle
import subprocess
import sys
import tempfile
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from suture_bench import order_timing
from suture_bench.frames import Frame, find_bags, read_frames
from suture_bench.ordering_metrics import ordering_success
from suture_common.bag_io import BagError
from suture_ordering import OrderingError, OrderingParams, StereoOrdering, order_stereo


def single_core() -> str:
    """Pin this process to one CPU core and OpenCV to one thread; returns a description."""
    cv2.setNumThreads(1)
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    try:
        core = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {core})
        return f"pinned to CPU core {core}, cv2 threads 1"
    except (AttributeError, OSError):
        return "cv2 threads 1 (could not pin to one core on this OS)"


def _parse_set(items: Sequence[str]) -> dict[str, float | int | bool]:
    changes: dict[str, float | int | bool] = {}
    names = OrderingParams.field_names()
    for item in items:
        name, _, value = item.partition("=")
        if name not in names or not value:
            raise argparse.ArgumentTypeError(f"--set expects NAME=VALUE with NAME one of {', '.join(names)}")
        if name == "curvature_prediction":
            changes[name] = value.lower() in ("1", "true", "yes")
        elif name in ("grid_size", "zone_margin_px", "max_steps"):
            changes[name] = int(value)
        else:
            changes[name] = float(value)
    return changes


def _baseline_python(checkout: str) -> str:
    """The interpreter of ``checkout`` (a checkout with ``.venv/bin/python``, or an interpreter)."""
    path = Path(checkout)
    python = path / ".venv" / "bin" / "python" if path.is_dir() else path
    if not (python.is_file() and os.access(python, os.X_OK)):
        raise ValueError(f"--baseline {checkout}: no interpreter there (expected {python})")
    return str(python)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="suture-order-bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("bags", nargs="+", help="simulator bags (directories or .mcap), or folders of bags")
    parser.add_argument("--limit", type=int, default=None, help="at most this many frames per bag")
    parser.add_argument("--failures", action="store_true", help="print every failed frame and why")
    parser.add_argument(
        "--set", action="append", default=[], metavar="NAME=VALUE", help="override an OrderingParams field"
    )
    parser.add_argument(
        "--rounds", type=int, default=1, help="order each frame this many times; a view's time is its fastest"
    )
    parser.add_argument(
        "--baseline",
        metavar="CHECKOUT",
        help="time another checkout's ordering side by side (its .venv/bin/python, or an interpreter)",
    )
    args = parser.parse_args(argv)
    try:
        params = OrderingParams().with_updates(**_parse_set(args.set))
        if args.rounds < 1:
            raise ValueError(f"--rounds must be at least 1, got {args.rounds}")
        baseline = None if args.baseline is None else _baseline_python(args.baseline)
        if baseline is not None and args.set:
            raise ValueError("--baseline times the default parameters: drop --set")
    except (argparse.ArgumentTypeError, ValueError) as exc:
        print(f"suture-order-bench: error: {exc}", file=sys.stderr)
        return 2
    print(f"suture-order-bench: {single_core()}")

    success: dict[tuple[str, str, str], list[bool]] = defaultdict(list)
    timing: dict[tuple[str, str], list[float]] = defaultdict(list)
    packed: list[tuple] = []  # the frames for the side-by-side timing
    labels: list[tuple[str, str]] = []
    try:
        for path in find_bags(args.bags):
            for frame in itertools.islice(read_frames(path, images=False), args.limit):
                resolution = f"{frame.camera.width}x{frame.camera.height}"
                if baseline is not None:
                    packed.append(_packed(frame))
                    labels.append((resolution, frame.topology))
                try:
                    result = order_stereo(
                        frame.true_left_mask, frame.true_right_mask, frame.tip_hint, frame.camera, params
                    )
                except OrderingError as exc:
                    for view in ("left", "right"):
                        success[(resolution, frame.topology, view)].append(False)
                    if args.failures:
                        print(f"FAIL {path.name} {frame.stamp_ns} {frame.topology}: {exc}")
                    continue
                timing[(resolution, frame.topology)].extend(_fastest(frame, params, result, args.rounds))
                for view, predicted, truth, view_result in (
                    ("left", result.left, frame.true_left_sequence, result.left_result),
                    ("right", result.right, frame.true_right_sequence, result.right_result),
                ):
                    score = ordering_success(predicted, truth)
                    success[(resolution, frame.topology, view)].append(score.success)
                    if args.failures and not score.success:
                        print(
                            f"FAIL {path.name} {frame.stamp_ns} {frame.topology} {view}: {score.reason} "
                            f"(status {view_result.status}, {view_result.bridges} bridges, "
                            f"{view_result.forks} forks)"
                        )
    except BagError as exc:
        print(f"suture-order-bench: error: {exc}", file=sys.stderr)
        return 1

    print(f"{'resolution':<11} {'topology':<17} {'frames':>6} {'left %':>7} {'right %':>8} {'median ms':>10}")
    for resolution, topology in sorted({(r, t) for r, t, _ in success}):
        left = success[(resolution, topology, "left")]
        right = success[(resolution, topology, "right")]
        times = timing.get((resolution, topology))
        median = f"{np.median(times):>10.2f}" if times else f"{'-':>10}"
        print(
            f"{resolution:<11} {topology:<17} {len(left):>6} "
            f"{100 * np.mean(left):>7.1f} {100 * np.mean(right):>8.1f} {median}"
        )
    for resolution in sorted({r for r, _ in timing}):
        values = [ms for (r, _), times in timing.items() if r == resolution for ms in times]
        print(
            f"{resolution}: median {np.median(values):.2f} ms per view, "
            f"p90 {np.percentile(values, 90):.2f} ms, "
            f"max {np.max(values):.2f} ms over {len(values)} masks (one core)"
        )
    if baseline is None:
        return 0
    try:
        runs = _time_side_by_side(packed, baseline, args.rounds)
    except RuntimeError as exc:
        print(f"suture-order-bench: error: {exc}", file=sys.stderr)
        return 1
    _print_side_by_side(runs, labels, args.rounds)
    return 0


def _fastest(frame: Frame, params: OrderingParams, result: StereoOrdering, rounds: int) -> list[float]:
    """The views' milliseconds, the fastest of ``rounds`` orderings of ``frame``."""
    times = [result.left_result.elapsed_ms, result.right_result.elapsed_ms]
    masks = (frame.true_left_mask, frame.true_right_mask)
    for _ in range(rounds - 1):
        again = order_stereo(*masks, frame.tip_hint, frame.camera, params)
        times = [min(times[0], again.left_result.elapsed_ms), min(times[1], again.right_result.elapsed_ms)]
    return times


def _packed(frame: Frame) -> tuple:
    """``frame`` as one entry of a :mod:`suture_bench.order_timing` FRAMES file."""
    return (
        order_timing.pack_mask(frame.true_left_mask),
        order_timing.pack_mask(frame.true_right_mask),
        frame.true_left_mask.shape,
        frame.tip_hint,
        frame.camera,
    )


def _time_side_by_side(packed: list[tuple], baseline: str, rounds: int) -> dict[str, list[list[tuple]]]:
    """Each round, this code's and the baseline's worker (alternately first) order ``packed``."""
    pythons = {"this": sys.executable, "baseline": baseline}
    runs: dict[str, list[list[tuple]]] = {"this": [], "baseline": []}
    with tempfile.TemporaryDirectory(prefix="suture-order-bench-") as folder:
        frames_file = Path(folder) / "frames.pkl"
        with open(frames_file, "wb") as stream:
            pickle.dump(packed, stream)
        for round_ in range(rounds):
            for name in ("this", "baseline") if round_ % 2 == 0 else ("baseline", "this"):
                out_file = Path(folder) / f"{name}-{round_}.pkl"
                done = subprocess.run(
                    [pythons[name], "-P", order_timing.__file__, str(frames_file), str(out_file)],
                    capture_output=True,
                    text=True,
                    check=False,
                )
                if done.returncode != 0:
                    last = (done.stderr.strip().splitlines() or ["no message"])[-1]
                    raise RuntimeError(f"the {name} code's timing failed ({pythons[name]}): {last}")
                with open(out_file, "rb") as stream:
                    runs[name].append(pickle.load(stream))
    return runs


def _print_side_by_side(
    runs: dict[str, list[list[tuple]]], labels: list[tuple[str, str]], rounds: int
) -> None:
    """Median ms per view by topology, CPU time per view, and how many frames' sequences differ."""

    def fastest(name: str, column: int) -> np.ndarray:
        values = [[np.nan if r[column] is None else r[column] for r in run] for run in runs[name]]
        return np.min(np.array(values, dtype=float), axis=0)  # nan where the ordering refused

    views = {name: np.column_stack([fastest(name, 0), fastest(name, 1)]) for name in runs}
    cpu = {name: fastest(name, 2) / 2 for name in runs}
    both = np.isfinite(views["this"]) & np.isfinite(views["baseline"])
    print(f"side by side: median ms per view, the fastest of {rounds} round(s), one core")
    print(f"{'resolution':<11} {'topology':<17} {'views':>6} {'this':>8} {'baseline':>9}")
    keys = sorted(set(labels)) + [(r, "all") for r in sorted({r for r, _ in labels})]
    for resolution, topology in keys:
        rows = np.array([r == resolution and topology in (t, "all") for r, t in labels])
        chosen = both & rows[:, None]
        if not chosen.any():
            continue
        this, base = np.median(views["this"][chosen]), np.median(views["baseline"][chosen])
        print(f"{resolution:<11} {topology:<17} {int(chosen.sum()):>6} {this:>8.2f} {base:>9.2f}")
    pairs = np.isfinite(cpu["this"]) & np.isfinite(cpu["baseline"])
    if pairs.any():
        print(
            f"CPU ms per view (a pair's thread time / 2, stereo fill included), median: "
            f"this {np.median(cpu['this'][pairs]):.2f}, baseline {np.median(cpu['baseline'][pairs]):.2f}"
        )
    differ = sum(not _same_ordering(a, b) for a, b in zip(runs["this"][0], runs["baseline"][0], strict=True))
    print(f"sequences: {differ} of {len(labels)} frames differ from the baseline's (by more than 1e-9 px)")


def _same_ordering(a: tuple, b: tuple) -> bool:
    """Both refused, or both ordered both views alike (within 1e-9 px)."""
    if a[0] is None or b[0] is None:
        return a[0] is None and b[0] is None
    pairs = zip(a[3:], b[3:], strict=True)
    return all(x.shape == y.shape and np.allclose(x, y, rtol=0.0, atol=1e-9) for x, y in pairs)


if __name__ == "__main__":
    sys.exit(main())
