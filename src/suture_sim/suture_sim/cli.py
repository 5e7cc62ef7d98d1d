# SPDX-License-Identifier: Apache-2.0
"""``suture-sim``: write simulated stereo suture frames with ground truth to an MCAP bag
and/or PNG training folders.

Examples::

    suture-sim --topology mixed --frames 50 --domain legacy --resolution 640x480 \\
        --seed 1 --out bags/train_legacy
    suture-sim --topology hard --frames 30 --resolution 1280x1024 --seed 1 --out bags/hard

Exit status 0 on success; otherwise 1 with one line on standard error naming the
problem (argument errors exit 2, as argparse does).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

from suture_common.bag_io import BagError, BagWriter
from suture_common.camera import CameraModelError, StereoCamera
from suture_sim.cycles import DEFAULT_SAMPLES, CyclesUnavailableError
from suture_sim.output import export_png, write_frame
from suture_sim.parallel import generate_frames
from suture_sim.scene import (
    BACKGROUNDS,
    DOMAINS,
    RENDERERS,
    TOPOLOGY_CHOICES,
    SceneError,
    SimConfig,
    SimFrame,
)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, no usage dump
        self.exit(2, f"{self.prog}: error: {message}\n")


def resolution(text: str) -> tuple[int, int]:
    """Parse 'WxH' into positive (width, height)."""
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must look like 640x480, got {text!r}") from None
    if width < 64 or height < 64 or width > 8192 or height > 8192:
        raise argparse.ArgumentTypeError(f"resolution must be between 64x64 and 8192x8192, got {text}")
    return width, height


def _positive(kind: type) -> object:
    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {text}")
        return value

    return parse


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="suture-sim", description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--topology",
        required=True,
        choices=TOPOLOGY_CHOICES,
        help="thread topology; 'mixed' cycles through the paper's five (straight to occluded), "
        "'hard' through hooked, wide_occlusion and along_rows",
    )
    parser.add_argument(
        "--frames", type=_positive(int), default=10, help="number of stereo frames (default 10)"
    )
    parser.add_argument(
        "--domain",
        choices=DOMAINS,
        default="legacy",
        help="appearance domain: legacy (offline training), on-site (new endoscope) or random "
        "(domain randomisation: looks, backgrounds, thread colours and widths far wider than both)",
    )
    parser.add_argument(
        "--background",
        choices=BACKGROUNDS,
        default=None,
        help="tissue, phantom or printed (default: tissue for legacy, phantom/printed for on-site)",
    )
    parser.add_argument(
        "--renderer",
        choices=RENDERERS,
        default="raster",
        help="raster (fast, default) or cycles (Blender Cycles, physically based; needs "
        "`bash ros2_ws/setup.sh --with-blender`)",
    )
    parser.add_argument(
        "--samples",
        type=_positive(int),
        default=DEFAULT_SAMPLES,
        help=f"Cycles samples per pixel (default {DEFAULT_SAMPLES}; ignored by the raster renderer)",
    )
    parser.add_argument("--resolution", type=resolution, default=(640, 480), help="WxH (default 640x480)")
    parser.add_argument("--seed", type=int, default=0, help="random seed; the same seed gives the same bag")
    parser.add_argument(
        "--start-index",
        type=_nonnegative_int,
        default=0,
        help="index of the first frame (frames are drawn from seed and index)",
    )
    parser.add_argument("--fx", type=_positive(float), help="focal length in pixels (default 0.8125 * width)")
    parser.add_argument("--fy", type=_positive(float), help="focal length in pixels (default fx)")
    parser.add_argument("--cx", type=float, help="principal point column (default image centre)")
    parser.add_argument("--cy", type=float, help="principal point row (default image centre)")
    parser.add_argument(
        "--baseline",
        type=_positive(float),
        default=0.005,
        help="stereo baseline in metres (default 0.005; endoscopes: 0.004 to 0.006)",
    )
    parser.add_argument("--out", type=Path, help="bag directory to create (rosbag2, MCAP storage)")
    parser.add_argument(
        "--compression-level",
        type=int,
        choices=range(1, 23),
        default=3,
        metavar="1..22",
        help="zstd level of the MCAP chunks (default 3; 19 for small committed bags)",
    )
    parser.add_argument("--png-dir", type=Path, help="also write images/ and masks/ PNG folders here")
    parser.add_argument(
        "--workers", type=_positive(int), default=2, help="processes rendering frames (default 2)"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def _nonnegative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be zero or more, got {text}")
    return value


def camera_from_args(args: argparse.Namespace) -> StereoCamera:
    width, height = args.resolution
    default = StereoCamera.default(width, height, args.baseline)
    fx = args.fx if args.fx is not None else default.fx
    return StereoCamera(
        width,
        height,
        fx,
        args.fy if args.fy is not None else fx,
        args.cx if args.cx is not None else default.cx,
        args.cy if args.cy is not None else default.cy,
        args.baseline,
    )


def run(args: argparse.Namespace) -> list[SimFrame]:
    """Generate and write the frames; returns them (without images kept when many)."""
    config = SimConfig(
        topology=args.topology,
        camera=camera_from_args(args),
        domain=args.domain,
        seed=args.seed,
        background=args.background,
        renderer=args.renderer,
        samples=args.samples,
    )
    indices = range(args.start_index, args.start_index + args.frames)
    frames = generate_frames(config, indices, workers=args.workers)
    if not args.quiet:
        frames = _progress(frames, args.frames)
    summaries = []
    writer = BagWriter(args.out, compression_level=args.compression_level) if args.out is not None else None
    try:
        if writer is not None:
            writer.open()
        for frame in frames:
            if writer is not None:
                write_frame(writer, frame)
            if args.png_dir is not None:
                export_png(frame, args.png_dir)
            summaries.append(frame)
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    if writer is not None:
        writer.close()
    return summaries


def _progress(frames: Iterator[SimFrame], total: int) -> Iterator[SimFrame]:
    from tqdm import tqdm

    return iter(tqdm(frames, total=total, unit="frame", desc="suture-sim", file=sys.stderr))


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.out is None and args.png_dir is None:
        parser.error("nothing to write: give --out BAG and/or --png-dir DIR")
    if args.out is not None and args.out.exists():
        parser.error(f"--out {args.out} exists already; choose a new bag path")
    try:
        frames = run(args)
    except (OSError, BagError) as error:
        print(f"suture-sim: error: {error}", file=sys.stderr)
        return 1
    except (SceneError, CameraModelError, CyclesUnavailableError, ValueError) as error:
        print(f"suture-sim: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("suture-sim: interrupted; the partial bag was removed", file=sys.stderr)
        return 130
    where = " and ".join(str(p) for p in (args.out, args.png_dir) if p is not None)
    print(f"suture-sim: wrote {len(frames)} frames to {where}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
