# SPDX-License-Identifier: Apache-2.0
"""Tests of the procedural surface textures and the camera/domain appearance effects."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from suture_sim.appearance import DOMAINS, Look, apply_look, sample_look, vignetting
from suture_sim.textures import TEXTURE_KINDS, SurfaceTexture, make_surface_texture

# peak-to-peak relief bounds per kind, metres
RELIEF = {"tissue": (1.4e-3, 3.05e-3), "phantom": (0.25e-3, 0.65e-3), "printed": (0.15e-3, 1.0e-3)}


def _texture(kind: str, seed: int, size: int = 128, extent: float = 0.1) -> SurfaceTexture:
    return make_surface_texture(kind, size, extent, np.random.default_rng(seed))


# --------------------------------------------------------------------------------------------
# Textures
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", TEXTURE_KINDS)
@pytest.mark.parametrize(("size", "extent"), [(128, 0.1), (256, 0.28)])
def test_texture_shapes_dtypes_and_ranges(kind: str, size: int, extent: float) -> None:
    for seed in range(3):
        tex = _texture(kind, seed, size, extent)
        assert tex.albedo.shape == (size, size, 3) and tex.albedo.dtype == np.float32
        assert tex.height.shape == (size, size) and tex.height.dtype == np.float32
        assert tex.specular.shape == (size, size) and tex.specular.dtype == np.float32
        assert tex.extent_m == extent and tex.size == size
        assert tex.texel_m == pytest.approx(extent / size)
        for a in (tex.albedo, tex.height, tex.specular):
            assert np.isfinite(a).all()
        assert tex.albedo.min() >= 0.0 and tex.albedo.max() <= 1.0
        assert tex.specular.min() >= 0.0 and tex.specular.max() <= 1.0
        lo, hi = RELIEF[kind]
        assert lo <= np.ptp(tex.height) <= hi
        # relief is smooth enough to shade and to lift threads onto: slopes well below 45 degrees
        gy, gx = np.gradient(tex.height.astype(np.float64), tex.texel_m)
        assert np.hypot(gx, gy).max() < 1.0
        # not a flat colour: some texture in every kind
        assert tex.albedo.reshape(-1, 3).std(axis=0).mean() > 0.005


@pytest.mark.parametrize("kind", TEXTURE_KINDS)
def test_texture_is_deterministic_per_seed(kind: str) -> None:
    a, b, c = _texture(kind, 11), _texture(kind, 11), _texture(kind, 12)
    for name in ("albedo", "height", "specular"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.albedo, c.albedo)
    assert not np.array_equal(a.height, c.height)


def test_unknown_kind_and_bad_arguments_raise() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="tissue, phantom, printed"):
        make_surface_texture("marble", 64, 0.1, rng)
    with pytest.raises(ValueError, match="size"):
        make_surface_texture("tissue", 8, 0.1, rng)
    with pytest.raises(ValueError, match="extent"):
        make_surface_texture("tissue", 64, 0.0, rng)


def test_texture_kinds_have_their_character() -> None:
    def mean_stats(kind: str) -> tuple[np.ndarray, float, float]:
        texs = [_texture(kind, s) for s in range(4)]
        albedo = np.mean([t.albedo.reshape(-1, 3).mean(axis=0) for t in texs], axis=0)
        return (
            albedo,
            float(np.mean([t.specular.mean() for t in texs])),
            float(np.mean([np.ptp(t.height) for t in texs])),
        )

    tissue, phantom, printed = (mean_stats(k) for k in TEXTURE_KINDS)
    # in-vivo tissue is red (R well above G and B) and wet
    assert tissue[0][0] > 2.5 * tissue[0][1] and tissue[0][0] > 2.5 * tissue[0][2]
    assert tissue[1] > 0.35
    # the silicone pad is pale skin-coloured: brighter and less saturated than tissue, matte-ish, flat
    assert phantom[0].mean() > 1.5 * tissue[0].mean()
    assert phantom[0][0] / phantom[0][2] < 0.5 * tissue[0][0] / tissue[0][2]
    assert phantom[1] < tissue[1] and phantom[2] < 0.4 * tissue[2]
    # the print on paper is the most matte and nearly flat, but as colourful as the tissue it shows
    assert printed[1] < phantom[1] and printed[2] < 0.5 * tissue[2]
    assert printed[0][0] > 2.5 * printed[0][1]


def _correlation_length_m(tex: SurfaceTexture, size: int) -> float:
    """Lag (metres) at which the autocorrelation of the albedo luminance, area-averaged to
    size x size texels, drops below 0.5."""
    lum = cv2.resize(tex.albedo.mean(axis=2), (size, size), interpolation=cv2.INTER_AREA).astype(np.float64)
    lum -= lum.mean()
    acf = np.real(np.fft.ifft2(np.abs(np.fft.fft2(lum)) ** 2))
    acf /= acf[0, 0]
    radial = 0.5 * (acf[0, : size // 2] + acf[: size // 2, 0])
    return float(np.argmax(radial < 0.5) * tex.extent_m / size)


@pytest.mark.parametrize("kind", TEXTURE_KINDS)
def test_feature_sizes_are_physical(kind: str) -> None:
    """Feature sizes are set in millimetres: at the renderer's texel pitches (512 and 1024 texels
    over ~0.28 m; here 256 and 512 over 0.14 m), seen at the same resolution, a texture with twice
    the texels has about the same correlation length."""

    def length(size: int) -> float:
        return float(np.median([_correlation_length_m(_texture(kind, s, size, 0.14), 128) for s in range(6)]))

    assert 0.6 < length(512) / length(256) < 1.6


def test_feature_sizes_follow_the_extent() -> None:
    """The same texel count over twice the extent shows features half as many texels wide."""

    def texels(extent: float) -> float:
        lengths = [_correlation_length_m(_texture("tissue", s, 256, extent), 256) for s in range(6)]
        return float(np.median(lengths)) / (extent / 256)

    assert 1.3 < texels(0.14) / texels(0.28) < 2.8


# --------------------------------------------------------------------------------------------
# Looks
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("domain", DOMAINS)
def test_sample_look_is_deterministic_and_varies(domain: str) -> None:
    a = sample_look(domain, np.random.default_rng(5))
    assert a == sample_look(domain, np.random.default_rng(5))
    assert hash(a) == hash(sample_look(domain, np.random.default_rng(5)))
    looks = [sample_look(domain, np.random.default_rng(s)) for s in range(20)]
    assert len(set(looks)) == 20
    for look in looks:
        assert look.domain == domain
        m = look.color_matrix_array
        assert m.shape == (3, 3)
        np.testing.assert_allclose(m.sum(axis=1), 1.0, atol=1e-9)  # grey stays grey
        assert look.gamma > 1 and look.read_noise_sigma > 0 and look.shot_noise_gain > 0
        assert look.jpeg_quality is None or 1 <= look.jpeg_quality <= 100


def test_domain_parameter_ranges_are_separated() -> None:
    legacy = [sample_look("legacy", np.random.default_rng(s)) for s in range(50)]
    onsite = [sample_look("on-site", np.random.default_rng(s)) for s in range(50)]
    assert all(lk.internal_scale == 1.0 for lk in legacy)
    assert all(0.8 <= lk.internal_scale <= 0.95 for lk in onsite)
    assert all(lk.jpeg_quality is not None and lk.jpeg_quality <= 85 for lk in onsite)
    assert max(lk.read_noise_sigma for lk in legacy) < min(lk.read_noise_sigma for lk in onsite)
    assert max(lk.shot_noise_gain for lk in legacy) < min(lk.shot_noise_gain for lk in onsite)
    assert max(lk.vignetting for lk in legacy) < min(lk.vignetting for lk in onsite)
    assert all(lk.white_balance[0] > lk.white_balance[2] for lk in legacy)  # warm
    assert all(lk.white_balance[0] < lk.white_balance[1] for lk in onsite)  # cool / green


def test_unknown_domain_raises() -> None:
    with pytest.raises(ValueError, match="legacy, on-site"):
        sample_look("da-vinci", np.random.default_rng(0))


# --------------------------------------------------------------------------------------------
# apply_look
# --------------------------------------------------------------------------------------------


def _flat(value: float, shape: tuple[int, int] = (240, 320)) -> np.ndarray:
    return np.full((*shape, 3), value, dtype=np.float32)


def _edge(shape: tuple[int, int] = (240, 320)) -> np.ndarray:
    img = _flat(0.05, shape)
    img[:, shape[1] // 2 :] = 0.5
    return img


@pytest.mark.parametrize("domain", DOMAINS)
@pytest.mark.parametrize("shape", [(240, 320), (123, 77)])
def test_apply_look_shape_dtype_and_determinism(domain: str, shape: tuple[int, int]) -> None:
    image = np.random.default_rng(0).random((*shape, 3), dtype=np.float32) * 0.8
    before = image.copy()
    look = sample_look(domain, np.random.default_rng(1))
    a = apply_look(image, look, np.random.default_rng(2))
    b = apply_look(image, look, np.random.default_rng(2))
    c = apply_look(image, look, np.random.default_rng(3))
    assert a.shape == (*shape, 3) and a.dtype == np.uint8
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)  # independent noise draws (e.g. left and right eye)
    np.testing.assert_array_equal(image, before)  # the input is not modified
    # the two eyes share the look: same statistics up to noise
    assert abs(float(a.mean()) - float(c.mean())) < 1.0


def test_apply_look_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError, match="H, W, 3"):
        apply_look(np.zeros((10, 10), np.float32), Look.neutral(), np.random.default_rng(0))


def test_neutral_look_is_plain_gamma_encoding() -> None:
    ramp = np.repeat(np.linspace(0.0, 1.0, 64, dtype=np.float32)[None, :, None], 3, axis=2)
    out = apply_look(np.repeat(ramp, 4, axis=0), Look.neutral(), np.random.default_rng(0))
    expected = np.round(255.0 * np.linspace(0.0, 1.0, 64) ** (1 / 2.2))
    np.testing.assert_allclose(out[0, :, 1], expected, atol=1.0)
    # out-of-range input saturates
    assert apply_look(_flat(3.0, (8, 8)), Look.neutral(), np.random.default_rng(0)).min() == 255


def test_individual_effects() -> None:
    base = Look.neutral()
    edge = np.zeros((64, 64, 3), np.float32)
    edge[:, 32:] = 0.5
    edge[32:, :] += 0.25

    def spread(img: np.ndarray, axis: int) -> int:
        """Number of intermediate levels across the edge along the axis (a blur measure)."""
        line = img[16, :, 1] if axis == 1 else img[:, 16, 1]
        lo, hi = int(line.min()), int(line.max())
        return int(np.sum((line > lo + 2) & (line < hi - 2)))

    sharp = apply_look(edge, base, np.random.default_rng(0))
    moved = apply_look(edge, dataclasses.replace(base, motion_blur_px=9.0), np.random.default_rng(0))
    assert spread(moved, 1) >= spread(sharp, 1) + 4  # horizontal motion smears the vertical edge
    assert spread(moved, 0) <= spread(sharp, 0) + 1  # ... but not the horizontal one
    defocus = apply_look(edge, dataclasses.replace(base, defocus_sigma_px=2.0), np.random.default_rng(0))
    assert spread(defocus, 1) >= spread(sharp, 1) + 3 and spread(defocus, 0) >= spread(sharp, 0) + 3
    small = apply_look(edge, dataclasses.replace(base, internal_scale=0.5), np.random.default_rng(0))
    assert small.shape == sharp.shape and spread(small, 1) > spread(sharp, 1)
    jpeg = apply_look(edge, dataclasses.replace(base, jpeg_quality=30), np.random.default_rng(0))
    assert not np.array_equal(jpeg, sharp) and np.abs(jpeg.astype(int) - sharp).mean() < 4
    noisy = apply_look(
        _flat(0.2, (64, 64)), dataclasses.replace(base, shot_noise_gain=4e-3), np.random.default_rng(0)
    )
    dark = apply_look(
        _flat(0.01, (64, 64)), dataclasses.replace(base, shot_noise_gain=4e-3), np.random.default_rng(0)
    )
    assert noisy.std() > 3.0 and dark.std() > 0.5
    warm = apply_look(
        _flat(0.2, (8, 8)), dataclasses.replace(base, white_balance=(1.2, 1.0, 0.8)), np.random.default_rng(0)
    )
    assert warm[..., 0].mean() > warm[..., 1].mean() > warm[..., 2].mean()


# --------------------------------------------------------------------------------------------
# Domain gap, measured on simple test charts over many frames
# --------------------------------------------------------------------------------------------


def _frames(domain: str, image: np.ndarray, n: int = 12) -> list[np.ndarray]:
    return [
        apply_look(image, sample_look(domain, np.random.default_rng(s)), np.random.default_rng(100 + s))
        for s in range(n)
    ]


def _noise_std(frame: np.ndarray) -> float:
    """High-pass std in a central patch (the smooth vignetting falloff is removed)."""
    f = frame.astype(np.float32)
    hp = f - cv2.GaussianBlur(f, (0, 0), 4.0)
    h, w = f.shape[:2]
    return float(hp[h // 2 - 40 : h // 2 + 40, w // 2 - 40 : w // 2 + 40].std())


def _edge_sharpness(frame: np.ndarray) -> float:
    """Largest step between neighbouring pixels across the edge over the edge's total rise."""
    rows = frame[100:140, :, 1].astype(np.float32).mean(axis=0)
    mid = frame.shape[1] // 2
    rise = rows[mid + 20 : mid + 30].mean() - rows[mid - 30 : mid - 20].mean()
    return float(np.abs(np.diff(rows[mid - 10 : mid + 10])).max() / max(rise, 1e-6))


def test_on_site_is_noisier_than_legacy() -> None:
    legacy = np.mean([_noise_std(f) for f in _frames("legacy", _flat(0.2))])
    onsite = np.mean([_noise_std(f) for f in _frames("on-site", _flat(0.2))])
    assert onsite > 2.0 * legacy
    assert legacy < 2.0  # legacy is clean


def test_on_site_is_blurrier_than_legacy() -> None:
    legacy = np.mean([_edge_sharpness(f) for f in _frames("legacy", _edge())])
    onsite = np.mean([_edge_sharpness(f) for f in _frames("on-site", _edge())])
    assert legacy > 0.5
    assert legacy > 1.4 * onsite  # softer, not blurred out: measured 0.78 against 0.49


def test_colour_casts_differ() -> None:
    def mean_rgb(domain: str) -> np.ndarray:
        frames = _frames(domain, _flat(0.2))
        return np.mean([f[100:140, 140:180].reshape(-1, 3).mean(axis=0) for f in frames], axis=0)

    legacy, onsite = mean_rgb("legacy"), mean_rgb("on-site")
    assert legacy[0] > legacy[1] > legacy[2]  # warm
    assert onsite[1] > onsite[0] and onsite[2] > onsite[0]  # cool / greenish
    assert onsite[1] / onsite[0] > 1.1 * legacy[1] / legacy[0]


def test_on_site_vignetting_is_stronger() -> None:
    def corner_ratio(domain: str) -> float:
        frames = _frames(domain, _flat(0.3), n=8)
        return float(np.mean([f[:20, :20].mean() / f[110:130, 150:170].mean() for f in frames]))

    assert corner_ratio("on-site") < corner_ratio("legacy") - 0.1


def test_vignetting_map() -> None:
    v = vignetting(48, 64, 1.0)
    assert v.shape == (48, 64) and v.dtype == np.float32
    assert v.max() <= 1.0 and v[23:25, 31:33].min() > 0.99
    assert v[0, 0] == pytest.approx(0.25, rel=1e-4) and v[-1, -1] == pytest.approx(0.25, rel=1e-4)
    assert (np.diff(v[24, 32:]) <= 0).all()  # falls off monotonically
    np.testing.assert_array_equal(vignetting(10, 12, 0.0), np.ones((10, 12), np.float32))
    with pytest.raises(ValueError):
        vignetting(10, 10, -0.1)
