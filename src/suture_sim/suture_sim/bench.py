# SPDX-License-Identifier: Apache-2.0
"""``suture-sim-bench``: frames per second of the simulator.

Prints two figures for the requested resolution and topology (default ``mixed``):
rendering alone, and the whole ``suture-sim`` job (rendering, bag serialisation
with zstd chunks, disk), both with the given number of worker processes. Example::

    suture-sim-bench --frames 40 --resolution 640x480 --workers 2
    suture-sim-bench --frames 30 --resolution 1280x1024 --topology hard
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from suture_common.bag_io import BagWriter
from suture_common.camera import StereoCamera
from suture_sim.cli import resolution
from suture_sim.output import write_frame
from suture_sim.parallel import generate_frames
from suture_sim.scene import DOMAINS, TOPOLOGY_CHOICES, SimConfig


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="suture-sim-bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--resolution", type=resolution, default=(640, 480))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--domain", default="legacy", choices=DOMAINS)
    parser.add_argument("--topology", default="mixed", choices=TOPOLOGY_CHOICES)
    args = parser.parse_args(argv)
    config = SimConfig(
        topology=args.topology, camera=StereoCamera.default(*args.resolution), domain=args.domain, seed=7
    )
    list(generate_frames(config, range(2), workers=1))  # warm caches and imports

    start = time.perf_counter()
    for _ in generate_frames(config, range(args.frames), workers=args.workers):
        pass
    render_fps = args.frames / (time.perf_counter() - start)

    with tempfile.TemporaryDirectory() as scratch:
        start = time.perf_counter()
        with BagWriter(Path(scratch) / "bench") as writer:
            for frame in generate_frames(config, range(args.frames), workers=args.workers):
                write_frame(writer, frame)
        total_fps = args.frames / (time.perf_counter() - start)

    width, height = args.resolution
    print(
        f"suture-sim-bench: {width}x{height}, {args.domain}, {args.topology}, {args.frames} frames, "
        f"{args.workers} worker(s)"
    )
    print(f"  rendering only : {render_fps:6.1f} stereo frames/s")
    print(f"  rendering + bag: {total_fps:6.1f} stereo frames/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
