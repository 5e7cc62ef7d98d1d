# SPDX-License-Identifier: Apache-2.0
"""``suture-import``: raw stereo recordings from a real endoscope into a bag of docs/interfaces.md.

Sources (one of):

* ``--left DIR --right DIR``: two folders of images (png, jpg, bmp, tif). Pairs are matched
  by the last number in the file names (``left_0012.png`` with ``right_0012.png``) when every
  name has a distinct one, else by sorted order. A name whose partner is missing is an error.
* ``--left VIDEO --right VIDEO``: two video files, frame by frame (equal frame counts).
* ``--bag BAG``: a rosbag2 bag with raw image topics (sensor_msgs/Image or CompressedImage)
  and, unless a calibration file is given, their camera_info topics; paired by exact header
  stamp (an image without a partner is skipped and counted).

Calibration (``suture_replay.calibration``): ``--calibration stereo.yaml`` (OpenCV: K1 D1 K2 D2
R T), ``--camera-info left.yaml right.yaml`` (ROS ``camera_calibration``), or the bag's raw
camera_info messages.

Output: a bag with the rectified images (rgb8) on ``/stereo/{left,right}/image_rect``, the
rectified camera_info, and, when given, tip hints (``--tip-hints CSV``: a header ``frame,u,v``
or ``stamp_ns,u,v``; ``frame`` is the pair's number, see below; u, v pixels of the raw left
image, rectified with the same maps) and hand-drawn masks (``--left-masks DIR``,
``--right-masks DIR``: 0 = background, non-zero = suture; rectified with the same maps,
written as ``/ground_truth/{left,right}/mask``). ``--png-dir DIR`` also writes every rectified
view that has a mask as ``DIR/images/<stamp>_<view>.png`` and ``DIR/masks/<stamp>_<view>.png``,
the folders ``suture-seg finetune --images --masks`` trains on.

A pair's *number*: for folders paired by name, the number in the names; otherwise its index
from 0. Masks are matched to pairs by the last number in their file names: the pair's number
or its stamp in nanoseconds.

Stamps: a bag's header stamps; a video's position (``CAP_PROP_POS_MSEC``) from ``--start-ns``;
for folders the number in the names when it has 16 or more digits (nanoseconds), else
``--start-ns`` + index / ``--fps``.

Exit status 0, or 1 with one line on standard error naming the problem.
"""

from __future__ import annotations

import argparse
import csv
import re
import sys
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from suture_common import messages, topics
from suture_common.bag_io import BagMessage, BagWriter, bag_summary, read_messages
from suture_common.camera import StereoCamera
from suture_common.image_files import image_files
from suture_common.stamp_buffer import StampPairBuffer
from suture_replay.calibration import (
    Rectifier,
    StereoCalibration,
    from_camera_info_messages,
    load_camera_info_yamls,
    load_opencv_stereo,
)

DEFAULT_START_NS = 1_700_000_000_000_000_000
NANOSECOND_DIGITS = 16
PAIRING_WINDOW = 30
"""Images of one view that may wait for the other view's image of their stamp."""


class RecordingError(ValueError):
    """The recording cannot be imported; the text names the file and the problem."""


@dataclass
class RawPair:
    """One raw stereo pair: ``number`` (see module docstring), ``stamp_ns``, RGB uint8 images."""

    number: int
    stamp_ns: int
    left: np.ndarray
    right: np.ndarray


def _last_number(path: Path) -> int | None:
    numbers = re.findall(r"\d+", path.stem)
    return int(numbers[-1]) if numbers else None


def _read_image(path: Path) -> np.ndarray:
    """An RGB uint8 image (grey images become three equal channels)."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise RecordingError(f"cannot read image {path} (missing, unreadable or not an image)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def pair_files(left: list[Path], right: list[Path]) -> list[tuple[int, Path, Path]]:
    """``(number, left, right)`` pairs: by the last number in the names where that is unambiguous,
    else by sorted order; a missing partner raises :class:`RecordingError`."""
    left_numbers = [_last_number(p) for p in left]
    right_numbers = [_last_number(p) for p in right]
    if None not in left_numbers + right_numbers and (
        len(set(left_numbers)) == len(left) and len(set(right_numbers)) == len(right)
    ):
        by_number = dict(zip(right_numbers, right, strict=True))
        lone_left = [p.name for p, n in zip(left, left_numbers, strict=True) if n not in by_number]
        lone_right = sorted(set(right_numbers) - set(left_numbers))
        if lone_left or lone_right:
            names = lone_left[:3] + [by_number[n].name for n in lone_right[:3]]
            raise RecordingError(
                f"missing pairs: {len(lone_left)} left and {len(lone_right)} right image(s) have no partner "
                f"with the same number (e.g. {', '.join(names)})"
            )
        return sorted((n, p, by_number[n]) for p, n in zip(left, left_numbers, strict=True))
    if len(left) != len(right):
        raise RecordingError(
            f"missing pairs: {len(left)} left but {len(right)} right images, and the names carry no "
            "distinct frame numbers to match them by"
        )
    return [(index, a, b) for index, (a, b) in enumerate(zip(left, right, strict=True))]


def folder_pairs(left: Path, right: Path, fps: float, start_ns: int) -> Iterator[RawPair]:
    pairs = pair_files(image_files(left, "left", RecordingError), image_files(right, "right", RecordingError))
    stamps_in_names = all(len(str(number)) >= NANOSECOND_DIGITS for number, _, _ in pairs) and len(pairs) > 0
    for index, (number, left_file, right_file) in enumerate(pairs):
        stamp = number if stamps_in_names else start_ns + round(index * 1e9 / fps)
        yield RawPair(number, stamp, _read_image(left_file), _read_image(right_file))


def video_pairs(left: Path, right: Path, start_ns: int) -> Iterator[RawPair]:
    captures = []
    for path in (left, right):
        if not path.is_file():
            raise RecordingError(f"video {path} does not exist")
        capture = cv2.VideoCapture(str(path))
        if not capture.isOpened():
            raise RecordingError(f"cannot open video {path} (unreadable or an unsupported codec)")
        captures.append(capture)
    index = 0
    try:
        while True:
            position_ms = captures[0].get(cv2.CAP_PROP_POS_MSEC)
            (ok_left, frame_left), (ok_right, frame_right) = captures[0].read(), captures[1].read()
            if not ok_left and not ok_right:
                break
            if ok_left != ok_right:
                shorter = right if ok_left else left
                raise RecordingError(
                    f"missing pairs: video {shorter} ends after {index} frames, the other goes on"
                )
            stamp = start_ns + round(position_ms * 1e6)
            rgb = [cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in (frame_left, frame_right)]
            yield RawPair(index, stamp, rgb[0], rgb[1])
            index += 1
    finally:
        for capture in captures:
            capture.release()
    if index == 0:
        raise RecordingError(f"video {left} has no frames")


def _decode(message: Any, msgtype: str, topic: str) -> np.ndarray:
    if msgtype == "sensor_msgs/msg/CompressedImage":
        image = cv2.imdecode(np.asarray(message.data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise RecordingError(f"{topic}: a compressed image ({message.format}) cannot be decoded")
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    try:
        return messages.image_to_rgb(message)
    except messages.MessageConversionError as error:
        raise RecordingError(f"{topic}: {error}") from error


@dataclass
class BagSource:
    """A bag's raw image and camera_info topics."""

    path: Path
    left_topic: str = "/stereo/left/image_raw"
    right_topic: str = "/stereo/right/image_raw"
    left_info_topic: str = "/stereo/left/camera_info"
    right_info_topic: str = "/stereo/right/camera_info"
    unpaired: int = 0

    def calibration(self, units: str) -> StereoCalibration:
        """The first raw camera_info of each side."""
        found: dict[str, Any] = {}
        for record in read_messages(self.path, [self.left_info_topic, self.right_info_topic]):
            found.setdefault(record.topic, record.message)
            if len(found) == 2:
                break
        missing = [t for t in (self.left_info_topic, self.right_info_topic) if t not in found]
        if missing:
            raise RecordingError(
                f"{self.path} has no camera_info on {', '.join(missing)}; name the topics "
                "(--left-info-topic, --right-info-topic) or give --calibration / --camera-info"
            )
        return from_camera_info_messages(
            found[self.left_info_topic], found[self.right_info_topic], units, f"{self.path} camera_info"
        )

    def pairs(self) -> Iterator[RawPair]:
        """Left and right images with the same header stamp, decoded as RGB, in bag order.

        Images wait for their partner in a bounded buffer (a bag records both views of a stamp
        close together); the ones that never find it are counted in ``unpaired``.
        """
        recorded = bag_summary(self.path)
        for topic in (self.left_topic, self.right_topic):
            if not recorded.get(topic, ("", 0))[1]:
                raise RecordingError(f"{self.path} has no messages on {topic}; name the raw image topics")
        waiting: StampPairBuffer[BagMessage] = StampPairBuffer(capacity=PAIRING_WINDOW)
        index = 0
        for record in read_messages(self.path, [self.left_topic, self.right_topic]):
            stamp = messages.ns_from_stamp(record.message.header.stamp)
            side = "left" if record.topic == self.left_topic else "right"
            pair = waiting.add(side, stamp, record)
            if pair is not None:
                left, right = (_decode(r.message, r.msgtype, r.topic) for r in pair)
                yield RawPair(index, stamp, left, right)
                index += 1
        self.unpaired = waiting.dropped + sum(len(waiting.pending(side)) for side in ("left", "right"))


def read_tip_hints(path: Path) -> dict[tuple[str, int], np.ndarray]:
    """``{("frame" | "stamp_ns", key): (u, v)}`` of a tip-hint CSV (raw left pixels)."""
    try:
        with open(path, newline="") as stream:
            rows = list(csv.DictReader(stream))
    except OSError as error:
        raise RecordingError(f"cannot read tip hints {path}: {error.strerror or error}") from error
    hints = {}
    for line, row in enumerate(rows, start=2):
        key = "frame" if "frame" in row else "stamp_ns" if "stamp_ns" in row else None
        if key is None or "u" not in row or "v" not in row:
            raise RecordingError(f"{path}: needs a header 'frame,u,v' or 'stamp_ns,u,v'")
        try:
            hints[(key, int(row[key]))] = np.array([float(row["u"]), float(row["v"])])
        except (TypeError, ValueError) as error:
            raise RecordingError(f"{path} line {line}: {key}, u and v must be numbers") from error
    return hints


def mask_files(folder: Path | None, what: str) -> dict[int, Path]:
    """Mask files by the last number in their names."""
    if folder is None:
        return {}
    files = image_files(folder, what, RecordingError)
    by_number: dict[int, Path] = {}
    for path in files:
        number = _last_number(path)
        if number is None:
            raise RecordingError(f"mask {path} has no frame number in its name")
        if number in by_number:
            raise RecordingError(
                f"masks {by_number[number].name} and {path.name} carry the same frame number"
            )
        by_number[number] = path
    return by_number


@dataclass
class ImportSummary:
    """What :func:`import_recording` wrote."""

    frames: int
    masks: int
    tip_hints: int
    camera: StereoCamera


def import_recording(
    pairs: Iterator[RawPair],
    calibration: StereoCalibration,
    out: Path,
    alpha: float = 0.0,
    tip_hints: dict[tuple[str, int], np.ndarray] | None = None,
    left_masks: dict[int, Path] | None = None,
    right_masks: dict[int, Path] | None = None,
    limit: int | None = None,
    png_dir: Path | None = None,
) -> ImportSummary:
    """Rectify the raw pairs and write the bag at ``out`` (removed again on any error); with
    ``png_dir``, also the rectified views with masks as training folders."""
    tip_hints, left_masks, right_masks = tip_hints or {}, left_masks or {}, right_masks or {}
    rectifier: Rectifier | None = None
    counts = Counter()
    with BagWriter(out) as writer:
        for pair in pairs:
            if limit is not None and counts["frames"] >= limit:
                break
            size = (pair.left.shape[1], pair.left.shape[0])
            if pair.right.shape != pair.left.shape:
                raise RecordingError(
                    f"pair {pair.number}: left is {size[0]}x{size[1]} but right "
                    f"{pair.right.shape[1]}x{pair.right.shape[0]}"
                )
            if rectifier is None:
                rectifier = Rectifier(calibration, size, alpha)
            elif size != rectifier.size:
                raise RecordingError(
                    f"pair {pair.number} is {size[0]}x{size[1]}, the first pair {rectifier.size}"
                )
            _write_pair(writer, rectifier, pair, tip_hints, left_masks, right_masks, counts, png_dir)
            counts["frames"] += 1
        if rectifier is None:
            raise RecordingError("no stereo pairs to import")
    return ImportSummary(counts["frames"], counts["masks"], counts["tip_hints"], rectifier.camera)


def _write_pair(
    writer: BagWriter,
    rectifier: Rectifier,
    pair: RawPair,
    tip_hints: dict[tuple[str, int], np.ndarray],
    left_masks: dict[int, Path],
    right_masks: dict[int, Path],
    counts: Counter,
    png_dir: Path | None,
) -> None:
    stamp = pair.stamp_ns
    frames = {"left": topics.LEFT_FRAME, "right": topics.RIGHT_FRAME}
    image_topics = {"left": topics.LEFT_IMAGE, "right": topics.RIGHT_IMAGE}
    info_topics = {"left": topics.LEFT_CAMERA_INFO, "right": topics.RIGHT_CAMERA_INFO}
    mask_topics = {"left": topics.GT_LEFT_MASK, "right": topics.GT_RIGHT_MASK}
    for view, raw in (("left", pair.left), ("right", pair.right)):
        info = messages.camera_info_message(rectifier.camera, view, stamp, frames[view])
        writer.write(info_topics[view], info, stamp)
        rectified_image = rectifier.image(view, raw)
        image = messages.image_message(rectified_image, "rgb8", stamp, frames[view])
        writer.write(image_topics[view], image, stamp)
        masks = left_masks if view == "left" else right_masks
        mask_file = masks.get(pair.number, masks.get(pair.stamp_ns))
        if mask_file is not None:
            raw_mask = cv2.imread(str(mask_file), cv2.IMREAD_GRAYSCALE)
            if raw_mask is None:
                raise RecordingError(f"cannot read mask {mask_file}")
            if raw_mask.shape != raw.shape[:2]:
                raise RecordingError(
                    f"mask {mask_file} is {raw_mask.shape[1]}x{raw_mask.shape[0]}, its image "
                    f"{raw.shape[1]}x{raw.shape[0]}"
                )
            rectified_mask = rectifier.mask(view, raw_mask)
            writer.write(
                mask_topics[view], messages.image_message(rectified_mask, "mono8", stamp, frames[view]), stamp
            )
            counts["masks"] += 1
            if png_dir is not None:
                _write_png(
                    png_dir / "images" / f"{stamp}_{view}.png",
                    cv2.cvtColor(rectified_image, cv2.COLOR_RGB2BGR),
                )
                _write_png(png_dir / "masks" / f"{stamp}_{view}.png", rectified_mask)
    hint = tip_hints.get(("frame", pair.number), tip_hints.get(("stamp_ns", stamp)))
    if hint is not None:
        u, v = rectifier.points("left", hint[None])[0]
        writer.write(
            topics.TIP_HINT, messages.point_message(np.array([u, v, 0.0]), stamp, frames["left"]), stamp
        )
        counts["tip_hints"] += 1


def _write_png(path: Path, array: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), array):
        raise RecordingError(f"cannot write {path}")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="suture-import",
        description="Rectify raw stereo endoscope recordings (image folders, videos or a bag with raw "
        "topics) with their calibration into a bag of the pipeline's interface contract.",
    )
    source = parser.add_argument_group("source (either --left/--right or --bag)")
    source.add_argument("--left", type=Path, help="folder of left images, or a left video")
    source.add_argument("--right", type=Path, help="folder of right images, or a right video")
    source.add_argument("--bag", type=Path, help="rosbag2 bag with raw image topics")
    source.add_argument("--left-topic", default="/stereo/left/image_raw", help="raw left image topic")
    source.add_argument("--right-topic", default="/stereo/right/image_raw", help="raw right image topic")
    source.add_argument("--left-info-topic", default="/stereo/left/camera_info", help="raw left camera_info")
    source.add_argument(
        "--right-info-topic", default="/stereo/right/camera_info", help="raw right camera_info"
    )
    calibration = parser.add_argument_group("calibration (a bag's camera_info when neither is given)")
    calibration.add_argument("--calibration", type=Path, help="OpenCV stereo YAML: K1 D1 K2 D2 R T")
    calibration.add_argument(
        "--camera-info",
        type=Path,
        nargs=2,
        metavar=("LEFT_YAML", "RIGHT_YAML"),
        help="the two camera_info YAMLs of ROS camera_calibration",
    )
    calibration.add_argument(
        "--calibration-units", choices=("m", "mm"), default="m", help="unit of the translation (default m)"
    )
    calibration.add_argument(
        "--alpha",
        type=float,
        default=0.0,
        help="stereoRectify's free scaling: 0 every rectified pixel valid (default), 1 every raw pixel kept",
    )
    parser.add_argument("--tip-hints", type=Path, help="CSV 'frame,u,v' or 'stamp_ns,u,v' in raw left pixels")
    parser.add_argument(
        "--left-masks", type=Path, help="folder of hand-drawn left masks (frame number in names)"
    )
    parser.add_argument("--right-masks", type=Path, help="folder of hand-drawn right masks")
    parser.add_argument("--fps", type=float, default=30.0, help="frame rate of image folders (default 30)")
    parser.add_argument(
        "--start-ns", type=int, default=DEFAULT_START_NS, help="first stamp of folders and videos"
    )
    parser.add_argument("--limit", type=int, help="import at most N pairs")
    parser.add_argument(
        "--png-dir", type=Path, help="also write the rectified views with masks as images/ and masks/ PNGs"
    )
    parser.add_argument("--out", type=Path, required=True, help="bag to write (a new directory)")
    return parser


def _calibration(args: argparse.Namespace, bag: BagSource | None) -> StereoCalibration:
    if args.calibration and args.camera_info:
        raise RecordingError("give --calibration or --camera-info, not both")
    if args.calibration:
        return load_opencv_stereo(args.calibration, args.calibration_units)
    if args.camera_info:
        return load_camera_info_yamls(*args.camera_info, units=args.calibration_units)
    if bag is None:
        raise RecordingError("image folders and videos need a calibration: --calibration or --camera-info")
    return bag.calibration(args.calibration_units)


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        bag = None
        if args.bag is not None:
            if args.left or args.right:
                raise RecordingError("give either --bag or --left/--right, not both")
            bag = BagSource(
                args.bag, args.left_topic, args.right_topic, args.left_info_topic, args.right_info_topic
            )
            pairs = bag.pairs()
        elif args.left is None or args.right is None:
            raise RecordingError("give --left and --right (folders or videos), or --bag")
        elif args.left.is_dir() or args.right.is_dir():
            pairs = folder_pairs(args.left, args.right, args.fps, args.start_ns)
        else:
            pairs = video_pairs(args.left, args.right, args.start_ns)
        calibration = _calibration(args, bag)
        summary = import_recording(
            pairs,
            calibration,
            args.out,
            alpha=args.alpha,
            tip_hints=read_tip_hints(args.tip_hints) if args.tip_hints else None,
            left_masks=mask_files(args.left_masks, "left mask"),
            right_masks=mask_files(args.right_masks, "right mask"),
            limit=args.limit,
            png_dir=args.png_dir,
        )
    except (ValueError, OSError) as error:  # RecordingError, CalibrationError, BagError...
        print(f"suture-import: error: {error}", file=sys.stderr)
        return 1
    camera = summary.camera
    unpaired = f", {bag.unpaired} unpaired image(s) skipped" if bag is not None and bag.unpaired else ""
    print(
        f"suture-import: {summary.frames} stereo pairs -> {args.out} ({camera.width}x{camera.height}, "
        f"fx {camera.fx:.1f} px, baseline {1000 * camera.baseline:.2f} mm; {summary.masks} masks, "
        f"{summary.tip_hints} tip hints{unpaired})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
