# SPDX-License-Identifier: Apache-2.0
"""The thread's ends in the images as the witness of a depth that rests on them
(suture_reconstruction.ends)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from suture_common.camera import StereoCamera
from suture_reconstruction import (
    EndDisparityError,
    GraspNotSeenError,
    ReconstructionParams,
    ThreadTooShortError,
    core,
    reconstruct,
)
from suture_reconstruction.curve import fit_curve
from suture_reconstruction.ends import (
    END_SAMPLES,
    END_WINDOW,
    MIN_END_CONTRAST,
    anchor_row_angle_deg,
    at_occluder,
    end_contrast,
    match_unanchored_ends,
    refuse_contradicted_ends,
    sequence_anchor_deg,
)
from suture_reconstruction.pairing import DisparitySmoothing, Pairs, regularise_disparity
from suture_reconstruction.photometric import match_along_rows, prepare_images, refine_disparity
from suture_reconstruction.sequences import resample

DEPTH = 0.095
#: Arc length (m) from the tip to the grasp point (ReconstructionParams' default).
GRASP_ARC = 0.05


def straight_thread(row_angle_deg: float, wave: float = 0.0) -> np.ndarray:
    """An 80 mm thread DEPTH m away at ``row_angle_deg`` to the image rows (m, every 0.05 mm), its
    cut tip on the right, straight or waving ``wave`` m either side every 20 mm."""
    s = np.arange(0.0, 0.08, 5e-5)
    heading = np.radians(row_angle_deg)
    across = wave * np.sin(2 * np.pi * s / 0.02)
    xy = np.column_stack([-np.cos(heading) * s, np.sin(heading) * s + across]) + np.array([0.035, -0.005])
    return np.column_stack([xy, np.full(len(s), DEPTH)])


def along_rows_then_steep(flat_deg: float = 2.0, steep_deg: float = 45.0) -> np.ndarray:
    """An 85 mm thread DEPTH m away, its cut tip on the right: its first 55 mm at ``flat_deg`` to
    the image rows, then bending over 10 mm to ``steep_deg`` (m, every 0.05 mm)."""
    s = np.arange(0.0, 0.085, 5e-5)
    ramp = np.clip((s - 0.055) / 0.01, 0.0, 1.0)
    heading = np.radians(flat_deg + (steep_deg - flat_deg) * ramp * ramp * (3 - 2 * ramp))
    step = np.column_stack([-np.cos(heading), np.sin(heading)]) * 5e-5
    xy = np.cumsum(step, axis=0) - step[0] + np.array([0.035, 0.0])
    return np.column_stack([xy, np.full(len(s), DEPTH)])


def with_thread(images: tuple[np.ndarray, np.ndarray], camera: StereoCamera, curve: np.ndarray):
    """The images with a dark 2 px thread drawn along the curve's projection in each view."""
    drawn = []
    for image, view in zip(images, ("left", "right"), strict=True):
        mask = np.zeros(image.shape[:2], np.uint8)
        uv = np.rint(camera.project(curve, view) * 16).astype(np.int32)
        cv2.polylines(mask, [uv], False, 255, 2, cv2.LINE_AA, shift=4)
        alpha = mask[..., None] / 255.0
        drawn.append(
            np.clip(image * (1 - alpha) + np.array([40.0, 70.0, 50.0]) * alpha, 0, 255).astype(np.uint8)
        )
    return drawn[0], drawn[1]


def with_shaft(
    images: tuple[np.ndarray, np.ndarray], camera: StereoCamera, edge_u: float, side: int
) -> tuple[np.ndarray, np.ndarray]:
    """The images with an instrument shaft 60 px wide and 15 mm nearer the camera than the thread
    (DEPTH) lying along the columns, its edge at the left view's column ``edge_u`` and its body
    on that ``side`` of it (1: right, -1: left), shaded as a metal cylinder."""
    shaft_disparity = float(camera.disparity(DEPTH - 0.015))
    covered = []
    for image, shift in zip(images, (0.0, shaft_disparity), strict=True):
        across = side * (np.arange(camera.width) + shift - edge_u)  # 0 at the shaft's edge
        inside = (across > 1.0) & (across < 60.0)
        shade = 120.0 + 100.0 * np.sin(np.pi * across[inside] / 60.0)
        shaded = image.copy()
        shaded[:, inside] = shade.astype(np.uint8)[None, :, None]
        covered.append(shaded)
    return covered[0], covered[1]


def test_the_anchor_is_the_steepest_stretch_held_over_5_mm():
    camera = StereoCamera.default(640, 480)
    assert anchor_row_angle_deg(fit_curve(straight_thread(3.0), 0.0), camera) == pytest.approx(3.0, abs=0.5)
    bent = straight_thread(3.0)
    bent[:200, 1] += np.linspace(0.006, 0.0, 200)  # its first 10 mm at about 30 degrees
    assert anchor_row_angle_deg(fit_curve(bent, 0.0), camera) > 20.0


def test_the_sequence_reads_the_same_anchor_as_the_curve_on_a_straight_thread(exact_views):
    camera = StereoCamera.default(640, 480)
    for angle in (3.0, 30.0):
        samples = resample(exact_views(camera, straight_thread(angle))[0], 1.0, 10.0)
        flat = np.full(len(samples.arc), float(camera.disparity(DEPTH)))
        fit = regularise_disparity(
            len(flat), np.arange(len(flat)), flat, np.ones(len(flat)), DisparitySmoothing()
        )
        assert sequence_anchor_deg(samples, fit, camera) == pytest.approx(angle, abs=0.5)


def test_a_thread_either_reading_finds_nowhere_steep_is_checked_at_its_ends(
    exact_views, textured_pair, monkeypatch
):
    """The 3D curve smooths the sequence, so near 10 degrees the curve's reading of the steepest
    stretch and the sequence's, which the refinement goes by, can fall either side of it. A thread
    whose sequence holds no steep stretch has its ends' depth from their pairs, and is checked at
    its ends even where its curve reads one (here the curve's reading is set to 12 degrees).
    Checked by the curve's reading alone, an along_rows frame (sequence 8.1 degrees, curve 10.9)
    went unchecked with its tip 5 px of disparity off and its grasp 13.5 mm off."""
    camera = StereoCamera.default(640, 480)
    curve = straight_thread(3.0, wave=0.0003)
    left, right = exact_views(camera, curve)
    images = with_thread(textured_pair(camera, round(float(camera.disparity(DEPTH + 0.002)))), camera, curve)
    higher = right - np.array([0.0, 0.3])
    monkeypatch.setattr(core, "anchor_row_angle_deg", lambda curve, camera: 12.0)
    with pytest.raises(EndDisparityError, match=r"the steepest: \d\.\d deg.*cut tip -2\.\d px of disparity"):
        reconstruct(left, higher, camera, images=images)


def test_a_curl_of_the_last_2_mm_is_no_anchor():
    """A thread at 3 degrees to the rows whose far end curls steeply over its last 2 mm (as the
    last few points of a sequence may, where the mask ends): a steep stretch must hold over 5 mm,
    and at the thread's end only 2 mm of it is thread. Counted over half the window, it would
    make the thread anchored, so that neither its ends' disparity is checked nor matched."""
    camera = StereoCamera.default(640, 480)
    curled = straight_thread(3.0)
    curled[-40:, 1] += np.linspace(0.0, 0.0015, 40)  # the last 2 mm at about 37 degrees
    assert anchor_row_angle_deg(fit_curve(curled, 0.0), camera) < 10.0


def test_only_an_unanchored_thread_with_an_end_off_the_images_is_refused():
    refuse_contradicted_ends((None, None), 3.0, 1.5)  # no evidence
    refuse_contradicted_ends((1.0, -1.2), 3.0, 1.5)
    refuse_contradicted_ends((6.0, 0.0), 30.0, 1.5)  # a steep stretch measures the depth
    with pytest.raises(EndDisparityError, match=r"cut tip \+6\.0 px of disparity"):
        refuse_contradicted_ends((6.0, 0.0), 3.0, 1.5)
    with pytest.raises(EndDisparityError, match=r"far end -2\.0 px"):
        refuse_contradicted_ends((0.5, -2.0), 3.0, 1.5)


def test_a_thread_along_the_rows_whose_views_sit_a_third_of_a_row_apart_is_refused(
    exact_views, textured_pair
):
    """A thread at 3 degrees to the rows (waving by 1-2 px), its depth resting on its ends: the right
    view's sequence 0.3 px higher than the left's (one mask's edge sitting lower) changes every
    pair's disparity by 0.3 / tan(3 deg) = 6 px along the rows, tilts the thread and puts the grasp
    point more than 5 mm off, while the views still agree on the thread; the images show where its
    ends are, and it is refused."""
    camera = StereoCamera.default(640, 480)
    curve = straight_thread(3.0, wave=0.0003)
    assert anchor_row_angle_deg(fit_curve(curve, 0.0), camera) < 10.0
    left, right = exact_views(camera, curve)
    images = with_thread(textured_pair(camera, round(float(camera.disparity(DEPTH + 0.002)))), camera, curve)
    true_grasp = curve[round(GRASP_ARC / 5e-5)]

    published = reconstruct(left, right, camera, images=images)
    assert np.linalg.norm(published.grasp_position - true_grasp) < 0.002

    higher = right - np.array([0.0, 0.3])
    unchecked = reconstruct(left, higher, camera)  # without images there is no witness
    assert np.linalg.norm(unchecked.grasp_position - true_grasp) > 0.005
    assert unchecked.grasp_uncertainty_mm < 5.0  # the views agree: no other check sees it
    with pytest.raises(EndDisparityError, match=r"cut tip -2\.\d px of disparity"):
        reconstruct(left, higher, camera, images=images)
    with pytest.raises(ValueError, match="max_end_disparity_gap_px"):
        ReconstructionParams(max_end_disparity_gap_px=0.0)


def test_an_end_far_from_any_steep_stretch_takes_its_disparity_from_the_images(exact_views, textured_pair):
    """The first 55 mm from the cut tip run along the rows, so the tip's depth rests on the tip's
    pair: a predicted mask cut 3 px short at the tip in one view is 3 px of disparity (about 10
    mm of depth), and along the rows the thread's own windows match themselves at any shift. The
    window round the tip, which holds its termination, finds the true disparity in the images
    and the fused disparity follows it; a thread steep at both ends is not matched, nor one steep
    nowhere whose pairs the images confirm."""
    camera = StereoCamera.default(640, 480)
    curve = along_rows_then_steep(flat_deg=0.0)
    left, _ = exact_views(camera, curve)
    images = with_thread(textured_pair(camera, round(float(camera.disparity(DEPTH + 0.002)))), camera, curve)
    resampled = resample(left, 1.0, 10.0)
    true_disparity = float(camera.disparity(DEPTH))
    steep_from = round(0.055 * camera.fx / DEPTH)  # left samples (1 px) before the bend
    tip_off = np.full(len(resampled.arc), true_disparity)
    tip_off[:steep_from] += 3.0 * (1.0 - np.arange(steep_from) / steep_from)  # 3 px at the tip, 0 at the bend
    wrong = regularise_disparity(
        len(tip_off), np.arange(len(tip_off)), tip_off, np.ones(len(tip_off)), DisparitySmoothing()
    )

    matched = match_unanchored_ends(prepare_images(*images), resampled, wrong, camera, images, 2.0)
    assert matched is not None
    rows, values = matched
    assert rows.tolist() == list(range(5))  # the tip's 5 outermost samples; the far end is steep
    assert np.abs(values - true_disparity).max() < 0.3

    for anchored_or_not in (straight_thread(30.0), straight_thread(3.0)):
        view, _ = exact_views(camera, anchored_or_not)
        samples = resample(view, 1.0, 10.0)
        flat = np.full(len(samples.arc), true_disparity)
        fit = regularise_disparity(
            len(flat), np.arange(len(flat)), flat, np.ones(len(flat)), DisparitySmoothing()
        )
        thread_images = with_thread(textured_pair(camera, 20), camera, anchored_or_not)
        prepared = prepare_images(*thread_images)
        assert match_unanchored_ends(prepared, samples, fit, camera, thread_images, 2.0) is None

    steep = np.arange(steep_from, len(tip_off))
    pairs = Pairs(  # the tip's pair 3 px off (the cut mask), every steep sample's pair right
        rows=np.r_[0, steep],
        t=np.r_[0, steep].astype(float),
        disparity=np.r_[true_disparity + 3.0, np.full(steep.size, true_disparity)],
        weight=np.r_[0.25, np.ones(steep.size)],
        predicted_t=np.arange(len(tip_off), dtype=float),
        rejected={},
    )
    fused, _ = refine_disparity(
        images, resampled.points, resampled.observed, wrong, pairs, DisparitySmoothing()
    )
    refined, _ = refine_disparity(
        images,
        resampled.points,
        resampled.observed,
        wrong,
        pairs,
        DisparitySmoothing(),
        end_matcher=lambda fused, prepared: matched,
    )
    assert abs(refined.value[0] - true_disparity) < 0.5
    assert not abs(fused.value[0] - true_disparity) < 1.0  # without them: unsupported (NaN) or off


def test_a_thread_nowhere_steep_takes_an_end_from_the_images_where_it_stands_out_and_its_pairs_sit_off(
    exact_views, textured_pair
):
    """A straight thread at 1.5 degrees to the rows, its depth resting on its ends' pairs. The right
    view's sequence 1.5 px to the left of the thread (its mask cut short at both ends, or wider on
    one side) moves every pair's disparity by 1.5 px, about 5 mm of depth: inside the 2 px that the
    end check lets pass, and the grasp point moves with it. The images, matched round each end,
    put the ends where they are and the fused depth follows them. Ends whose pairs the images
    confirm within 1 px (the match's own noise) keep the pairs, ends farther off than
    ``max_end_disparity_gap_px`` are left to the end check, and a thread barely darker than the
    tissue (2 grey levels on tissue varying by 5), which leaves the window mostly the tissue's
    noise to match, keeps its pairs."""
    camera = StereoCamera.default(640, 480)
    curve = straight_thread(1.5)
    left, right = exact_views(camera, curve)
    images = with_thread(textured_pair(camera, round(float(camera.disparity(DEPTH + 0.002)))), camera, curve)
    true_grasp = curve[round(GRASP_ARC / 5e-5)]
    shifted = right - np.array([1.5, 0.0])

    without_images = reconstruct(left, shifted, camera)
    assert np.linalg.norm(without_images.grasp_position - true_grasp) > 0.004
    with_images = reconstruct(left, shifted, camera, images=images)
    assert np.linalg.norm(with_images.grasp_position - true_grasp) < 0.002

    samples = resample(left, 1.0, 10.0)
    tip = samples.points[:END_SAMPLES]
    assert end_contrast(images[0], samples.points, tip) >= MIN_END_CONTRAST
    noise = np.random.default_rng(1).normal(0.0, 5.0, (camera.height, camera.width + 40))
    plain = np.clip(128.0 + noise, 0, 255)
    shift = round(float(camera.disparity(DEPTH + 0.002)))
    plain_pair = (
        np.dstack([plain[:, : camera.width]] * 3),
        np.dstack([plain[:, shift : shift + camera.width]] * 3),
    )
    faint = []
    for image, view in zip(plain_pair, ("left", "right"), strict=True):
        drawn = np.zeros(image.shape[:2], np.uint8)
        cv2.polylines(drawn, [np.rint(camera.project(curve, view)).astype(np.int32)], False, 1, 2)
        faint.append((image - 2.0 * drawn[..., None]).astype(np.uint8))
    faint = (faint[0], faint[1])
    assert end_contrast(faint[0], samples.points, tip) < MIN_END_CONTRAST
    true_disparity = float(camera.disparity(DEPTH))

    def matched_at(offset_px: float, views: tuple[np.ndarray, np.ndarray]):
        flat = np.full(len(samples.arc), true_disparity + offset_px)
        fit = regularise_disparity(
            len(flat), np.arange(len(flat)), flat, np.ones(len(flat)), DisparitySmoothing()
        )
        return match_unanchored_ends(prepare_images(*views), samples, fit, camera, views, 2.0)

    rows, values = matched_at(1.5, images)
    assert set(rows.tolist()) == set(range(END_SAMPLES)) | set(
        range(len(samples.arc) - END_SAMPLES, len(samples.arc))
    )
    assert np.abs(values - true_disparity).max() < 0.5  # the tissue 2 mm behind pulls the window a little
    assert matched_at(0.5, images) is None  # the pairs confirmed
    assert matched_at(3.0, images) is None  # the end check's to refuse
    assert matched_at(1.5, faint) is None  # hardly any thread to match


def test_an_end_under_an_instrument_is_not_matched_in_the_images(exact_views, textured_pair):
    """The thread of the test above with its first 10 mm under an instrument shaft lying across
    it, 15 mm nearer the camera: the left sequence starts at the shaft's edge. The window round
    that end holds the edge, at the shaft's depth, and the images put the end 1-3 px of disparity
    (3-10 mm) too near. Past the end lies the shaft, which the right view puts nearer than
    the thread: the end is not matched. With tissue past it (the thread drawn on), it is."""
    camera = StereoCamera.default(640, 480)
    curve = along_rows_then_steep(flat_deg=0.0)
    left, _ = exact_views(camera, curve[round(0.010 / 5e-5) :])
    samples = resample(left, 1.0, 10.0)
    true_disparity = float(camera.disparity(DEPTH))
    flat = np.full(len(samples.arc), true_disparity)
    fit = regularise_disparity(
        len(flat), np.arange(len(flat)), flat, np.ones(len(flat)), DisparitySmoothing()
    )
    tissue = with_thread(textured_pair(camera, round(float(camera.disparity(DEPTH + 0.002)))), camera, curve)
    images = with_shaft(tissue, camera, float(left[0, 0]), side=1)
    prepared = prepare_images(*images)
    tip = np.arange(5)
    tangents = np.gradient(samples.points, axis=0)
    edge_match = match_along_rows(*prepared, samples.points[tip], tangents[tip], flat[tip], END_WINDOW)
    assert np.median(edge_match.disparity[edge_match.matched]) > true_disparity + 1.5

    assert at_occluder(images, samples.points, 0, 1, true_disparity)
    assert match_unanchored_ends(prepared, samples, fit, camera, images, 2.0) is None
    assert not at_occluder(tissue, samples.points, 0, 1, true_disparity)
    assert match_unanchored_ends(prepare_images(*tissue), samples, fit, camera, tissue, 2.0) is not None


def test_a_thread_under_an_instrument_short_of_the_grasp_point_is_refused_as_not_seen(
    exact_views, textured_pair
):
    """A thread at 30 degrees to the rows whose stretch from 40 mm on lies under an instrument
    shaft 15 mm nearer the camera: both views' sequences end at the shaft's edge, 10 mm short of
    the grasp point, which is hidden; the refusal says so (GraspNotSeenError). The same sequences
    on bare tissue end where the thread does: ThreadTooShortError."""
    camera = StereoCamera.default(640, 480)
    seen = straight_thread(30.0)[: round(0.040 / 5e-5)]
    left, right = exact_views(camera, seen)
    tissue = with_thread(textured_pair(camera, round(float(camera.disparity(DEPTH + 0.002)))), camera, seen)
    covered = with_shaft(tissue, camera, float(left[-1, 0]), side=-1)
    with pytest.raises(GraspNotSeenError, match="under something nearer the camera") as refused:
        reconstruct(left, right, camera, images=covered)
    assert refused.value.uncertainty is None
    with pytest.raises(ThreadTooShortError):
        reconstruct(left, right, camera, images=tissue)
    with pytest.raises(ThreadTooShortError):
        reconstruct(left, right, camera)  # without images nothing tells
