# SPDX-License-Identifier: Apache-2.0
"""Stereo calibration files and the rectification of raw endoscope frames, as ROS ``image_proc`` does.

A calibration is read from one of:

* an OpenCV stereo YAML (``cv::FileStorage``, as OpenCV's ``stereo_calib`` sample writes it):
  ``K1 D1 K2 D2 R T`` (``R``, ``T``: the right camera from the left, x_right = R x_left + T),
  optionally ``R1 R2 P1 P2`` (a rectification already computed; used as given) and the image
  size (``image_width``/``image_height``, or ``image_size``/``imageSize`` as [w, h]);
* the two ``camera_info`` YAMLs that ROS ``camera_calibration`` writes (``image_width``,
  ``image_height``, ``camera_matrix``, ``distortion_model``, ``distortion_coefficients``,
  ``rectification_matrix``, ``projection_matrix``); their R and P are the rectification;
* the raw ``camera_info`` messages of a bag (same fields).

Without R1 R2 P1 P2, the rectification comes from OpenCV's ``stereoRectify`` with zero
disparity at infinity (``CALIB_ZERO_DISPARITY``) and the given ``alpha`` (0: every rectified
pixel valid, 1: every raw pixel kept). The maps are ``initUndistortRectifyMap(K, D, R, P)``
of each view, as ``image_proc``'s rectify node builds them; masks go through the same maps.
Distortion models: ``plumb_bob`` and ``rational_polynomial`` (OpenCV's 5, 8, 12 or 14
coefficients) and ``equidistant`` (OpenCV's fisheye model, 4 coefficients).

Translation units: the contract's camera_info is in metres; an OpenCV calibration made with
the chessboard square in millimetres has T in millimetres (``units="mm"``). A baseline above
:data:`MAX_BASELINE_M` is refused with that hint.

Every problem raises :class:`CalibrationError`, whose text names the file and the fix.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from suture_common.camera import CameraModelError, StereoCamera

MAX_BASELINE_M = 0.2
"""A stereo endoscope's baseline is millimetres; more than this means the units are wrong."""
MIN_VALID_SHARE = 0.5
"""Share of each rectified image that must map into its raw image, else the calibration does not fit."""
VIEWS = ("left", "right")
_MODELS = ("plumb_bob", "rational_polynomial", "equidistant")
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
"""Iterations of ``undistortPoints`` to convergence (OpenCV's default 5 leave ~0.1 px near the corners)."""


class CalibrationError(ValueError):
    """A calibration cannot be read or does not fit the images; the text says which and why."""


@dataclass(frozen=True)
class CameraCalibration:
    """One raw camera: intrinsics ``k`` (3, 3), distortion ``d`` (N,) of ``model``; and, when known,
    its rectification ``r`` (3, 3) and rectified projection ``p`` (3, 4)."""

    k: np.ndarray
    d: np.ndarray
    model: str = "plumb_bob"
    r: np.ndarray | None = None
    p: np.ndarray | None = None


@dataclass(frozen=True)
class StereoCalibration:
    """A raw stereo pair: the two cameras, the right camera's pose from the left (``rotation``,
    ``translation`` in metres; None when the rectification is given instead), and the image
    size (width, height) it was made for, None when the source does not say."""

    left: CameraCalibration
    right: CameraCalibration
    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None
    size: tuple[int, int] | None = None
    source: str = "calibration"


def _matrix(value: Any, shape: tuple[int, ...], what: str, source: str) -> np.ndarray:
    """A float64 array of ``shape`` from a FileStorage node, a ROS YAML matrix or a list."""
    if isinstance(value, dict):  # ROS YAML: {rows, cols, data}
        value = value.get("data")
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise CalibrationError(f"{source}: {what} is not a numeric matrix") from error
    if shape and array.size != int(np.prod(shape)):
        raise CalibrationError(f"{source}: {what} has {array.size} values, expected shape {shape}")
    if not np.all(np.isfinite(array)):
        raise CalibrationError(f"{source}: {what} contains NaN or inf")
    return array.reshape(shape) if shape else array.ravel()


def _distortion(value: Any, model: str, source: str, what: str) -> np.ndarray:
    d = _matrix(value, (), what, source) if value is not None else np.zeros(0)
    if model not in _MODELS:
        raise CalibrationError(
            f"{source}: distortion model {model!r} is not supported; use one of {', '.join(_MODELS)}"
        )
    expected = (4,) if model == "equidistant" else (0, 4, 5, 8, 12, 14)
    if d.size not in expected:
        raise CalibrationError(f"{source}: {what} has {d.size} coefficients; {model} takes {expected}")
    return d


def _scale(units: str) -> float:
    if units not in ("m", "mm"):
        raise CalibrationError(f"calibration units must be 'm' or 'mm', got {units!r}")
    return 1e-3 if units == "mm" else 1.0


def load_opencv_stereo(path: str | Path, units: str = "m") -> StereoCalibration:
    """An OpenCV stereo YAML (K1 D1 K2 D2 R T, optional R1 R2 P1 P2 and image size)."""
    source = str(path)
    if not Path(path).is_file():
        raise CalibrationError(f"calibration file {source} does not exist")
    try:
        storage = cv2.FileStorage(source, cv2.FILE_STORAGE_READ)
    except cv2.error as error:
        raise CalibrationError(f"{source} is not an OpenCV YAML/XML file: {error.msg.strip()}") from error
    if not storage.isOpened():
        raise CalibrationError(f"{source} is not an OpenCV YAML/XML file")

    def node(name: str) -> np.ndarray | None:
        item = storage.getNode(name)
        if item.empty():
            return None
        if item.isSeq():
            return np.asarray([item.at(i).real() for i in range(item.size())])
        matrix = item.mat()
        return np.asarray(item.real()) if matrix is None else matrix

    found = {name: node(name) for name in ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2")}
    missing = [name for name in ("K1", "D1", "K2", "D2") if found[name] is None]
    rectified = all(found[name] is not None for name in ("R1", "R2", "P1", "P2"))
    if not rectified:
        missing += [name for name in ("R", "T") if found[name] is None]
    if missing:
        raise CalibrationError(
            f"{source}: missing {', '.join(missing)}; an OpenCV stereo calibration needs K1 D1 K2 D2 R T "
            "(or R1 R2 P1 P2 instead of R T)"
        )
    scale = _scale(units)
    size = _size_from_storage(storage)
    storage.release()
    cameras = []
    for index in (1, 2):
        p = None
        if rectified:
            p = _matrix(found[f"P{index}"], (3, 4), f"P{index}", source).copy()
            p[:, 3] *= scale
        cameras.append(
            CameraCalibration(
                k=_matrix(found[f"K{index}"], (3, 3), f"K{index}", source),
                d=_distortion(found[f"D{index}"], "plumb_bob", source, f"D{index}"),
                r=_matrix(found[f"R{index}"], (3, 3), f"R{index}", source) if rectified else None,
                p=p,
            )
        )
    rotation = translation = None
    if found["R"] is not None and found["T"] is not None:
        rotation = np.asarray(found["R"], dtype=np.float64)
        if rotation.size == 3:  # a rotation vector
            rotation = cv2.Rodrigues(rotation.reshape(3, 1))[0]
        rotation = _matrix(rotation, (3, 3), "R", source)
        translation = _matrix(found["T"], (3,), "T", source) * scale
    return StereoCalibration(cameras[0], cameras[1], rotation, translation, size, source)


def _size_from_storage(storage: cv2.FileStorage) -> tuple[int, int] | None:
    width, height = storage.getNode("image_width"), storage.getNode("image_height")
    if not width.empty() and not height.empty():
        return int(width.real()), int(height.real())
    for name in ("image_size", "imageSize"):
        item = storage.getNode(name)
        if not item.empty():
            if item.isSeq():
                values = np.asarray([item.at(i).real() for i in range(item.size())])
            else:
                values = np.asarray(item.mat(), dtype=float).ravel()
            if values.size == 2:
                return int(values[0]), int(values[1])
    return None


def load_camera_info_yamls(left: str | Path, right: str | Path, units: str = "m") -> StereoCalibration:
    """The two camera_info YAMLs of ROS ``camera_calibration`` (its R and P are the rectification)."""
    cameras, sizes = [], []
    for path in (left, right):
        source = str(path)
        try:
            data = yaml.safe_load(Path(path).read_text())
        except FileNotFoundError as error:
            raise CalibrationError(f"camera_info file {source} does not exist") from error
        except (OSError, yaml.YAMLError) as error:
            raise CalibrationError(f"{source} is not a readable camera_info YAML: {error}") from error
        if not isinstance(data, dict):
            raise CalibrationError(f"{source} is not a camera_info YAML (no mapping of fields)")
        missing = [
            key
            for key in ("image_width", "image_height", "camera_matrix", "projection_matrix")
            if key not in data
        ]
        if missing:
            raise CalibrationError(
                f"{source}: missing {', '.join(missing)} (a ROS camera_info YAML has them)"
            )
        sizes.append((int(data["image_width"]), int(data["image_height"])))
        cameras.append(
            _camera_from_fields(
                data["camera_matrix"],
                data.get("distortion_coefficients"),
                data.get("distortion_model", "plumb_bob"),
                data.get("rectification_matrix", np.eye(3).ravel().tolist()),
                data["projection_matrix"],
                source,
                units,
            )
        )
    if sizes[0] != sizes[1]:
        raise CalibrationError(
            f"{left} is for {sizes[0][0]}x{sizes[0][1]} but {right} for {sizes[1][0]}x{sizes[1][1]}"
        )
    return StereoCalibration(cameras[0], cameras[1], size=sizes[0], source=f"{left} + {right}")


def from_camera_info_messages(
    left: Any, right: Any, units: str = "m", source: str = "bag"
) -> StereoCalibration:
    """The calibration carried by two raw sensor_msgs/CameraInfo messages (rclpy or rosbags)."""
    cameras = [
        _camera_from_fields(
            m.k, m.d, m.distortion_model or "plumb_bob", m.r, m.p, f"{source} {view} camera_info", units
        )
        for view, m in zip(VIEWS, (left, right), strict=True)
    ]
    return StereoCalibration(cameras[0], cameras[1], size=(int(left.width), int(left.height)), source=source)


def _camera_from_fields(
    k: Any, d: Any, model: str, r: Any, p: Any, source: str, units: str
) -> CameraCalibration:
    projection = _matrix(p, (3, 4), "projection matrix P", source).copy()
    projection[:, 3] *= _scale(units)
    if not np.any(projection[:, :3]):
        raise CalibrationError(f"{source}: projection matrix P is zero (the camera is not calibrated)")
    return CameraCalibration(
        k=_matrix(k, (3, 3), "camera matrix K", source),
        d=_distortion(d, model, source, "distortion coefficients D"),
        model=model,
        r=_matrix(r, (3, 3), "rectification matrix R", source),
        p=projection,
    )


class Rectifier:
    """Rectification maps of one calibration at one image size; rectifies images, masks and points.

    ``camera``: the rectified pair (:class:`suture_common.camera.StereoCamera`), whose
    camera_info is what the bag carries; ``maps[view]``: (map_x, map_y) float32, for each
    rectified pixel the raw pixel it samples.
    """

    def __init__(self, calibration: StereoCalibration, size: tuple[int, int], alpha: float = 0.0) -> None:
        width, height = size
        source = calibration.source
        if calibration.size is not None and tuple(calibration.size) != (width, height):
            raise CalibrationError(
                f"{source} is for {calibration.size[0]}x{calibration.size[1]} images but the images are "
                f"{width}x{height}; use the calibration of this camera at this resolution"
            )
        for view, camera in zip(VIEWS, (calibration.left, calibration.right), strict=True):
            cx, cy = camera.k[0, 2], camera.k[1, 2]
            if not (0 <= cx < width and 0 <= cy < height) or camera.k[0, 0] <= 0 or camera.k[1, 1] <= 0:
                raise CalibrationError(
                    f"{source}: the {view} camera matrix (principal point {cx:.1f}, {cy:.1f}) does not fit "
                    f"{width}x{height} images"
                )
        self.cameras = self._rectification(calibration, (width, height), alpha)
        self.size = (width, height)
        self.camera = self._rectified_camera(self.cameras, (width, height), source)
        self.maps = {}
        for view, camera in self.cameras.items():
            self.maps[view] = self._maps(camera, (width, height))
            map_x, map_y = self.maps[view]
            valid = (map_x >= 0) & (map_x <= width - 1) & (map_y >= 0) & (map_y <= height - 1)
            if valid.mean() < MIN_VALID_SHARE:
                raise CalibrationError(
                    f"{source} does not fit the images: only {100 * valid.mean():.0f} % of the rectified "
                    f"{view} image maps into the raw image (wrong camera, resolution or units?)"
                )

    @staticmethod
    def _rectification(
        calibration: StereoCalibration, size: tuple[int, int], alpha: float
    ) -> dict[str, CameraCalibration]:
        left, right = calibration.left, calibration.right
        if left.p is not None and right.p is not None and left.r is not None and right.r is not None:
            return {"left": left, "right": right}
        if calibration.rotation is None or calibration.translation is None:
            raise CalibrationError(f"{calibration.source}: neither R T nor a rectification (R1 R2 P1 P2)")
        pose = (calibration.rotation, calibration.translation.reshape(3, 1))
        try:
            if left.model == "equidistant" or right.model == "equidistant":
                r1, r2, p1, p2, _ = cv2.fisheye.stereoRectify(
                    left.k,
                    left.d,
                    right.k,
                    right.d,
                    size,
                    *pose,
                    flags=cv2.CALIB_ZERO_DISPARITY,
                    balance=alpha,
                )
            else:
                r1, r2, p1, p2, *_ = cv2.stereoRectify(
                    left.k, left.d, right.k, right.d, size, *pose, flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha
                )
        except cv2.error as error:
            raise CalibrationError(f"{calibration.source}: stereoRectify failed: {error.err}") from error
        return {
            "left": CameraCalibration(left.k, left.d, left.model, r1, p1),
            "right": CameraCalibration(right.k, right.d, right.model, r2, p2),
        }

    @staticmethod
    def _rectified_camera(
        cameras: dict[str, CameraCalibration], size: tuple[int, int], source: str
    ) -> StereoCamera:
        p1, p2 = cameras["left"].p, cameras["right"].p
        if abs(p2[1, 3]) > abs(p2[0, 3]):
            raise CalibrationError(
                f"{source}: vertical stereo (the right camera is below the left) is not supported"
            )
        if not np.allclose(p1[:, :3], p2[:, :3], rtol=1e-6, atol=1e-6):
            raise CalibrationError(
                f"{source}: the rectified projections P1 and P2 differ in their 3x3 part; rectify with "
                "zero disparity at infinity (CALIB_ZERO_DISPARITY) so both views share the intrinsics"
            )
        fx = p1[0, 0]
        baseline = -(p2[0, 3] - p1[0, 3]) / fx
        if baseline > MAX_BASELINE_M:
            raise CalibrationError(
                f"{source}: stereo baseline {baseline:.3g} m is too long for an endoscope; "
                "is the translation in millimetres? pass --calibration-units mm"
            )
        if baseline <= 0:
            raise CalibrationError(
                f"{source}: the right camera is not to the right of the left (baseline {baseline:.3g} m); "
                "are left and right swapped?"
            )
        try:
            return StereoCamera(size[0], size[1], fx, p1[1, 1], p1[0, 2], p1[1, 2], float(baseline))
        except CameraModelError as error:
            raise CalibrationError(f"{source}: {error}") from error

    @staticmethod
    def _maps(camera: CameraCalibration, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        if camera.model == "equidistant":
            return cv2.fisheye.initUndistortRectifyMap(
                camera.k, camera.d, camera.r, camera.p, size, cv2.CV_32FC1
            )
        return cv2.initUndistortRectifyMap(camera.k, camera.d, camera.r, camera.p, size, cv2.CV_32FC1)

    def image(self, view: str, raw: np.ndarray) -> np.ndarray:
        """The rectified image of ``view`` (bilinear, black outside the raw image)."""
        map_x, map_y = self.maps[view]
        return cv2.remap(raw, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def mask(self, view: str, raw: np.ndarray) -> np.ndarray:
        """The rectified mask of ``view``, 0 or 255 (the same maps; bilinear, then halfway threshold)."""
        rectified = self.image(view, (np.asarray(raw) > 0).astype(np.uint8) * 255)
        return np.where(rectified >= 128, 255, 0).astype(np.uint8)

    def points(self, view: str, raw_uv: np.ndarray) -> np.ndarray:
        """(N, 2) raw pixels of ``view`` as rectified pixels."""
        camera = self.cameras[view]
        points = np.asarray(raw_uv, dtype=np.float64).reshape(-1, 1, 2)
        if camera.model == "equidistant":
            out = cv2.fisheye.undistortPoints(points, camera.k, camera.d, R=camera.r, P=camera.p)
        else:
            out = cv2.undistortPoints(
                points, camera.k, camera.d, R=camera.r, P=camera.p, criteria=UNDISTORT_CRITERIA
            )
        return out.reshape(-1, 2)
