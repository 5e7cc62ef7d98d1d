# SPDX-License-Identifier: Apache-2.0
"""The reconstruction stage's one entry point: two ordered sequences and a camera in, 3D thread and grasp out.

:func:`reconstruct` is what ``reconstruction_node`` and the offline evaluator
both call. Steps (paper Section II.B end and II.C):

1. validate the sequences ((N, 2) pixels from the cut tip, finite, at least
   ``min_points``; (N, 3) with the not-seen flag, :mod:`suture_reconstruction.not_seen`);
   smooth each lightly (Savitzky-Golay, ``smoothing_window`` samples) and resample it
   every 1 px of its own arc length; a step longer than ``max_jump_px`` is a jump over a
   hidden stretch, not observed thread (:mod:`suture_reconstruction.sequences`);
2. stereo pairing on epipolar rows, sub-pixel, monotone along the thread, within
   the disparity limits of the working depth range, and disparity
   regularisation along the thread (:mod:`suture_reconstruction.pairing`);
   given the rectified images too, the disparity is then refined by matching
   the thread's image along the rows (:mod:`suture_reconstruction.photometric`):
   the mask-traced centrelines leave biases of 0.5-3 px over stretches, each
   pixel 4-5 mm of depth at 110 mm with a 5 mm baseline; an end whose nearest steep
   stretch lies far along the thread is matched in the images too, with a window that
   holds its termination (:func:`~suture_reconstruction.ends.match_unanchored_ends`).
   The depth must follow precise pairs closely: where the thread is lifted
   over the other strand 1 px of disparity is about 3 mm of depth, and a
   flattened lift is arc length missing before the grasp point, which moves
   the grasp along the thread by as much.
   It must not follow noise either: sequences traced on pixel masks carry a
   quantisation saw-tooth correlated over tens of px, whose level is read from
   the sequences' roughness (``pair_noise_floor``); followed, it is a depth
   ripple that makes the thread too long;
3. triangulation of every left sample with a supported disparity
   (:mod:`suture_reconstruction.triangulation`): the dense vertices ``points``; the samples
   of not-seen stretches between them at the disparity interpolated across
   (:mod:`suture_reconstruction.not_seen`);
4. resampling of the vertices every ``vertex_step`` along each unbroken run and
   Algorithm 1 (:mod:`suture_reconstruction.shape_graph`);
5. a smoothing spline through the path's vertices, re-parametrised by arc
   length (:mod:`suture_reconstruction.curve`): ``path`` every ``path_step``
   and ``length``;
6. the grasp pose ``grasp_arc_length`` from the cut tip (``suture_common.grasp``), and its
   uncertainty (:mod:`suture_reconstruction.uncertainty`): a thread whose reconstruction starts
   more than ``max_tip_gap_mm`` after the cut tip, a grasp point a view does not see (with
   images, also where the thread runs under an instrument before reaching it:
   :func:`~suture_reconstruction.ends.refuse_grasp_under_occluder`), one
   uncertain by more than ``max_grasp_uncertainty_mm``, or one before which a view's sequence
   holds more than ``max_unexplained_arc_mm`` of thread the 3D thread does not explain, or near
   which (from the cut tip to 10 mm past it) a stretch of 20 mm of arc is more than
   ``max_arc_image_ratio`` times the length its image covers, is refused;
   so is, where the thread runs along the image rows at the grasp point (its depth not measured
   there), one that lies more than ``max_behind_surface_px`` of disparity behind the textured
   surface beside it (:mod:`suture_reconstruction.surface`; only with images), and, where no
   stretch of the thread crosses the image rows steeply (its depth rests on its ends), one whose
   cut tip or far end the images place more than ``max_end_disparity_gap_px`` of disparity from
   the reconstruction (:mod:`suture_reconstruction.ends`; only with images).

Errors: :class:`~suture_reconstruction.errors.ReconstructionError` subclasses
(InvalidSequenceError, also for points outside the image or an implausibly long
sequence, see :func:`~suture_reconstruction.sequences.check_plausible`; TooFewPointsError,
NoStereoOverlapError, ThreadTooShortError; ImagePairError for images that do not fit the
camera; TipNotReconstructedError, GraspNotSeenError, UncertainGraspError, UnexplainedArcError,
ArcAlongViewError, ThreadBehindSurfaceError and EndDisparityError
for a grasp point that is not trusted)
and ``suture_common.camera.CameraModelError`` for an unusable camera.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field, fields

import numpy as np

from suture_common.camera import CameraModelError, StereoCamera
from suture_common.parameters import described
from suture_reconstruction.curve import ArcLengthCurve, fit_curve, grasp_pose
from suture_reconstruction.ends import (
    ANCHOR_ROW_DEG,
    anchor_row_angle_deg,
    end_disparity_gaps_px,
    match_unanchored_ends,
    refuse_contradicted_ends,
    refuse_grasp_under_occluder,
    sequence_anchor_deg,
)
from suture_reconstruction.errors import (
    NoStereoOverlapError,
    ReconstructionError,
    ThreadTooShortError,
    TooFewPointsError,
)
from suture_reconstruction.image_evidence import seen_in_image
from suture_reconstruction.not_seen import not_seen_flags, observed_samples, with_not_seen
from suture_reconstruction.pairing import (
    Disparity,
    DisparitySmoothing,
    PairingParams,
    Pairs,
    SelectionCosts,
    pair_noise_floor,
    pair_sequences,
    regularise_disparity,
)
from suture_reconstruction.photometric import PhotometricParams, check_image_pair, refine_disparity
from suture_reconstruction.sequences import Resampled, as_sequence, check_plausible
from suture_reconstruction.shape_graph import ShapeGraphParams, ShapePath, optimise_shape
from suture_reconstruction.surface import refuse_behind_surface, surface_gap_px
from suture_reconstruction.triangulation import Triangulated, resample_runs, triangulate_supported
from suture_reconstruction.uncertainty import (
    RATIO_ARC_M,
    UNSUPPORTED_ROW_DEG,
    GraspUncertainty,
    arc_image_ratio,
    assess_grasp,
    refuse_arc_along_view,
    refuse_late_start,
    refuse_uncertain_grasp,
    refuse_unexplained_arc,
    tip_gap_mm,
    unexplained_arc_mm,
)


@dataclass(frozen=True)
class ReconstructionParams:
    """Every tunable of :func:`reconstruct`; SI units unless the name says px.

    Sequences: ``min_points`` (fewer points in a view: TooFewPointsError),
    ``smoothing_window`` (Savitzky-Golay samples), ``max_jump_px`` (a longer step
    is a jump over a hidden stretch). Pairing: ``pairing``
    (:class:`~suture_reconstruction.pairing.PairingParams`: depth range, angles,
    bands, end pairs), ``disparity``
    (:class:`~suture_reconstruction.pairing.DisparitySmoothing`: the adaptive
    smoothing of the disparity along the thread, its ladder of smoothing
    lengths, the noise floor read from the sequences' roughness, outlier
    rejection and extrapolation beyond the first/last pair),
    ``photometric`` (:class:`~suture_reconstruction.photometric.PhotometricParams`:
    the refinement by the images, when :func:`reconstruct` is given them),
    ``min_pairs`` (fewer pairs: NoStereoOverlapError). Shape: ``vertex_step`` (m
    between the vertices given to Algorithm 1, which fixes the unit of its index
    difference |i - t|), ``shape`` (:class:`ShapeGraphParams`: tau_L, its step,
    Upsilon_3...). Curve: ``curve_smoothing`` (m), ``arc_smoothing`` (m, the shorter smoothing of
    the image-plane directions along which the arc length is measured), ``path_step`` (m). Grasp:
    ``grasp_arc_length`` (m from the cut tip), ``max_grasp_uncertainty_mm`` and
    ``refuse_unseen_grasp``, ``image_evidence``, ``max_tip_gap_mm``, ``max_unexplained_arc_mm``,
    ``max_arc_image_ratio`` (the refusals of :mod:`suture_reconstruction.uncertainty`).

    :meth:`replace` takes flat names for the nested parameters too.
    """

    min_points: int = field(
        default=8,
        metadata=described(
            "fewest points a sequence must have",
            (3, 1_000_000),
        ),
    )
    smoothing_window: int = 9
    max_jump_px: float = 4.0
    pairing: PairingParams = field(default_factory=PairingParams)
    disparity: DisparitySmoothing = field(default_factory=DisparitySmoothing)
    photometric: PhotometricParams = field(default_factory=PhotometricParams)
    min_pairs: int = 8
    vertex_step: float = field(
        default=0.0001,
        metadata=described(
            "spacing (m) of the vertices given to Algorithm 1 (unit of |i - t| in Eq. 11; > 0)",
            (0.0, 0.01),
        ),
    )
    shape: ShapeGraphParams = field(default_factory=ShapeGraphParams)
    curve_smoothing: float = field(
        default=0.001,
        metadata=described(
            "smoothing length (m) of the 3D curve",
            (0.0, 0.1),
        ),
    )
    arc_smoothing: float = field(
        default=0.0002,
        metadata=described(
            "smoothing length (m) of the image-plane directions of the curve along which the arc length "
            "from the cut tip is measured (its depth keeps curve_smoothing): shorter than curve_smoothing, "
            "which cuts the arc of a tight hook at the tip; about one pixel's span at the working distance",
            (0.0, 0.1),
        ),
    )
    path_step: float = field(
        default=0.0005,
        metadata=described(
            "spacing (m) of the published path (> 0)",
            (0.0, 0.1),
        ),
    )
    grasp_arc_length: float = field(
        default=0.05,
        metadata=described(
            "arc length (m) from the cut tip to the grasp point",
            (0.0, 1.0),
        ),
    )
    max_grasp_uncertainty_mm: float = field(
        default=10.0,
        metadata=described(
            "largest estimated uncertainty (mm) of the grasp point that is still published; a grasp "
            "point less certain is refused (UncertainGraspError)",
            (0.0, 1000.0),
        ),
    )
    refuse_unseen_grasp: bool = field(
        default=True,
        metadata=described("refuse a grasp point that a view does not see (GraspNotSeenError)"),
    )
    image_evidence: bool = field(
        default=True,
        metadata=described(
            "with images: a stretch a view's mask lost (flagged not seen) that its image shows as a thin "
            "line of the thread's contrast counts as seen for the grasp's refusal and uncertainty "
            "(suture_reconstruction.image_evidence)"
        ),
    )
    max_tip_gap_mm: float = field(
        default=3.0,
        metadata=described(
            "largest arc (mm) next to the cut tip that may be missing from the reconstructed thread; "
            "a thread that starts later is refused (TipNotReconstructedError), since the grasp point "
            "is placed by arc length from the tip",
            (0.0, 1000.0),
        ),
    )
    max_unexplained_arc_mm: float = field(
        default=5.0,
        metadata=described(
            "longest stretch (mm) of a view's seen sequence between the cut tip and the grasp point that "
            "may lie off the reconstructed thread's projection; a longer one is thread the 3D thread does "
            "not hold, which moves the grasp point along the thread by as much (UnexplainedArcError)",
            (0.0, 1000.0),
        ),
    )
    max_arc_image_ratio: float = field(
        default=2.0,
        metadata=described(
            "largest ratio of the 3D arc to the length its left image covers at the thread's depth, over "
            f"any {1000 * RATIO_ARC_M:g} mm of arc between the cut tip and {500 * RATIO_ARC_M:g} mm past the "
            "grasp point (1 for a thread across the viewing rays, 2 for one 60 degrees out of the image "
            "plane); a larger one runs along the viewing rays, where its length rests on disparity alone "
            "(ArcAlongViewError)",
            (1.0, 1000.0),
        ),
    )
    max_behind_surface_px: float = field(
        default=3.0,
        metadata=described(
            "where the thread runs along the image rows at the grasp point (its depth not measured by "
            "the pair), the largest disparity (px) by which the grasp point may lie behind the textured "
            "surface beside it; farther is inside the tissue, a wrongly carried depth "
            "(ThreadBehindSurfaceError; only checked with images)",
            (0.0, 1000.0),
        ),
    )

    max_end_disparity_gap_px: float = field(
        default=2.0,
        metadata=described(
            "where no stretch of the thread crosses the image rows at 10 degrees or more (its depth "
            "rests on its two ends' pairs), the largest disparity (px) by which the images may place "
            "the cut tip or the far end away from the reconstruction (2 px: about 8 mm of depth at "
            "100 mm with fx 520 px and a 5 mm baseline); farther, the masks' ends or rows disagree "
            "between the views and the carried depth is wrong (EndDisparityError; only checked with "
            "images); an end the images place 1 px to this far away, where the thread stands out "
            "from the tissue, takes its disparity from them",
            (0.0, 1000.0),
        ),
    )

    def __post_init__(self) -> None:
        if self.min_points < 3 or self.min_pairs < 3:
            raise ValueError("min_points and min_pairs must be at least 3")
        for name in ("max_jump_px", "vertex_step", "path_step"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value}")
        if not self.max_unexplained_arc_mm > 0:
            raise ValueError(f"max_unexplained_arc_mm must be positive, got {self.max_unexplained_arc_mm}")
        if not self.max_arc_image_ratio >= 1:
            raise ValueError(f"max_arc_image_ratio must be at least 1, got {self.max_arc_image_ratio}")
        if not self.max_behind_surface_px > 0:
            raise ValueError(f"max_behind_surface_px must be positive, got {self.max_behind_surface_px}")
        if not self.max_end_disparity_gap_px > 0:
            raise ValueError(
                f"max_end_disparity_gap_px must be positive, got {self.max_end_disparity_gap_px}"
            )
        if not self.max_tip_gap_mm > 0:
            raise ValueError(f"max_tip_gap_mm must be positive, got {self.max_tip_gap_mm}")
        if not self.max_grasp_uncertainty_mm > 0:
            raise ValueError(
                f"max_grasp_uncertainty_mm must be positive, got {self.max_grasp_uncertainty_mm}"
            )
        if not (self.curve_smoothing >= 0 and self.arc_smoothing >= 0 and self.grasp_arc_length >= 0):
            raise ValueError("curve_smoothing, arc_smoothing and grasp_arc_length must not be negative")

    def replace(self, **changes: object) -> ReconstructionParams:
        """A copy with ``changes`` applied; names of the fields of PairingParams, SelectionCosts,
        ShapeGraphParams, DisparitySmoothing and PhotometricParams go to the nested parameters.
        Unknown names raise TypeError."""
        nested = {
            "pairing": PairingParams,
            "shape": ShapeGraphParams,
            "disparity": DisparitySmoothing,
            "photometric": PhotometricParams,
        }
        own_names = {f.name for f in fields(self)}
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        grouped: dict[str, dict[str, object]] = {key: {} for key in (*nested, "selection")}
        for name, value in changes.items():
            if name in own_names:
                values[name] = value
            elif name in {f.name for f in fields(PairingParams)}:
                grouped["pairing"][name] = value
            elif name in {f.name for f in fields(SelectionCosts)}:
                grouped["selection"][name] = value
            elif name in {f.name for f in fields(ShapeGraphParams)}:
                grouped["shape"][name] = value
            elif name in {f.name for f in fields(DisparitySmoothing)}:
                grouped["disparity"][name] = value
            elif name in {f.name for f in fields(PhotometricParams)}:
                grouped["photometric"][name] = value
            else:
                raise TypeError(f"unknown reconstruction parameter {name!r}")
        if grouped["selection"]:
            selection = values["pairing"].selection
            grouped["pairing"]["selection"] = dataclasses.replace(selection, **grouped["selection"])
        for key, cls in nested.items():
            if grouped[key]:
                values[key] = dataclasses.replace(values[key], **grouped[key])
                assert isinstance(values[key], cls)
        return ReconstructionParams(**values)


@dataclass(frozen=True)
class Reconstruction:
    """The 3D thread of one stereo pair, in the left camera optical frame (metres).

    ``points`` (K, 3): dense triangulated vertices, one per paired left sample,
    in sequence order from the cut tip. ``path`` (P, 3): the optimised smooth
    centreline from the cut tip, every ``path_step`` of arc length (last point
    at the end). ``length``: its arc length (m). ``grasp_position`` (3,) and
    ``grasp_quaternion`` (4,) x y z w: the grasp pose (``suture_common.grasp``).
    ``left_uv`` (K, 2): the left pixels of ``points``; ``disparity`` (K,) px.
    ``image_matches``: left samples whose disparity the images refined (0 without images).
    ``shape``: Algorithm 1's result (``tau_l`` used, path vertex indices into
    ``vertices`` (V, 3), the resampled input). ``rejected``: counts of left
    samples without a vertex, by reason. ``timings_ms``: per step.
    ``uncertainty``: the grasp point's estimated uncertainty and its parts
    (:class:`~suture_reconstruction.uncertainty.GraspUncertainty`); ``path_not_seen`` (P,) bool:
    True where the path point lies on a stretch that a view does not see (flagged in the
    sequences, its depth interpolated from the seen thread on either side,
    :mod:`suture_reconstruction.not_seen`, or jumped over); ``points`` holds the seen vertices only.
    """

    points: np.ndarray
    path: np.ndarray
    length: float
    grasp_position: np.ndarray
    grasp_quaternion: np.ndarray
    left_uv: np.ndarray
    disparity: np.ndarray
    vertices: np.ndarray
    shape: ShapePath
    curve: ArcLengthCurve
    rejected: dict[str, int]
    timings_ms: dict[str, float]
    image_matches: int = 0
    uncertainty: GraspUncertainty | None = None
    path_not_seen: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def grasp_uncertainty_mm(self) -> float:
        """The grasp point's estimated uncertainty (mm); NaN when it was not assessed."""
        return float("nan") if self.uncertainty is None else self.uncertainty.total_mm

    @property
    def tau_l(self) -> float:
        """tau_L (m) at which Algorithm 1 found its path."""
        return self.shape.tau_l


def reconstruct(
    left_sequence: np.ndarray,
    right_sequence: np.ndarray,
    camera: StereoCamera,
    params: ReconstructionParams | None = None,
    images: tuple[np.ndarray, np.ndarray] | None = None,
) -> Reconstruction:
    """Reconstruct the thread in 3D from its ordered sequences in a rectified stereo pair.

    The steps are those of the module docstring: validate, smooth and resample the sequences;
    pair them on epipolar rows and regularise the disparity (refined by the images when given);
    triangulate; Algorithm 1; a smoothing spline; the grasp pose.

    Parameters
    ----------
    left_sequence, right_sequence : (N, 2) and (M, 2) array_like of float
        The thread's ordered centreline in the left and right rectified images, pixels (u, v)
        from the cut tip, about 1 px apart, as the ordering stage publishes them; (N, 3) arrays
        carry the not-seen flag in the third column (1.0: interpolated across a gap in the mask,
        never matched; its depth comes from the seen thread on either side,
        :mod:`suture_reconstruction.not_seen`; a grasp point there is refused). A step longer
        than ``params.max_jump_px`` is taken as a jump over a hidden stretch.
    camera : suture_common.camera.StereoCamera
        The rectified pair (intrinsics, baseline in m, image size).
    params : ReconstructionParams, optional
        Every tunable; the defaults when None.
    images : (left, right) tuple of ndarray, optional
        The rectified images of the same stereo pair, (H, W) or (H, W, C) uint8 of the camera's
        size; with them the disparity is refined photometrically.

    Returns
    -------
    Reconstruction
        In the left camera optical frame, metres: ``points`` (K, 3) float64 dense vertices,
        ``path`` (P, 3) float64 smooth centreline from the cut tip every ``params.path_step``,
        ``length`` (m), ``grasp_position`` (3,) and ``grasp_quaternion`` (4,) x y z w, and
        diagnostics (``left_uv``, ``disparity`` px, ``rejected``, ``timings_ms``...).

    Raises
    ------
    InvalidSequenceError
        A sequence of the wrong shape, with NaN/inf, outside the image or implausibly long.
    TooFewPointsError
        Fewer than ``params.min_points`` points in a view, or too few 3D vertices.
    NoStereoOverlapError
        Fewer than ``params.min_pairs`` left samples pair with the right sequence.
    ThreadTooShortError
        The reconstructed thread is shorter than ``params.grasp_arc_length`` (GraspNotSeenError
        instead, with ``images``, where it ends running under an instrument).
    TipNotReconstructedError
        The reconstructed thread starts more than ``params.max_tip_gap_mm`` of arc after the
        cut tip (the grasp point would be counted from a later point).
    ImagePairError
        ``images`` that do not fit the camera.
    GraspNotSeenError
        The grasp point lies on a stretch a view does not see (``params.refuse_unseen_grasp``), or
        past where the thread runs under an instrument, short of the grasp point.
    UncertainGraspError
        The grasp point's uncertainty exceeds ``params.max_grasp_uncertainty_mm``.
    UnexplainedArcError
        A stretch longer than ``params.max_unexplained_arc_mm`` of a view's seen sequence between
        the cut tip and the grasp point lies off the 3D thread's projection.
    ArcAlongViewError
        A stretch of 20 mm of the 3D arc between the cut tip and 10 mm past the grasp point is
        more than ``params.max_arc_image_ratio`` times the length its left image covers (it would
        run along the viewing rays).
    ThreadBehindSurfaceError
        With ``images``: the thread runs along the image rows at the grasp point and lies more than
        ``params.max_behind_surface_px`` of disparity behind the surface beside it.
    ReconstructionError
        Algorithm 1 found no path, or the thread points along the viewing ray at the grasp
        point (the base class of all the above; a ``ValueError``).
    suture_common.camera.CameraModelError
        ``camera`` is not a StereoCamera.

    Examples
    --------
    A curved thread about 64 mm long, 100-110 mm in front of the camera, seen in both views:

    >>> import numpy as np
    >>> from suture_common.camera import StereoCamera
    >>> from suture_reconstruction import reconstruct
    >>> camera = StereoCamera.default(640, 480)
    >>> s = np.linspace(0.0, 1.0, 400)
    >>> thread = np.column_stack([0.06 * s - 0.03, 0.01 * np.sin(3 * s), 0.1 + 0.01 * s])
    >>> left, right = camera.project(thread, "left"), camera.project(thread, "right")
    >>> result = reconstruct(left, right, camera)
    >>> result.path.shape[1], result.path.dtype
    (3, dtype('float64'))
    >>> true_length = np.linalg.norm(np.diff(thread, axis=0), axis=1).sum()
    >>> print(f"{1000 * result.length:.1f} mm (true {1000 * true_length:.1f} mm)")
    64.2 mm (true 64.2 mm)
    >>> print("tip at", np.round(1000 * result.path[0], 1) + 0.0, "mm")
    tip at [-30.   0. 100.] mm
    """
    params = params or ReconstructionParams()
    if not isinstance(camera, StereoCamera):
        raise CameraModelError(f"camera must be a StereoCamera, got {type(camera).__name__}")
    timer = _StepTimer()
    left, right = _checked_sequences(left_sequence, right_sequence, camera, params.min_points)
    if images is not None:
        images = check_image_pair(images, camera.width, camera.height)
    (left, left_hidden), (right, _) = (
        observed_samples(sequence, not_seen_flags(raw, name), params.smoothing_window, params.max_jump_px)
        for sequence, raw, name in ((left, left_sequence, "left"), (right, right_sequence, "right"))
    )
    d_range = (camera.disparity(params.pairing.max_depth), camera.disparity(params.pairing.min_depth))
    pairs, disparity, rejected = _stereo_disparity(left, right, d_range, params)
    timer.lap("pairing")
    image_matches = 0
    if images is not None:
        disparity, image_matches = refine_disparity(
            images,
            left.points,
            left.observed,
            disparity,
            pairs,
            params.disparity,
            params.photometric,
            end_matcher=lambda fused, prepared: match_unanchored_ends(
                prepared, left, fused, camera, images, params.max_end_disparity_gap_px
            ),
        )
    timer.lap("photometric")
    triangulated = triangulate_supported(camera, left, disparity, d_range, params.min_pairs)
    rejected["unsupported"] = triangulated.unsupported
    thread = with_not_seen(camera, left, left_hidden, disparity, d_range, triangulated)
    timer.lap("triangulation")
    vertices, shape = _shape(thread, params)
    timer.lap("optimisation")
    curve = fit_curve(vertices[shape.indices], params.curve_smoothing, params.arc_smoothing)
    path = curve.resample(params.path_step)
    try:
        grasp = grasp_pose(curve, params.grasp_arc_length)
    except ThreadTooShortError:
        if images is not None:
            length, wanted = curve.length, params.grasp_arc_length
            refuse_grasp_under_occluder(images, left, disparity, camera, length, wanted)
        raise
    refuse_late_start(tip_gap_mm(curve, left, camera), params.max_tip_gap_mm)
    timer.lap("curve_and_grasp")
    views = (left, right)
    if images is not None and params.image_evidence:
        views = (seen_in_image(left, images[0]), seen_in_image(right, images[1]))
    uncertainty, path_not_seen = assess_grasp(curve, path, camera, views, params.grasp_arc_length)
    refuse_uncertain_grasp(uncertainty, params.max_grasp_uncertainty_mm, params.refuse_unseen_grasp)
    unexplained, view = unexplained_arc_mm(curve, camera, (left, right), params.grasp_arc_length)
    refuse_unexplained_arc(unexplained, view, params.max_unexplained_arc_mm)
    refuse_arc_along_view(arc_image_ratio(curve, camera, params.grasp_arc_length), params.max_arc_image_ratio)
    if images is not None:
        anchor_deg = min(anchor_row_angle_deg(curve, camera), sequence_anchor_deg(left, disparity, camera))
        if anchor_deg < ANCHOR_ROW_DEG:
            gaps = end_disparity_gaps_px(images, left, curve, camera)
            refuse_contradicted_ends(gaps, anchor_deg, params.max_end_disparity_gap_px)
    if images is not None and uncertainty.row_angle_deg < UNSUPPORTED_ROW_DEG:
        grasp_uv = camera.project(grasp.position[None], "left")[0]
        gap = surface_gap_px(images, grasp_uv, float(camera.disparity(grasp.position[2])))
        refuse_behind_surface(gap, uncertainty.row_angle_deg, params.max_behind_surface_px)
    timer.lap("uncertainty")
    return Reconstruction(
        points=triangulated.points,
        left_uv=triangulated.left_uv,
        disparity=triangulated.disparity,
        vertices=vertices,
        shape=shape,
        curve=curve,
        path=path,
        length=curve.length,
        grasp_position=grasp.position,
        grasp_quaternion=grasp.quaternion,
        rejected=rejected,
        timings_ms=timer.timings(),
        image_matches=image_matches,
        uncertainty=uncertainty,
        path_not_seen=path_not_seen,
    )


class _StepTimer:
    """Wall time (ms) of consecutive steps, each from the end of the one before."""

    def __init__(self) -> None:
        self._last = time.perf_counter()
        self._laps: dict[str, float] = {}

    def lap(self, step: str) -> None:
        now = time.perf_counter()
        self._laps[step] = 1000 * (now - self._last)
        self._last = now

    def timings(self) -> dict[str, float]:
        """The steps' times and their ``total``."""
        return {**self._laps, "total": sum(self._laps.values())}


def _checked_sequences(
    left_sequence: np.ndarray, right_sequence: np.ndarray, camera: StereoCamera, min_points: int
) -> tuple[np.ndarray, np.ndarray]:
    """Both sequences as (N, 2) float64 pixels, checked for shape, values and plausibility."""
    left = as_sequence(left_sequence, "left", min_points)
    right = as_sequence(right_sequence, "right", min_points)
    check_plausible(left, camera.width, camera.height, "left")
    check_plausible(right, camera.width, camera.height, "right")
    return left, right


def _stereo_disparity(
    left: Resampled, right: Resampled, d_range: tuple[float, float], params: ReconstructionParams
) -> tuple[Pairs, Disparity, dict[str, int]]:
    """The stereo pairs, the regularised disparity along the left samples, and the counts of
    left samples without a pair by reason (``outlier`` included).

    Raises NoStereoOverlapError with fewer than ``params.min_pairs`` pairs.
    """
    n_left = len(left.points)
    pairs = pair_sequences(left.points, left.observed, right.points, right.observed, d_range, params.pairing)
    rejected = dict(pairs.rejected)
    if pairs.rows.size < params.min_pairs:
        raise NoStereoOverlapError(
            f"only {pairs.rows.size} of {n_left} left samples pair with the right sequence on their epipolar "
            f"row within the disparity limits {d_range[0]:.1f}-{d_range[1]:.1f} px "
            f"({params.pairing.min_depth * 1000:.0f}-{params.pairing.max_depth * 1000:.0f} mm); at least "
            f"{params.min_pairs} are needed (are both sequences of the same thread and stereo pair, and is "
            "camera_info the rectified pair?)"
        )
    noise_floor = pair_noise_floor(left.points, right.points, params.disparity)
    disparity = regularise_disparity(
        n_left, pairs.rows, pairs.disparity, pairs.weight, params.disparity, noise_floor
    )
    rejected["outlier"] = int((~disparity.inlier).sum())
    return pairs, disparity, rejected


def _shape(triangulated: Triangulated, params: ReconstructionParams) -> tuple[np.ndarray, ShapePath]:
    """The vertices every ``vertex_step`` along each unbroken run, and Algorithm 1's path."""
    vertices = resample_runs(triangulated.points, triangulated.index, params.vertex_step)
    if len(vertices) < 2:
        raise TooFewPointsError(f"only {len(vertices)} 3D vertex after resampling; the thread is too short")
    try:
        shape = optimise_shape(vertices, params.shape)
    except TooFewPointsError:
        raise
    except ValueError as exc:
        raise ReconstructionError(str(exc)) from None
    return vertices, shape
