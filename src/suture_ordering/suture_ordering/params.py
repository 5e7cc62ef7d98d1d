# SPDX-License-Identifier: Apache-2.0
"""Parameters of the ordering search (paper Section II.B) and their resolution-dependent values.

Lengths are in pixels **for an image 640 px wide**; with ``reference_width_px``
set (the default, 640) they scale linearly with the width of the mask being
ordered, so the same parameters serve 640x480 and 1280x1024 (areas scale with
the square). Set ``reference_width_px=None`` to use the pixel values as given.
Angles are radians.

Correspondence with the paper (Eq. 4-7):

============================  =========================  ==========================
paper                          here                        default (at 640 px)
============================  =========================  ==========================
RoI radius Υ                   ``roi_radius_px``            24 px
(nodes nearer than this are    ``step_radius_px``           8 px
covered by the next chord)
μ                              ``mu``                       0.01
R1, R2, R3 (ε1, ε2, ε3)        ``eps1_range`` ...           [1, 5], [0.1, 0.5], [0.02, 0.1]
grid over R1 x R2 x R3         ``grid_size`` per range      3 (27 parameter sets)
τ_O = 2.6 Υ                    ``tau_o_factor`` x Υ         2.6 x 24 = 62.4 px
τ_V = 2π/3                     ``tau_v``                    2.094 rad
============================  =========================  ==========================

The choices where the paper is silent are documented in the modules that
:mod:`suture_ordering.search` lists.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

from suture_common.parameters import described


@dataclass(frozen=True)
class OrderingParams:
    """Tunable values of mask cleaning, tip localisation and the sequence search.

    Pixel lengths are for a 640 px wide image (see the module docstring). Each field's
    metadata holds its description and range as a ROS parameter of ordering_node
    (:func:`suture_common.parameters.described`).
    """

    roi_radius_px: float = field(
        default=24.0,
        metadata=described(
            "Υ: radius of the Region of Interest around the current vertex (px)", (0.0, 640.0)
        ),
    )
    step_radius_px: float = field(
        default=8.0,
        metadata=described(
            "inner radius of the RoI: the nearest active nodes lie this far from the vertex, so the "
            "search advances by about this much per step (px; 2 to roi_radius_px)",
            (2.0, 640.0),
        ),
    )
    detect_radius_px: float = field(
        default=2.5,
        metadata=described(
            "centreline nodes within this distance of the path already traversed are detected "
            "(px; below step_radius_px)",
            (0.0, 640.0),
        ),
    )
    zone_margin_px: int = field(
        default=1,
        metadata=described(
            'the "zone" for the out-of-zone count O is the mask dilated by this many pixels', (0, 64)
        ),
    )
    mu: float = field(
        default=0.01,
        metadata=described("μ of Eq. (5): a small positive gain; O = 0 costs log(μ)", (0.0, 1.0)),
    )
    eps1_range: tuple[float, float] = field(
        default=(1.0, 5.0),
        metadata=described("R1 of Eq. (7): [low, high] of ε1, the weight of the out-of-zone count"),
    )
    eps2_range: tuple[float, float] = field(
        default=(0.1, 0.5),
        metadata=described("R2 of Eq. (7): [low, high] of ε2, the weight of the distance"),
    )
    eps3_range: tuple[float, float] = field(
        default=(0.02, 0.1),
        metadata=described("R3 of Eq. (7): [low, high] of ε3, the weight of the turning angle"),
    )
    grid_size: int = field(
        default=3,
        metadata=described(
            "values per range in the tuning grid of Eq. (7) (grid_size³ parameter sets; 1: midpoints)",
            (1, 20),
        ),
    )
    tau_o_factor: float = field(
        default=2.6,
        metadata=described(
            "τ_O = tau_o_factor x Υ (px): candidates with O >= τ_O are not admissible", (0.0, 100.0)
        ),
    )
    tau_v: float = field(
        default=2.0 * math.pi / 3.0,
        metadata=described("τ_V: candidates turning by δ >= τ_V are not admissible (rad)", (0.0, math.pi)),
    )
    max_mask_fraction: float = field(
        default=0.15,
        metadata=described(
            "largest share of the image a mask may cover: a thread covers a few percent; more is "
            "noise, a wrong threshold or encoding, and ordering it would take minutes",
            (0.0, 1.0),
        ),
    )
    curvature_prediction: bool = field(
        default=True,
        metadata=described(
            "measure δ from the direction predicted by the thread's curvature (the last chord turned "
            "by the last turn) instead of the last chord alone (the paper's literal Eq. 4)"
        ),
    )
    bridge_turn_max: float = field(
        default=math.radians(45.0),
        metadata=described(
            "a candidate whose chord leaves the zone (O > 0, a bridged gap) may turn at most this "
            "much, and the thread beyond it must continue within this angle of the chord (rad)",
            (0.0, math.pi),
        ),
    )
    bridge_bend_max: float = field(
        default=math.radians(20.0),
        metadata=described(
            "a bridged gap must bend like one smooth arc: the turns into and out of its chord may "
            "differ by at most this (rad)",
            (0.0, math.pi),
        ),
    )
    occluder_reach_px: float = field(
        default=160.0,
        metadata=described(
            "where the search ends, the thread may continue beyond a gap up to this far (px) when "
            "the thread beyond continues its direction and curvature (an instrument lying across "
            "it, suture_ordering.occluders); at most tau_o_factor x Υ: off",
            (0.0, 10_000.0),
        ),
    )
    occluder_bend_max: float = field(
        default=math.radians(40.0),
        metadata=described(
            "across an occluder (occluder_reach_px) the turns into and out of the chord may differ "
            "by at most this (rad): the thread may bend either way where it is hidden",
            (0.0, math.pi),
        ),
    )
    junction_bend_max: float = field(
        default=math.radians(30.0),
        metadata=described(
            "at a junction where every branch ahead bends by at least this much, the thread ends (rad)",
            (0.0, math.pi),
        ),
    )
    junction_tie: float = field(
        default=math.radians(8.0),
        metadata=described(
            "at a junction, a branch must bend this much less than the next to be chosen from afar (rad)",
            (0.0, math.pi),
        ),
    )
    sharp_step_turn: float = field(
        default=math.radians(32.0),
        metadata=described(
            "a step whose straightest near node turns by more than this is examined as a junction "
            "too: where a strand leaves the thread at a shallow angle (a small loop entered "
            "tangentially) the near node may be the other strand (rad)",
            (0.0, math.pi),
        ),
    )
    min_crossing_angle: float = field(
        default=math.radians(8.0),
        metadata=described(
            "at a junction with four arms, the strands must meet at least at this angle to be taken "
            "as crossing (the thread then goes straight across); below it they touch (rad)",
            (0.0, math.pi),
        ),
    )
    strand_switch_turn: float = field(
        default=math.radians(30.0),
        metadata=described(
            "beyond the hook window, where a sequence turns by more than this over one RoI radius "
            "at a crossing while mask lies straight on beyond it and the crossing strand's far arm "
            "behind the turn, it has left its thread for the other strand: it is cut there "
            "(suture_ordering.strand_switch; rad, pi: off)",
            (0.0, math.pi),
        ),
    )
    skipped_loop_cut: bool = field(
        default=True,
        metadata=described(
            "where a sequence passes by a loop or detour that its mask (the low mask where given) "
            "shows beside it, much longer than the sequence there, it is cut where it first joins "
            "it, where a loop the mask broke off at its crossing comes near it, or where a bridge that "
            "goes past what is left of a loop starts, so that a grasp beyond is refused as on a thread "
            "too short (suture_ordering.skipped_loop)"
        ),
    )
    wide_arc_factor: float = field(
        default=1.6,
        metadata=described(
            "a cross-section (run of mask pixels along a RoI circle) wider than this factor times "
            "the thread width gives one node per edge instead of one at its middle",
            (0.0, 100.0),
        ),
    )
    tip_radius_px: float = field(
        default=12.0,
        metadata=described(
            "the cut tip is the free end nearest to the tip hint, at most this far from it (px)", (0.0, 640.0)
        ),
    )
    tip_gap_max_px: float = field(
        default=48.0,
        metadata=described(
            "when the mask has no thread within tip_radius_px of the tip hint (the segmenter lost the "
            "cut end), the search starts at the thread end that points at the hint from at most this "
            "far, and the stretch from the hint to it is published as not seen; 0: refuse instead "
            "(TipNotOnThreadError) (px)",
            (0.0, 640.0),
        ),
    )
    tip_gap_max_angle: float = field(
        default=0.5,
        metadata=described(
            "largest angle between the thread's direction at that end and the way from it to the "
            "tip hint (rad)",
            (0.0, 3.1416),
        ),
    )
    tip_unexplained_radius_px: float = field(
        default=16.0,
        metadata=described(
            "after ordering, the mask (low mask where given) within this radius of each view's cut tip, "
            "and in line with the thread beyond the tip out to twice it, must lie on the sequence "
            "(suture_ordering.tip_check); 0: no check (px)",
            (0.0, 640.0),
        ),
    )
    tip_unexplained_max_px: float = field(
        default=5.0,
        metadata=described(
            "the ordering refuses (UnexplainedTipError) when more than this many mask pixels within "
            "tip_unexplained_radius_px of a cut tip, or in line beyond it, lie off the sequence: a hook or "
            "loop the search skipped, or one whose arms the mask lost (pixels at 640 px width, scaled "
            "with the width squared)",
            (0.0, 409600.0),
        ),
    )
    max_hole_area_px: float = field(
        default=20.0,
        metadata=described(
            "holes of at most this area inside the mask are filled (px², scales with the width²)",
            (0.0, 640.0 * 480.0),
        ),
    )
    min_eye_width_px: float = field(
        default=1.5,
        metadata=described(
            "a hole of at most max_hole_area_px that holds a square of background this wide, in thread "
            "at most 2 px thicker than the hole is wide, is kept, not filled: the eye of a small loop "
            "(the bend of a hairpin at the cut tip), which the "
            "sequence must go round to measure the arc to the grasp point (px at 640 px width, scaled "
            "with the width; 0: every such hole is filled)",
            (0.0, 640.0),
        ),
    )
    min_blob_extent_px: float = field(
        default=5.0,
        metadata=described(
            "mask components whose bounding box is smaller than this in both directions are removed (px)",
            (0.0, 640.0),
        ),
    )
    row_tolerance_px: float = field(
        default=6.0,
        metadata=described(
            "right-view tip: at most this many rows from the left tip's row (px; predicted masks often "
            "lose a faint tip's last pixels in one view only)",
            (0.0, 480.0),
        ),
    )
    min_depth_m: float = field(
        default=0.05,
        metadata=described("right-view tip: nearest depth of the disparity search (m)", (0.0, 100.0)),
    )
    max_depth_m: float = field(
        default=0.15,
        metadata=described(
            "right-view tip: farthest depth of the disparity search (m; above min_depth_m)", (0.0, 100.0)
        ),
    )
    stereo_fill_max_gap_px: float = field(
        default=60.0,
        metadata=described(
            "a view whose search stops at a gap the other view does not have is continued along the "
            "other view across gaps of up to this many px, not counting a stretch the other view "
            "bridged where this view's mask is missing too (suture_ordering.stereo_fill); 0: off",
            (0.0, 640.0),
        ),
    )
    low_mask_min_gain: float = field(
        default=0.1,
        metadata=described(
            "with low masks, their sequences are taken when one view's is longer than the masks' by "
            "more than this share (below 1) ...",
            (0.0, 1.0),
        ),
    )
    low_mask_max_loss: float = field(
        default=0.02,
        metadata=described("... and neither view's is shorter by more than this share (below 1)", (0.0, 1.0)),
    )
    low_mask_tip_gain_px: float = field(
        default=6.0,
        metadata=described(
            "... or when, between the cut tip and where the masks' sequence leaves the hook window, "
            "one view's runs more than this many px (at 640 px width) along thread the masks' does "
            "not pass (a hairpin's bend the mask lost) and neither view's is 2 px shorter there; 0: off",
            (0.0, 640.0),
        ),
    )
    max_steps: int = field(
        default=2000,
        metadata=described(
            "upper bound on search steps (a safeguard; a 640 px image needs < 200)", (1, 1_000_000)
        ),
    )
    reference_width_px: float | None = field(
        default=640.0,
        metadata=described(
            "width (px) the pixel values refer to; they scale with the mask width. "
            "None (as a ROS parameter: 0): use them unscaled",
            (0.0, 100_000.0),
        ),
    )

    def __post_init__(self) -> None:
        positive = (
            "roi_radius_px",
            "step_radius_px",
            "detect_radius_px",
            "mu",
            "tau_o_factor",
            "tau_v",
            "max_mask_fraction",
            "bridge_turn_max",
            "bridge_bend_max",
            "occluder_bend_max",
            "min_crossing_angle",
            "junction_bend_max",
            "junction_tie",
            "sharp_step_turn",
            "wide_arc_factor",
            "tip_radius_px",
            "min_blob_extent_px",
            "row_tolerance_px",
            "min_depth_m",
        )
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"OrderingParams.{name} must be a positive number, got {value!r}")
        if self.step_radius_px < 2 or self.step_radius_px > self.roi_radius_px:
            raise ValueError(
                f"OrderingParams.step_radius_px must lie in [2, roi_radius_px={self.roi_radius_px}], "
                f"got {self.step_radius_px}"
            )
        if self.detect_radius_px >= self.step_radius_px:
            raise ValueError(
                f"OrderingParams.detect_radius_px ({self.detect_radius_px}) must be smaller than "
                f"step_radius_px ({self.step_radius_px})"
            )
        if not self.max_depth_m > self.min_depth_m:
            raise ValueError(
                f"OrderingParams.max_depth_m ({self.max_depth_m}) must exceed "
                f"min_depth_m ({self.min_depth_m})"
            )
        if self.tau_v > math.pi:
            raise ValueError(f"OrderingParams.tau_v must be at most pi, got {self.tau_v}")
        for name in ("eps1_range", "eps2_range", "eps3_range"):
            low, high = getattr(self, name)
            if not (0 < low <= high and math.isfinite(high)):
                raise ValueError(
                    f"OrderingParams.{name} must be (low, high) with 0 < low <= high, got {(low, high)}"
                )
        if int(self.grid_size) != self.grid_size or self.grid_size < 1:
            raise ValueError(f"OrderingParams.grid_size must be a positive integer, got {self.grid_size}")
        if int(self.zone_margin_px) != self.zone_margin_px or self.zone_margin_px < 0:
            raise ValueError(
                f"OrderingParams.zone_margin_px must be a non-negative integer, got {self.zone_margin_px}"
            )
        gap = self.stereo_fill_max_gap_px
        if not (isinstance(gap, (int, float)) and math.isfinite(gap) and gap >= 0):
            raise ValueError(f"OrderingParams.stereo_fill_max_gap_px must be >= 0 (0: off), got {gap!r}")
        for name in ("low_mask_min_gain", "low_mask_max_loss"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0 <= value < 1):
                raise ValueError(f"OrderingParams.{name} must be in [0, 1), got {value!r}")
        for name in ("tip_unexplained_radius_px", "tip_unexplained_max_px", "tip_gap_max_px"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"OrderingParams.{name} must be >= 0, got {value!r}")
        if not 0 < self.tip_gap_max_angle <= math.pi:
            raise ValueError(
                f"OrderingParams.tip_gap_max_angle must be in (0, pi], got {self.tip_gap_max_angle!r}"
            )
        for name in ("max_hole_area_px", "min_eye_width_px"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"OrderingParams.{name} must be >= 0, got {value!r}")
        if int(self.max_steps) != self.max_steps or self.max_steps < 1:
            raise ValueError(f"OrderingParams.max_steps must be a positive integer, got {self.max_steps}")
        if self.reference_width_px is not None and not self.reference_width_px > 0:
            raise ValueError(
                f"OrderingParams.reference_width_px must be positive or None, got {self.reference_width_px}"
            )

    def scale_for(self, width: int) -> float:
        """Factor applied to pixel lengths for a mask ``width`` pixels wide."""
        return 1.0 if self.reference_width_px is None else width / self.reference_width_px

    def with_updates(self, **changes: object) -> OrderingParams:
        """A copy with some fields replaced (validated again)."""
        return replace(self, **changes)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Names of all fields, in declaration order (for ROS parameter declaration)."""
        return tuple(f.name for f in fields(cls))


@dataclass(frozen=True)
class ScaledParams:
    """Pixel values of :class:`OrderingParams` for one image width (internal to the search)."""

    step_radius: int
    roi_radius: int
    tau_o: float
    max_reach: int
    detect_radius: float
    tip_radius: float
    tip_gap_max: float
    max_hole_area: float
    min_eye_width: int
    min_blob_extent: float
    row_tolerance: float
    scale: float

    @classmethod
    def from_params(cls, params: OrderingParams, width: int) -> ScaledParams:
        s = params.scale_for(width)
        step = max(2, round(params.step_radius_px * s))
        roi = max(step, round(params.roi_radius_px * s))
        tau_o = params.tau_o_factor * roi
        return cls(
            step_radius=step,
            roi_radius=roi,
            tau_o=tau_o,
            max_reach=max(roi, math.ceil(tau_o)),
            detect_radius=params.detect_radius_px * s,
            tip_radius=params.tip_radius_px * s,
            tip_gap_max=params.tip_gap_max_px * s,
            max_hole_area=params.max_hole_area_px * s * s,
            min_eye_width=max(1, round(params.min_eye_width_px * s)) if params.min_eye_width_px > 0 else 0,
            min_blob_extent=params.min_blob_extent_px * s,
            row_tolerance=params.row_tolerance_px * s,
            scale=s,
        )
