# SPDX-License-Identifier: Apache-2.0
"""suture-import: simulator frames distorted with a known stereo calibration come back rectified.

The simulator renders rectified frames of a known camera. Here they are turned into what a
real endoscope records: each view seen by a raw camera with its own intrinsics, non-zero
distortion and a rotation away from the rectified frame. Importing those raw frames with the
calibration must give back the simulator's frames, within 0.5 px where the thread is, up to
the intrinsics that ``stereoRectify`` chooses (an affine map of the image plane, known from
the imported camera_info).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from skimage.registration import phase_cross_correlation

from suture_bench.frames import read_frames
from suture_common import messages
from suture_common.bag_io import BagWriter
from suture_common.camera import StereoCamera
from suture_replay.calibration import UNDISTORT_CRITERIA, Rectifier, load_opencv_stereo
from suture_replay.importer import main
from suture_segmentation.metrics import score_mask
from suture_sim.scene import SimConfig, generate_frame

CAMERA = StereoCamera.default(320, 240)
SIZE = (CAMERA.width, CAMERA.height)
VIEWS = ("left", "right")
HALF_TURN = cv2.Rodrigues(np.array([0.03, -0.02, 0.015]))[0]
#: raw camera -> rectified frame rotation of each view (OpenCV's R1, R2)
RECTIFYING = {"left": HALF_TURN.T, "right": HALF_TURN}
RAW_K = {
    "left": np.array([[CAMERA.fx * 1.03, 0, CAMERA.cx + 4], [0, CAMERA.fy * 1.03, CAMERA.cy - 3], [0, 0, 1]]),
    "right": np.array(
        [[CAMERA.fx * 0.98, 0, CAMERA.cx - 5], [0, CAMERA.fy * 0.98, CAMERA.cy + 2], [0, 0, 1]]
    ),
}
RAW_D = {
    "left": np.array([-0.12, 0.05, 0.001, -0.0015, 0.0]),
    "right": np.array([0.08, -0.03, -0.001, 0.001, 0.0]),
}
#: the right raw camera from the left one: x_right = R x_left + T (not identity, not zero)
R = RECTIFYING["right"].T @ RECTIFYING["left"]
T = -RECTIFYING["right"].T @ np.array([CAMERA.baseline, 0.0, 0.0])


def raw_to_simulator(view: str, raw_uv: np.ndarray) -> np.ndarray:
    """(N, 2) raw pixels of ``view`` -> the simulator's rectified pixels they see."""
    points = np.asarray(raw_uv, np.float64).reshape(-1, 1, 2)
    return cv2.undistortPoints(
        points, RAW_K[view], RAW_D[view], R=RECTIFYING[view], P=CAMERA.K, criteria=UNDISTORT_CRITERIA
    ).reshape(-1, 2)


def simulator_to_raw(view: str, uv: np.ndarray) -> np.ndarray:
    """(N, 2) simulator pixels -> the raw pixels that see them."""
    x, y = CAMERA.rays(uv[:, 0], uv[:, 1])
    rays = np.column_stack([x, y, np.ones(len(uv))])
    rotation = cv2.Rodrigues(RECTIFYING[view].T)[0]
    raw, _ = cv2.projectPoints(rays, rotation, np.zeros(3), RAW_K[view], RAW_D[view])
    return raw.reshape(-1, 2)


def distort(view: str, image: np.ndarray) -> np.ndarray:
    """What the raw camera of ``view`` records of a simulator image."""
    u, v = np.meshgrid(np.arange(SIZE[0], dtype=np.float64), np.arange(SIZE[1], dtype=np.float64))
    source = raw_to_simulator(view, np.column_stack([u.ravel(), v.ravel()])).astype(np.float32)
    map_x, map_y = source[:, 0].reshape(u.shape), source[:, 1].reshape(u.shape)
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Two simulator frames and their raw recording: image folders (named by stamp), hand-drawn
    masks, a tip-hint CSV and an OpenCV stereo YAML."""
    root = tmp_path_factory.mktemp("raw")
    config = SimConfig(topology="curved", camera=CAMERA, seed=2202)
    frames = [generate_frame(config, index) for index in range(2)]
    hints = ["stamp_ns,u,v"]
    for frame in frames:
        for view in VIEWS:
            image = cv2.cvtColor(distort(view, getattr(frame, f"{view}_image")), cv2.COLOR_RGB2BGR)
            mask = np.where(distort(view, getattr(frame, f"{view}_mask")) >= 128, 255, 0).astype(np.uint8)
            for folder, array in ((view, image), (f"{view}_masks", mask)):
                (root / folder).mkdir(exist_ok=True)
                cv2.imwrite(str(root / folder / f"{view}_{frame.stamp_ns}.png"), array)
        u, v = simulator_to_raw("left", frame.tip_hint[None])[0]
        hints.append(f"{frame.stamp_ns},{u},{v}")
    (root / "tips.csv").write_text("\n".join(hints) + "\n")
    storage = cv2.FileStorage(str(root / "stereo.yaml"), cv2.FILE_STORAGE_WRITE)
    for name, value in (("K1", RAW_K["left"]), ("K2", RAW_K["right"]), ("R", R)):
        storage.write(name, value)
    for name, value in (("D1", RAW_D["left"]), ("D2", RAW_D["right"]), ("T", T)):
        storage.write(name, value.reshape(-1, 1))
    storage.write("image_width", SIZE[0])
    storage.write("image_height", SIZE[1])
    storage.release()
    return root, frames


def affine_to(camera: StereoCamera) -> np.ndarray:
    """(2, 3): simulator pixel -> pixel of the same ray in a rectified camera with the same rotation."""
    return (camera.K @ np.linalg.inv(CAMERA.K))[:2]


def apply(affine: np.ndarray, uv: np.ndarray) -> np.ndarray:
    return uv @ affine[:, :2].T + affine[:, 2]


def image_shift_on_thread(bag: Path, frames) -> dict[str, float]:
    """The imported frames against the simulator's (moved by the intrinsics' affine map): the
    largest sub-pixel shift of the image around the thread (phase correlation upsampled 20
    times), the largest mean colour difference there (grey levels, RGB channel by channel), the
    smallest centreline recall or precision (1 px) of the imported hand-drawn masks, the largest
    tip-hint error."""
    imported = list(read_frames(bag, images=True, complete=False))
    assert [f.stamp_ns for f in imported] == [f.stamp_ns for f in frames]  # stamps from the source
    camera = imported[0].camera
    assert camera.baseline == pytest.approx(CAMERA.baseline, rel=1e-9)
    affine = affine_to(camera)
    worst = {"shift_px": 0.0, "colour": 0.0, "mask_centreline": 1.0, "tip_px": 0.0}
    for truth, got in zip(frames, imported, strict=True):
        for view in VIEWS:
            thread = apply(affine, np.argwhere(getattr(truth, f"{view}_mask") > 0)[:, ::-1].astype(float))
            (x0, y0), (x1, y1) = thread.min(axis=0).astype(int) - 8, thread.max(axis=0).astype(int) + 8
            crop = (slice(max(y0, 0), min(y1, SIZE[1])), slice(max(x0, 0), min(x1, SIZE[0])))
            expected = cv2.warpAffine(getattr(truth, f"{view}_image"), affine, SIZE, flags=cv2.INTER_LINEAR)
            grey = [
                cv2.cvtColor(image[crop], cv2.COLOR_RGB2GRAY).astype(np.float32)
                for image in (expected, getattr(got, f"{view}_image"))
            ]
            shift, _, _ = phase_cross_correlation(grey[0], grey[1], upsample_factor=20)
            worst["shift_px"] = max(worst["shift_px"], float(np.hypot(*shift)))
            colour = np.abs(expected[crop].astype(float) - getattr(got, f"{view}_image")[crop]).mean(
                axis=(0, 1)
            )
            worst["colour"] = max(worst["colour"], float(colour.max()))
            got_mask = getattr(got, f"true_{view}_mask")
            if got_mask is not None:
                expected_mask = cv2.warpAffine(getattr(truth, f"{view}_mask"), affine, SIZE) >= 128
                scores = score_mask(got_mask, expected_mask)
                worst["mask_centreline"] = min(
                    worst["mask_centreline"], scores.centreline_recall, scores.centreline_precision
                )
        if got.tip_hint is not None:
            tip_error = np.hypot(*(got.tip_hint - apply(affine, truth.tip_hint[None])[0]))
            worst["tip_px"] = max(worst["tip_px"], float(tip_error))
    return worst


def map_error_on_thread(rectifier: Rectifier, frames) -> float:
    """Largest distance (px) between the simulator pixel that an imported pixel on the thread
    shows (through the import's maps and the recording's distortion) and the one it should."""
    affine = np.vstack([affine_to(rectifier.camera), [0, 0, 1]])
    back = np.linalg.inv(affine)[:2]
    worst = 0.0
    for frame in frames:
        for view in VIEWS:
            thread = np.argwhere(getattr(frame, f"{view}_mask") > 0)[:, ::-1].astype(float)
            pixels = np.unique(np.rint(apply(affine[:2], thread)).astype(int), axis=0)
            map_x, map_y = rectifier.maps[view]
            raw = np.column_stack([map_x[pixels[:, 1], pixels[:, 0]], map_y[pixels[:, 1], pixels[:, 0]]])
            error = raw_to_simulator(view, raw) - apply(back, pixels.astype(float))
            worst = max(worst, float(np.max(np.linalg.norm(error, axis=1))))
    return worst


def test_image_folders_with_an_opencv_calibration_come_back_rectified(recording, tmp_path, capsys):
    root, frames = recording
    out = tmp_path / "imported"
    arguments = ["--left", str(root / "left"), "--right", str(root / "right")]
    arguments += ["--calibration", str(root / "stereo.yaml"), "--tip-hints", str(root / "tips.csv")]
    arguments += ["--left-masks", str(root / "left_masks"), "--right-masks", str(root / "right_masks")]
    assert main([*arguments, "--out", str(out), "--png-dir", str(tmp_path / "png")]) == 0, (
        capsys.readouterr().err
    )
    assert "2 stereo pairs" in capsys.readouterr().out
    # the labelled views as training folders for suture-seg finetune: same names in both
    images, masks = (
        sorted(p.name for p in (tmp_path / "png" / sub).iterdir()) for sub in ("images", "masks")
    )
    assert images == masks and len(images) == 4
    rectifier = Rectifier(load_opencv_stereo(root / "stereo.yaml"), SIZE)
    assert map_error_on_thread(rectifier, frames) < 0.5
    worst = image_shift_on_thread(out, frames)
    assert worst["shift_px"] < 0.25 and worst["colour"] < 4 and worst["mask_centreline"] > 0.95, worst
    assert worst["tip_px"] < 0.05, worst
    # the raw frames themselves are far from the simulator's: the checks can fail
    raw = cv2.imread(str(root / "left_masks" / f"left_{frames[0].stamp_ns}.png"), cv2.IMREAD_GRAYSCALE) > 0
    truth = frames[0].left_mask > 0
    assert np.sum(raw & truth) / np.sum(raw | truth) < 0.5


def test_a_raw_topic_bag_with_its_camera_info_comes_back_rectified(recording, tmp_path, capsys):
    root, frames = recording
    bag = tmp_path / "raw_bag"
    with BagWriter(bag) as writer:
        for frame in frames:
            stamp = frame.stamp_ns
            for view in VIEWS:
                raw = cv2.imread(str(root / view / f"{view}_{stamp}.png"))
                frame_id = f"{view}_camera_optical_frame"
                image = messages.image_message(raw, "bgr8", stamp, frame_id)
                writer.write(f"/endoscope/{view}/image_raw", image, stamp)
                # as camera_calibration writes it: raw K and D, rectifying R, rectified P
                info = messages.camera_info_message(CAMERA, view, stamp, frame_id)
                info.k, info.d, info.r = RAW_K[view].ravel(), RAW_D[view], RECTIFYING[view].ravel()
                writer.write(f"/endoscope/{view}/camera_info", info, stamp)
        # a left image whose right partner was dropped by the recorder: skipped and counted
        lonely = frames[-1].stamp_ns + 1
        writer.write("/endoscope/left/image_raw", messages.image_message(raw, "bgr8", lonely, "left"), lonely)
    out = tmp_path / "imported"
    arguments = ["--bag", str(bag), "--out", str(out)]
    for view in VIEWS:
        arguments += [f"--{view}-topic", f"/endoscope/{view}/image_raw"]
        arguments += [f"--{view}-info-topic", f"/endoscope/{view}/camera_info"]
        arguments += [f"--{view}-masks", str(root / f"{view}_masks")]  # matched by stamp
    wrong_topic = [a.replace("right/image_raw", "right/image_rect") for a in arguments]
    assert main(wrong_topic) == 1
    assert "has no messages on /endoscope/right/image_rect" in capsys.readouterr().err
    assert main(arguments) == 0, capsys.readouterr().err
    assert "1 unpaired image(s) skipped" in capsys.readouterr().out
    (camera,) = {f.camera for f in read_frames(out, images=False, complete=False)}
    assert camera == CAMERA  # the given rectification, exactly
    worst = image_shift_on_thread(out, frames)
    assert worst["shift_px"] < 0.25 and worst["colour"] < 4 and worst["mask_centreline"] > 0.95, worst


def test_bad_recordings_fail_with_one_line(recording, tmp_path, capsys):
    root, _ = recording
    small = tmp_path / "small"
    small.mkdir()
    cv2.imwrite(str(small / "left_1.png"), np.zeros((120, 160, 3), np.uint8))
    alone = tmp_path / "alone"
    alone.mkdir()
    cv2.imwrite(str(alone / "right_1.png"), np.zeros((120, 160, 3), np.uint8))
    cv2.imwrite(str(alone / "right_2.png"), np.zeros((120, 160, 3), np.uint8))
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "left_1.png").write_bytes(b"not a png")
    calibration = ["--calibration", str(root / "stereo.yaml")]
    cases = {
        "is for 320x240 images but the images are 160x120": ["--left", str(small), "--right", str(small)],
        "missing pairs": ["--left", str(small), "--right", str(alone)],
        "cannot read image": ["--left", str(broken), "--right", str(broken)],
    }
    for expected, arguments in cases.items():
        out = tmp_path / "never"
        assert main([*arguments, *calibration, "--out", str(out)]) == 1
        error = capsys.readouterr().err.strip().splitlines()
        assert len(error) == 1 and expected in error[0], error
        assert not out.exists()
    assert main(["--left", str(small), "--right", str(small), "--out", str(tmp_path / "x")]) == 1
    assert "need a calibration" in capsys.readouterr().err
    assert (
        main(
            [
                "--left",
                str(root / "left"),
                "--right",
                str(root / "right"),
                "--calibration",
                str(root / "missing.yaml"),
                "--out",
                str(tmp_path / "y"),
            ]
        )
        == 1
    )
    assert "does not exist" in capsys.readouterr().err
