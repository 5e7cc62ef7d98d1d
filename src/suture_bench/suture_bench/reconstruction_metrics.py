# SPDX-License-Identifier: Apache-2.0
"""Reconstruction metrics, as the paper's Tables II and III report them, and a benchmark of the 3D stage.

Pure metrics (no I/O), called by ``suture-eval`` and by the benchmark below:

* :func:`score_reconstruction` scores one frame: the distance from every
  predicted path point to the true 3D centreline (a polyline; mean and max), the
  length error, the errors of 10 key points evenly spaced by arc length along
  the predicted thread (tip to end; the error of a key point is its distance to
  the true centreline, as the paper's Table II measures how far the robot tip
  driven to a computed key point is from the suture), and the grasp point error
  (3D distance to the true grasp point, Table III).
* :func:`summarise` aggregates frames per topology.
* :func:`reprojection_to_masks` measures a reconstruction without 3D truth: how far its
  path, projected into each view, lands from that view's mask (stereo self-consistency).

Everything is in metres; reports print millimetres.

The benchmark (:func:`main`, ``python -m suture_bench.reconstruction_metrics BAG...``,
meant to be installed as ``suture-recon-bench``) isolates the 3D stage: it reads
the ground-truth sequences of simulator bags, makes them look like the ordering
stage's output (:func:`perturb_sequence`: each view resampled on its own every
~1 px of its own arc length from a random phase, plus 0.3 px of Gaussian noise),
runs :func:`suture_reconstruction.reconstruct` exactly as ``reconstruction_node``
does, and prints per topology the centreline and grasp errors next to the
paper's, and the milliseconds per stereo pair on one CPU core.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from suture_bench.frames import Frame, find_bags, read_frames
from suture_common.camera import StereoCamera
from suture_reconstruction import ReconstructionError, ReconstructionParams, reconstruct

KEYPOINTS = 10
"""Key points per thread (paper Table II)."""

PAPER_TABLE_II_MM = {
    "straight": (2.21, 3.6),
    "curved": (1.43, 2.4),
    "self_intersected": (1.85, 4.1),
    "artificial_liver": (1.62, 2.8),
    "surgical_phantom": (1.96, 4.5),
}
"""Paper Table II: key-point error (mean, max) in mm per experiment group (real UR5, hand-eye included)."""

PAPER_TABLE_III_MM = {
    "curved": (2.33, 3.2),
    "self_intersected": (1.73, 2.7),
}
"""Paper Table III: simulated grasp error (mean, max) in mm over 8 trials per topology."""


@dataclass(frozen=True)
class ReconstructionScore:
    """Errors of one reconstructed frame, metres.

    ``mean_error``/``max_error``: distance from the predicted path points to the
    true centreline; ``length_pred``/``length_true``; ``keypoint_errors`` (10,);
    ``grasp_error``: None when there is no predicted grasp point.
    """

    mean_error: float
    max_error: float
    length_pred: float
    length_true: float
    keypoint_errors: np.ndarray
    grasp_error: float | None

    @property
    def length_error(self) -> float:
        """Signed length error, predicted minus true (m)."""
        return self.length_pred - self.length_true

    def as_mm(self) -> dict[str, object]:
        """The score as a JSON-ready dict in millimetres."""
        return {
            "mean_error_mm": 1000 * self.mean_error,
            "max_error_mm": 1000 * self.max_error,
            "length_error_mm": 1000 * self.length_error,
            "keypoint_errors_mm": (1000 * self.keypoint_errors).tolist(),
            "grasp_error_mm": None if self.grasp_error is None else 1000 * self.grasp_error,
        }


def distances_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """(N,) Euclidean distance from each of (N, 3) ``points`` to the (Q, 3) polyline (its segments)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    polyline = np.asarray(polyline, dtype=np.float64).reshape(-1, 3)
    if len(polyline) == 1:
        return np.linalg.norm(points - polyline[0], axis=1)
    start, direction = polyline[:-1], np.diff(polyline, axis=0)
    length2 = np.maximum(np.einsum("ij,ij->i", direction, direction), 1e-30)
    best = np.full(len(points), np.inf)
    chunk = max(1, 200_000 // len(start))
    for first in range(0, len(points), chunk):
        p = points[first : first + chunk, None, :]
        offset = p - start[None]
        fraction = np.clip(np.einsum("pqk,qk->pq", offset, direction) / length2, 0.0, 1.0)
        nearest = start[None] + fraction[..., None] * direction[None]
        best[first : first + chunk] = np.sqrt(((p - nearest) ** 2).sum(axis=2).min(axis=1))
    return best


def polyline_length(polyline: np.ndarray) -> float:
    """Length (m) of an (N, 3) polyline."""
    return float(np.linalg.norm(np.diff(np.asarray(polyline, dtype=np.float64), axis=0), axis=1).sum())


def points_along(polyline: np.ndarray, count: int) -> np.ndarray:
    """(count, 3) points evenly spaced by arc length along a polyline, first and last point included."""
    polyline = np.asarray(polyline, dtype=np.float64)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(polyline, axis=0), axis=1))])
    s = np.linspace(0.0, arc[-1], count)
    return np.column_stack([np.interp(s, arc, polyline[:, k]) for k in range(3)])


def score_reconstruction(
    path_pred: np.ndarray,
    path_true: np.ndarray,
    grasp_pred: np.ndarray | None,
    grasp_true: np.ndarray,
) -> ReconstructionScore:
    """Score a predicted path (P, 3) and grasp point (3,) or None against the truth (Q, 3), (3,), metres.

    Raises ValueError for empty paths or non-finite values.
    """
    pred = np.asarray(path_pred, dtype=np.float64).reshape(-1, 3)
    true = np.asarray(path_true, dtype=np.float64).reshape(-1, 3)
    if len(pred) == 0 or len(true) == 0:
        raise ValueError(f"paths must not be empty (predicted {len(pred)}, true {len(true)} points)")
    if not (np.isfinite(pred).all() and np.isfinite(true).all()):
        raise ValueError("paths must be finite")
    errors = distances_to_polyline(pred, true)
    keypoints = distances_to_polyline(points_along(pred, KEYPOINTS), true)
    grasp_error = None
    if grasp_pred is not None:
        grasp_error = float(np.linalg.norm(np.asarray(grasp_pred, float) - np.asarray(grasp_true, float)))
    return ReconstructionScore(
        mean_error=float(errors.mean()),
        max_error=float(errors.max()),
        length_pred=polyline_length(pred),
        length_true=polyline_length(true),
        keypoint_errors=keypoints,
        grasp_error=grasp_error,
    )


def reprojection_to_masks(
    path: np.ndarray, camera: StereoCamera, masks: tuple[np.ndarray, np.ndarray]
) -> dict[str, float]:
    """Stereo self-consistency of a reconstructed (N, 3) ``path``: its points projected into the
    left and right views, and each pixel's distance to the nearest pixel of that view's mask.

    Returns ``mean_px`` (over both views' points), ``max_px``, and ``left_mean_px`` /
    ``right_mean_px``. A point projecting outside the image is measured from the nearest
    border pixel. A view with an empty mask gives inf.
    """
    figures: dict[str, float] = {}
    distances = []
    for view, mask in zip(("left", "right"), masks, strict=True):
        mask = np.asarray(mask) > 0
        if not mask.any():
            distance = np.full(len(path), np.inf)
        else:
            to_mask = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
            uv = camera.project(np.asarray(path, dtype=np.float64), view)
            inside = np.isfinite(uv).all(axis=1)
            u = np.clip(uv[inside, 0], 0, mask.shape[1] - 1)
            v = np.clip(uv[inside, 1], 0, mask.shape[0] - 1)
            border = np.hypot(uv[inside, 0] - u, uv[inside, 1] - v)
            distance = np.full(len(path), np.inf)
            distance[inside] = to_mask[np.rint(v).astype(int), np.rint(u).astype(int)] + border
        figures[f"{view}_mean_px"] = float(distance.mean())
        distances.append(distance)
    both = np.concatenate(distances)
    figures.update(mean_px=float(both.mean()), max_px=float(both.max()))
    return figures


@dataclass(frozen=True)
class Summary:
    """Aggregate of one group of frames, millimetres (NaN where nothing could be measured).

    ``frames``: scored frames; ``failures``: frames without a reconstruction;
    ``mean_error_mm``: mean over frames of the frame mean; ``worst_frame_mm``:
    the largest frame mean; ``max_error_mm``: the largest point error;
    ``grasp_median_mm``/``grasp_mean_mm``/``grasp_max_mm``; ``length_error_mm``:
    mean absolute length error; ``keypoint_mm`` (10,): mean error per key point;
    ``keypoint_mean_mm``/``keypoint_max_mm``: over all key points of all frames.
    """

    frames: int
    failures: int
    mean_error_mm: float
    worst_frame_mm: float
    max_error_mm: float
    grasp_median_mm: float
    grasp_mean_mm: float
    grasp_max_mm: float
    length_error_mm: float
    keypoint_mm: np.ndarray
    keypoint_mean_mm: float
    keypoint_max_mm: float


def summarise(scores: Iterable[ReconstructionScore | None]) -> Summary:
    """Aggregate frame scores (None = the frame failed to reconstruct)."""
    scores = list(scores)
    good = [s for s in scores if s is not None]
    nan = float("nan")
    if not good:
        return Summary(0, len(scores), nan, nan, nan, nan, nan, nan, nan, np.full(KEYPOINTS, nan), nan, nan)
    means = 1000 * np.array([s.mean_error for s in good])
    grasps = 1000 * np.array([s.grasp_error for s in good if s.grasp_error is not None])
    keypoints = 1000 * np.stack([s.keypoint_errors for s in good])
    return Summary(
        frames=len(good),
        failures=len(scores) - len(good),
        mean_error_mm=float(means.mean()),
        worst_frame_mm=float(means.max()),
        max_error_mm=float(1000 * max(s.max_error for s in good)),
        grasp_median_mm=float(np.median(grasps)) if grasps.size else nan,
        grasp_mean_mm=float(grasps.mean()) if grasps.size else nan,
        grasp_max_mm=float(grasps.max()) if grasps.size else nan,
        length_error_mm=float(1000 * np.mean([abs(s.length_error) for s in good])),
        keypoint_mm=keypoints.mean(axis=0),
        keypoint_mean_mm=float(keypoints.mean()),
        keypoint_max_mm=float(keypoints.max()),
    )


def perturb_sequence(
    sequence: np.ndarray,
    rng: np.random.Generator,
    spacing_px: float = 1.0,
    spacing_jitter: float = 0.05,
    noise_px: float = 0.3,
) -> np.ndarray:
    """A ground-truth sequence made to look like the ordering stage's output, (M, 2) pixels.

    The (N, 2|3) true sequence (its third column, visibility, is ignored) is
    resampled along its own arc length every ``spacing_px`` * (1 +- ``spacing_jitter``)
    (drawn once per call) from a random phase, keeping the cut tip as the first
    sample, then Gaussian noise of ``noise_px`` is added to u and v. Each view is
    perturbed on its own, so left and right rows are no longer index-aligned and
    the lengths differ. Covered stretches are kept, as the ordering stage follows
    a thread through crossings.
    """
    uv = np.asarray(sequence, dtype=np.float64)[:, :2]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(uv, axis=0), axis=1))])
    step = spacing_px * (1.0 + rng.uniform(-spacing_jitter, spacing_jitter))
    s = np.concatenate([[0.0], np.arange(rng.uniform(0.0, step), arc[-1], step)])
    resampled = np.column_stack([np.interp(s, arc, uv[:, 0]), np.interp(s, arc, uv[:, 1])])
    return resampled + rng.normal(0.0, noise_px, resampled.shape)


# --------------------------------------------------------------------------- benchmark over bags

TARGETS_MM = {"mean": 0.5, "worst_frame": 1.5, "grasp_median": 1.0, "grasp_max": 2.5}
"""The 3D stage's targets from true sequences: centreline mean and worst frame, grasp median and max."""

TIME_TARGET_MS = 15.0


@dataclass
class FrameResult:
    """One benchmarked frame: its score (None when it was not reconstructed, with ``error``) and timings."""

    topology: str
    stamp_ns: int
    score: ReconstructionScore | None
    error: str | None
    wall_ms: float
    stage_ms: dict[str, float]


def benchmark(
    frames: Iterable[Frame],
    seed: int = 0,
    noise_px: float = 0.3,
    params: ReconstructionParams | None = None,
) -> list[FrameResult]:
    """Reconstruct every frame from its perturbed ground-truth sequences and score it."""
    params = params or ReconstructionParams()
    results = []
    for index, frame in enumerate(frames):
        rng = np.random.default_rng([seed, index])
        left = perturb_sequence(frame.true_left_sequence[:, :2], rng, noise_px=noise_px)
        right = perturb_sequence(frame.true_right_sequence[:, :2], rng, noise_px=noise_px)
        start = time.perf_counter()
        try:
            result = reconstruct(left, right, frame.camera, params)
        except (ReconstructionError, ValueError) as exc:
            wall = 1000 * (time.perf_counter() - start)
            results.append(
                FrameResult(frame.topology, frame.stamp_ns, None, f"{type(exc).__name__}: {exc}", wall, {})
            )
            continue
        wall = 1000 * (time.perf_counter() - start)
        score = score_reconstruction(result.path, frame.true_path, result.grasp_position, frame.true_grasp)
        results.append(
            FrameResult(frame.topology, frame.stamp_ns, score, None, wall, dict(result.timings_ms))
        )
    return results


def _mark(value: float, target: float) -> str:
    return "ok" if value <= target else "MISS"


def format_report(results: list[FrameResult], noise_px: float) -> str:
    """The benchmark's table: per topology next to the paper's numbers, then the timings."""
    lines = [
        f"3D stage on ground-truth sequences (views resampled alone every ~1 px, {noise_px} px noise); mm",
        "",
        f"{'topology':<17} {'frames':>6} {'fail':>4} {'mean':>6} {'worst':>6} {'maxpt':>6} "
        f"{'g.med':>6} {'g.max':>6} {'|dlen|':>6} {'kp.avg':>6} {'kp.max':>6}  "
        "targets (mean/worst/g.med/g.max)",
    ]
    topologies = sorted({r.topology for r in results})
    for topology in [*topologies, "all"]:
        group = [r for r in results if topology in ("all", r.topology)]
        s = summarise(r.score for r in group)
        marks = " ".join(
            _mark(v, TARGETS_MM[k])
            for k, v in (
                ("mean", s.mean_error_mm),
                ("worst_frame", s.worst_frame_mm),
                ("grasp_median", s.grasp_median_mm),
                ("grasp_max", s.grasp_max_mm),
            )
        )
        lines.append(
            f"{topology:<17} {s.frames + s.failures:>6} {s.failures:>4} "
            f"{s.mean_error_mm:6.2f} {s.worst_frame_mm:6.2f} "
            f"{s.max_error_mm:6.2f} {s.grasp_median_mm:6.2f} {s.grasp_max_mm:6.2f} {s.length_error_mm:6.2f} "
            f"{s.keypoint_mean_mm:6.2f} {s.keypoint_max_mm:6.2f}  {marks}"
        )
        if topology != "all" and s.frames:
            lines.append(f"{'':<17} key points 1-10: " + " ".join(f"{v:.2f}" for v in s.keypoint_mm))
    lines += ["", "paper, Table II (UR5 touching 10 key points, hand-eye included), mean / max:"]
    lines += [f"  {name:<17} {m:.2f} / {x:.1f}" for name, (m, x) in PAPER_TABLE_II_MM.items()]
    lines += ["paper, Table III (simulated dVRK grasps, 8 per set), mean / max:"]
    lines += [f"  {name:<17} {m:.2f} / {x:.1f}" for name, (m, x) in PAPER_TABLE_III_MM.items()]
    timed = [r for r in results if r.stage_ms]
    if timed:
        stages = list(timed[0].stage_ms)
        lines += [
            "",
            f"ms per stereo pair on one CPU core ({len(timed)} pairs; target < {TIME_TARGET_MS:.0f} ms):",
        ]
        for stage in stages:
            values = np.array([r.stage_ms[stage] for r in timed])
            lines.append(
                f"  {stage:<16} mean {values.mean():6.2f}  median {np.median(values):6.2f}  "
                f"p95 {np.percentile(values, 95):6.2f}  max {values.max():6.2f}"
            )
        wall = np.array([r.wall_ms for r in timed])
        lines.append(
            f"  {'reconstruct()':<16} mean {wall.mean():6.2f}  median {np.median(wall):6.2f}  "
            f"p95 {np.percentile(wall, 95):6.2f}  max {wall.max():6.2f}  "
            f"{_mark(float(np.median(wall)), TIME_TARGET_MS)}"
        )
    failures = [r for r in results if r.error]
    if failures:
        lines += ["", "frames not reconstructed:"]
        lines += [f"  {r.topology} {r.stamp_ns}: {r.error}" for r in failures]
    return "\n".join(lines)


def _pin_to_one_core(core: int | None = None) -> tuple[str, set[int] | None]:
    """Run on one CPU core (default: the highest-numbered one); returns a note and the old affinity."""
    try:
        previous = os.sched_getaffinity(0)
        core = max(previous) if core is None else core
        os.sched_setaffinity(0, {core})
        return f"pinned to CPU core {core}", previous
    except (AttributeError, OSError) as exc:  # not Linux
        return f"could not pin to one core ({exc})", None


def _override(item: str) -> tuple[str, float | int]:
    """``NAME=VALUE`` of ``--set`` as (name, number)."""
    name, sep, value = item.partition("=")
    if not sep:
        raise ValueError(f"--set expects NAME=VALUE, got {item!r}")
    number = float(value)
    return name, int(
        number
    ) if number.is_integer() and "." not in value and "e" not in value.lower() else number


def main(argv: Sequence[str] | None = None) -> int:
    """``suture-recon-bench BAG... [--seed S] [--noise PX] [--json FILE]``.

    Exits 0, or 1 with one line on standard error naming the problem.
    """
    parser = argparse.ArgumentParser(
        prog="suture-recon-bench",
        description="Benchmark the 3D stage (pairing, triangulation, Algorithm 1, grasp) on the ground-truth "
        "sequences of simulator bags, per topology, next to the paper's Tables II and III.",
    )
    parser.add_argument("bags", nargs="+", help="bags (MCAP folders or files) or folders of bags")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sequence perturbation (default 0)")
    parser.add_argument(
        "--noise", type=float, default=0.3, help="pixel noise added to each view (default 0.3)"
    )
    parser.add_argument("--json", type=Path, help="also write per-frame and summary results to this file")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a reconstruction parameter (ReconstructionParams.replace names, SI units), repeatable",
    )
    parser.add_argument("--core", type=int, help="CPU core to run on (default: the highest-numbered one)")
    args = parser.parse_args(argv)
    note, previous = _pin_to_one_core(args.core)
    try:
        params = ReconstructionParams().replace(**dict(_override(item) for item in args.set))
        frames = [frame for bag in find_bags(args.bags) for frame in read_frames(bag, images=False)]
        if not frames:
            raise ValueError(f"no frame with ground-truth sequences, path and grasp pose in {args.bags}")
        benchmark(frames[:1], args.seed, args.noise, params)  # warm-up: caches and lazy imports
        results = benchmark(frames, args.seed, args.noise, params)
        print(format_report(results, args.noise))
        print(f"({note})")
        if args.json:
            payload = {
                "noise_px": args.noise,
                "seed": args.seed,
                "summary": {
                    topology: {
                        k: (v.tolist() if isinstance(v, np.ndarray) else v)
                        for k, v in asdict(
                            summarise(r.score for r in results if topology in ("all", r.topology))
                        ).items()
                    }
                    for topology in [*sorted({r.topology for r in results}), "all"]
                },
                "frames": [
                    {
                        "topology": r.topology,
                        "stamp_ns": r.stamp_ns,
                        "error": r.error,
                        "wall_ms": r.wall_ms,
                        "stage_ms": r.stage_ms,
                        **(r.score.as_mm() if r.score else {}),
                    }
                    for r in results
                ],
            }
            args.json.write_text(json.dumps(payload, indent=1, allow_nan=True))
    except (OSError, ValueError, TypeError) as exc:
        print(f"suture-recon-bench: {exc}", file=sys.stderr)
        return 1
    finally:
        if previous is not None:
            os.sched_setaffinity(0, previous)
    return 0


if __name__ == "__main__":
    sys.exit(main())
