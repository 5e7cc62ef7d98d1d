# SPDX-License-Identifier: Apache-2.0
"""Reconstruction metrics (paper Tables II and III) and the 3D-stage benchmark over bags."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from suture_bench.reconstruction_metrics import (
    KEYPOINTS,
    distances_to_polyline,
    main,
    perturb_sequence,
    points_along,
    score_reconstruction,
    summarise,
)

SAMPLE_BAG = Path(__file__).resolve().parents[3] / "bags" / "sample"


def test_distances_to_polyline_are_to_segments_not_vertices():
    polyline = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.01, 0.01, 0]])
    points = np.array([[0.005, 0.002, 0], [0.02, 0.005, 0], [-0.003, 0, 0.004], [0.01, 0.01, 0]])
    np.testing.assert_allclose(distances_to_polyline(points, polyline), [0.002, 0.01, 0.005, 0.0], atol=1e-15)
    assert distances_to_polyline(points[:1], polyline[:1])[0] == pytest.approx(np.hypot(0.005, 0.002))


def test_score_of_a_shifted_longer_path():
    true = np.column_stack([np.linspace(0, 0.1, 201), np.zeros(201), np.full(201, 0.1)])
    pred = true + np.array([0.0, 0.001, 0.0])  # 1 mm to the side
    score = score_reconstruction(pred, true, pred[100], true[100])
    assert score.mean_error == pytest.approx(0.001) and score.max_error == pytest.approx(0.001)
    assert score.length_error == pytest.approx(0.0, abs=1e-12)
    assert score.keypoint_errors.shape == (KEYPOINTS,)
    np.testing.assert_allclose(score.keypoint_errors, 0.001)
    assert score.grasp_error == pytest.approx(0.001)
    longer = np.vstack([true, [[0.11, 0.0, 0.1]]])
    score = score_reconstruction(longer, true, None, true[100])
    assert score.length_error == pytest.approx(0.01) and score.max_error == pytest.approx(0.01)
    assert score.grasp_error is None
    assert score.as_mm()["length_error_mm"] == pytest.approx(10.0)
    np.testing.assert_allclose(points_along(true, 3)[:, 0], [0.0, 0.05, 0.1])


def test_bad_paths():
    with pytest.raises(ValueError, match="empty"):
        score_reconstruction(np.zeros((0, 3)), np.zeros((2, 3)), None, np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        score_reconstruction(np.full((2, 3), np.nan), np.zeros((2, 3)), None, np.zeros(3))


def test_summary_per_group():
    true = np.column_stack([np.linspace(0, 0.1, 101), np.zeros(101), np.full(101, 0.1)])
    scores = [
        score_reconstruction(true + np.array([0, dy, 0]), true, true[50] + np.array([0, g, 0]), true[50])
        for dy, g in ((0.0005, 0.001), (0.001, 0.002), (0.0015, 0.004))
    ]
    s = summarise([*scores, None])
    assert (s.frames, s.failures) == (3, 1)
    assert s.mean_error_mm == pytest.approx(1.0) and s.worst_frame_mm == pytest.approx(1.5)
    assert s.grasp_median_mm == pytest.approx(2.0) and s.grasp_max_mm == pytest.approx(4.0)
    assert s.keypoint_mm.shape == (KEYPOINTS,)
    empty = summarise([None])
    assert empty.frames == 0 and np.isnan(empty.mean_error_mm)


def test_perturbation_looks_like_ordering_output():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 1, 400)
    truth = np.column_stack([100 + 300 * t, 200 + 50 * np.sin(6 * t), np.ones_like(t)])
    a = perturb_sequence(truth, rng)
    b = perturb_sequence(truth, rng)
    assert a.shape[1] == 2
    assert len(a) != len(b) or not np.allclose(a, b)  # each call draws its own sampling and noise
    assert np.linalg.norm(a[0] - truth[0, :2]) < 1.5  # starts at the cut tip (plus noise)
    steps = np.linalg.norm(np.diff(a, axis=0), axis=1)
    assert 0.9 < np.median(steps) < 1.3  # ~1 px apart (noise lengthens steps a little)
    clean = perturb_sequence(truth, np.random.default_rng(1), noise_px=0.0)
    dense = np.column_stack([np.interp(np.linspace(0, 1, 20000), t, truth[:, k]) for k in range(2)])
    offsets = np.min(np.linalg.norm(a[:, None] - dense[None, ::5], axis=2), axis=1)
    assert 0.15 < np.sqrt(np.mean(offsets**2)) < 0.4  # ~0.3 px across the thread
    assert np.max(np.min(np.linalg.norm(clean[:, None] - dense[None, ::5], axis=2), axis=1)) < 0.05


def test_benchmark_command_on_the_sample_bag(tmp_path, capsys):
    report = tmp_path / "bench.json"
    assert main([str(SAMPLE_BAG), "--json", str(report)]) == 0
    out = capsys.readouterr().out
    for word in ("straight", "curved", "self_intersected", "crossed", "occluded", "Table II", "Table III"):
        assert word in out
    assert "ms per stereo pair on one CPU core" in out and "reconstruct()" in out
    payload = json.loads(report.read_text())
    assert len(payload["frames"]) == 10 and payload["summary"]["all"]["frames"] == 10
    assert payload["summary"]["all"]["mean_error_mm"] < 1.0


def test_benchmark_command_reports_a_bad_path(tmp_path, capsys):
    assert main([str(tmp_path / "missing")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("suture-recon-bench:") and err.count("\n") == 1
