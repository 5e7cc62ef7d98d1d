# SPDX-License-Identifier: Apache-2.0
"""Procedural surface textures for the suture simulator: in-vivo tissue, silicone phantom, printed photo.

A texture is a square patch of side ``extent_m`` metres sampled on an S x S grid. It carries
the diffuse albedo (linear RGB), a height relief (metres, along the surface normal) and a
specular ("wetness") map, all in texture space so that everything drawn into it -- vessels,
blood, highlights-prone wet patches -- is seen consistently by both cameras of the stereo pair.

Three kinds model the three domains of the segmentation data:

``"tissue"``
    Legacy in-vivo look (da Vinci videos): pink/red/orange multi-octave colour noise, branching
    blood vessels (deep blurred ones and thin superficial ones that look like threads), yellow
    lobulated fat, dark-red blood pools and smears, wet specular patches; smooth bumps and folds
    of up to ~3 mm peak-to-peak.
``"phantom"``
    On-site "Set 1": a silicone suture pad -- pale skin colour with subtle mottling and pores, an
    incision with exposed inner layer, old stitch holes along it, faint scratches, a few fake-blood
    stains, matte-ish with some oily/wet patches; nearly flat (~0.5 mm relief).
``"printed"``
    On-site "Set 2": a colour print of a surgical scene on paper -- saturated tissue, vessels, fat,
    baked-in white highlights, dark instrument shafts with metallic tips and thread-like thin
    dark/bright curves as distractors, under a halftone screen and paper grain; a flat paper with a
    gentle bend (< 1 mm) and a matte, nearly uniform specular map.

Multi-octave noise is built as a pyramid: a coarse grid of blurred (band-limited) random values is
repeatedly upsampled by ~1.9 (``cv2.INTER_CUBIC``) and a finer grid added, with one final
upsampling to the target size. Strokes and blobs are drawn with OpenCV (``polylines``/``ellipse``/
``fillPoly``) on uint8 canvases and softened with ``GaussianBlur``. Smooth layers (colour fields,
fat, blood, deep vessels, wetness, relief) are built on a half-resolution grid and upsampled; thin
features (superficial vessels, the phantom's cut, stitch holes and scratches, the print's
instruments, threads, halftone and grain) are drawn at full resolution. A 512-texel texture takes
~10-15 ms on one core.

Feature sizes are specified in millimetres on the surface and converted with the texture's texels
per millimetre, so a texture looks the same whatever ``size`` is chosen; detail finer than ~2.5
texels is not drawn (noise asked finer is made at 2.5 texels with a proportionally reduced
amplitude), and strokes are at least one texel wide. Only the print's halftone screen and paper
grain are specified in texels (their physical scale, ~0.1-0.2 mm, is below any texel size used).
Heights are centred so that the mid-range relief is at 0.

Everything is deterministic under the ``np.random.Generator`` passed in. Colours are specified in
sRGB (0-255) and converted to linear RGB with a 2.2 power law.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from statistics import NormalDist

import cv2
import numpy as np

#: Texture kinds accepted by :func:`make_surface_texture`.
TEXTURE_KINDS: tuple[str, ...] = ("tissue", "phantom", "printed")

_CV_SHIFT = 4  # sub-pixel bits for OpenCV drawing
_CV_SCALE = float(1 << _CV_SHIFT)


@dataclass
class SurfaceTexture:
    """A square texture patch of side ``extent_m`` metres sampled on an S x S grid.

    Attributes:
        albedo: (S, S, 3) float32, linear RGB diffuse reflectance in [0, 1].
        height: (S, S) float32, relief along the surface normal in metres (zero-mean-ish).
        specular: (S, S) float32 in [0, 1], wet shininess (0 = matte, 1 = wet mirror-like).
        extent_m: side length of the patch in metres (pixel pitch = extent_m / S).
    """

    albedo: np.ndarray
    height: np.ndarray
    specular: np.ndarray
    extent_m: float

    @property
    def size(self) -> int:
        """Number of texels S along each side."""
        return int(self.height.shape[0])

    @property
    def texel_m(self) -> float:
        """Texel pitch in metres."""
        return self.extent_m / self.size


# --------------------------------------------------------------------------------------------
# Small helpers. Colour images are built planar, (3, S, S), because per-pixel blends are ~7x
# faster on contiguous planes than on interleaved (S, S, 3) arrays; they are interleaved at the end.
# --------------------------------------------------------------------------------------------

#: Standard normal quantised to 256 levels (inverse CDF at bin centres, renormalised to unit std):
#: indexing it with random bytes is ~8x faster than ``Generator.standard_normal`` at float32.
_GAUSS_LUT = np.array([NormalDist().inv_cdf((i + 0.5) / 256.0) for i in range(256)], dtype=np.float32)
_GAUSS_LUT /= _GAUSS_LUT.std()
_SRGB_TO_LINEAR = ((np.arange(256, dtype=np.float32) / 255.0) ** 2.2).astype(np.float32)


def _gauss(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Approximately standard-normal float32 noise (256-level quantised) of the given shape."""
    n = int(np.prod(shape))
    return cv2.LUT(rng.integers(0, 256, n, dtype=np.uint8), _GAUSS_LUT).reshape(shape)


def _lin(r: float, g: float, b: float) -> np.ndarray:
    """sRGB 0-255 triple -> (3,) float32 linear RGB (2.2 power law)."""
    return (np.array([r, g, b], dtype=np.float32) / 255.0) ** 2.2


def _jitter(colour: np.ndarray, rng: np.random.Generator, amount: float) -> np.ndarray:
    """Multiply a linear colour by per-channel log-normal factors (std ``amount``)."""
    return (colour * np.exp(rng.normal(0.0, amount, 3))).astype(np.float32)


def _resize(a: np.ndarray, size: int) -> np.ndarray:
    """Cubic resize of an (h, w) or (h, w, k) float32 array to (size, size[, k])."""
    out = cv2.resize(a, (size, size), interpolation=cv2.INTER_CUBIC)
    if a.ndim == 3 and out.ndim == 2:
        out = out[:, :, None]
    return out


def _octave(rng: np.random.Generator, cells: int) -> np.ndarray:
    """(cells, cells) band-limited noise: white noise blurred by 0.8 cell, rescaled to ~unit std.

    The blur makes the noise isotropic; cubic upsampling of raw white noise shows grid-aligned and
    diagonal artefacts.
    """
    grid = cv2.GaussianBlur(_gauss(rng, (cells, cells)), (0, 0), 0.8, borderType=cv2.BORDER_REFLECT)
    grid *= np.float32(2.0 * np.sqrt(np.pi) * 0.8)
    return grid


def _fbm(
    rng: np.random.Generator,
    size: int,
    feature_px: float,
    octaves: int,
    channels: int = 1,
    persistence: float = 0.5,
    fade: bool = True,
) -> np.ndarray:
    """Multi-octave smooth noise, normalised per channel to zero mean and unit std.

    The coarsest octave has a correlation length of about ``feature_px`` texels; each further
    octave is ~1.9x finer (not 2x, so that the octaves' grids do not line up), down to ~2.5
    texels. Noise asked finer than that is made at 2.5 texels and, with ``fade``, its std is
    reduced in proportion (what averaging over a texel would leave of it), so amplitudes stay
    physical (turn it off for noise that is thresholded). Returns planar (channels, size, size)
    float32.
    """
    out = np.empty((channels, size, size), dtype=np.float32)
    finest = max(size * 2 // 5, 2)
    cells0 = int(np.clip(round(size / max(feature_px, 1.0)), 2, finest))
    gain = min(1.0, max(feature_px, 0.1) * finest / size) if fade else 1.0  # < 1 only if clamped
    for k in range(channels):
        cells = cells0
        field = _octave(rng, cells)
        amp = np.float32(1.0)
        for _ in range(octaves - 1):
            finer = min(round(cells * 1.9), finest)
            if finer <= cells:
                break
            field = _resize(field, finer)
            amp *= np.float32(persistence)
            noise = _octave(rng, finer)
            noise *= amp
            field += noise
            cells = finer
        field = _resize(field, size)
        mean, std = cv2.meanStdDev(field)
        field -= np.float32(mean[0, 0])
        np.multiply(field, np.float32(gain / max(std[0, 0], 1e-6)), out=out[k])
    return out


def _smoothstep(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Hermite step from 0 (x <= lo) to 1 (x >= hi), float32 (in-place chain, two temporaries)."""
    t = np.subtract(x, np.float32(lo), dtype=np.float32)
    t *= np.float32(1.0 / (hi - lo))
    np.clip(t, 0.0, 1.0, out=t)
    out = t * np.float32(-2.0)
    out += np.float32(3.0)
    out *= t
    out *= t
    return out


def _half(size: int) -> int:
    """Side of the half-resolution working grid used for the smooth layers."""
    return max(size // 2, 16)


def _upsample(planes: list[np.ndarray] | np.ndarray, size: int, out: np.ndarray | None = None) -> np.ndarray:
    """Bilinear upsampling of k (h, h) float32 planes to a (k, size, size) float32 array."""
    if out is None:
        out = np.empty((len(planes), size, size), dtype=np.float32)
    for k, plane in enumerate(planes):
        cv2.resize(plane, (size, size), dst=out[k], interpolation=cv2.INTER_LINEAR)
    return out


def _blur(a: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur (no-op below 0.3 px); uint8 canvases are blurred as uint8 and scaled to [0, 1].

    Returns float32 of the same shape.
    """
    if sigma_px >= 0.3:
        a = cv2.GaussianBlur(a, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)
    if a.dtype == np.uint8:
        return _to_float(a)
    return a.astype(np.float32, copy=False)


def _grain(rng: np.random.Generator, size: int, feature_px: float) -> np.ndarray:
    """Single-octave fine noise (~unit std, not renormalised), (S, S) float32.

    Correlation length ~``feature_px`` texels, but at least ~2.5 texels (finer grain would only
    alias); grain asked finer is made at 2.5 texels with its std reduced in proportion.
    """
    cells = int(np.clip(round(size / max(feature_px, 2.5)), 2, size))
    grain = cv2.resize(_octave(rng, cells), (size, size), interpolation=cv2.INTER_CUBIC)
    if feature_px < 2.5:
        grain *= np.float32(max(feature_px, 0.1) / 2.5)
    return grain


def _lerp_into(albedo: np.ndarray, mask: np.ndarray, colour: np.ndarray | float) -> None:
    """In place on planar (3, S, S) albedo: albedo += mask * (colour - albedo).

    Restricted to the bounding box of the mask's support (blob and stroke masks are mostly empty)
    and done plane by plane, so temporaries stay small.
    """
    rows = np.flatnonzero(mask.max(axis=1) > 1e-3)
    if rows.size == 0:
        return
    cols = np.flatnonzero(mask[rows[0] : rows[-1] + 1].max(axis=0) > 1e-3)
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    m = mask[box]
    col = np.broadcast_to(np.asarray(colour, dtype=np.float32), (3,))
    for c in range(3):
        sub = albedo[c][box]
        diff = np.subtract(col[c], sub, dtype=np.float32)
        diff *= m
        sub += diff


def _pts(points: np.ndarray) -> np.ndarray:
    """(N, 2) float texel coordinates -> int32 array for OpenCV drawing with ``_CV_SHIFT``."""
    return np.round(np.asarray(points) * _CV_SCALE).astype(np.int32)


@lru_cache(maxsize=16)
def _turn_kernel(smooth: int) -> np.ndarray:
    """Hann window of ~2*smooth taps scaled to unit L2 norm (keeps the smoothed noise's std)."""
    kernel = np.hanning(2 * smooth + 3)[1:-1]
    return kernel / np.sqrt(np.sum(kernel**2))


def _walk(
    rng: np.random.Generator,
    start: np.ndarray,
    heading: float,
    n: int,
    step_px: float,
    turn: float,
    smooth: int = 6,
) -> np.ndarray:
    """Smooth random curve of n steps: (n + 1, 2) texel points.

    The turning rate (rad/step, std ``turn``) is white noise smoothed over ~``smooth`` steps, so
    curves bend gently and only rarely curl into loops.
    """
    kernel = _turn_kernel(smooth)
    omega = np.convolve(rng.normal(0.0, turn, n + 2 * smooth), kernel, mode="valid")[:n]
    theta = heading + np.cumsum(omega)
    steps = np.stack([np.cos(theta), np.sin(theta)], axis=1) * step_px
    return np.vstack([start[None, :], start[None, :] + np.cumsum(steps, axis=0)])


def _border_start(rng: np.random.Generator, size: int, margin: float) -> tuple[np.ndarray, float]:
    """A point just outside a random border of the patch and an inward heading (rad)."""
    side = int(rng.integers(4))
    u = rng.uniform(0.05, 0.95) * size
    point = [(u, -margin), (u, size + margin), (-margin, u), (size + margin, u)][side]
    heading = (np.pi / 2, -np.pi / 2, 0.0, np.pi)[side] + rng.normal(0.0, 0.45)
    return np.array(point, dtype=np.float64), float(heading)


def _canvas(size: int) -> np.ndarray:
    return np.zeros((size, size), dtype=np.uint8)


def _to_float(canvas: np.ndarray) -> np.ndarray:
    return canvas.astype(np.float32) * np.float32(1.0 / 255.0)


def _ellipse(canvas: np.ndarray, centre: np.ndarray, axes: tuple[float, float], angle_deg: float) -> None:
    """Filled anti-aliased ellipse (centre/axes in texels) at full intensity."""
    cx, cy = _pts(np.asarray(centre, dtype=np.float64)[None, :])[0]
    ax = (int(max(axes[0], 0.5) * _CV_SCALE), int(max(axes[1], 0.5) * _CV_SCALE))
    cv2.ellipse(canvas, (int(cx), int(cy)), ax, angle_deg, 0, 360, 255, -1, cv2.LINE_AA, _CV_SHIFT)


def _stroke(canvas: np.ndarray, pts: np.ndarray, width_px: float, value: float | tuple = 255) -> None:
    """Anti-aliased open polyline of the given width (>= 1 px)."""
    cv2.polylines(canvas, [_pts(pts)], False, value, max(1, round(width_px)), cv2.LINE_AA, _CV_SHIFT)


def _paint(colour: np.ndarray, mask: np.ndarray, pts: np.ndarray, width_px: float, value: tuple) -> None:
    """Stroke for compositing: anti-aliased coverage into ``mask`` (S, S) and the straight
    (un-premultiplied) sRGB colour, 2 px wider and aliased, into ``colour`` (S, S, 3)."""
    cv2.polylines(colour, [_pts(pts)], False, value, max(1, round(width_px)) + 2, cv2.LINE_8, _CV_SHIFT)
    _stroke(mask, pts, width_px)


def _composite(albedo: np.ndarray, colour: np.ndarray, mask: np.ndarray) -> None:
    """In place on planar albedo (3, S, S): albedo += coverage * (linear(colour) - albedo), with
    ``colour`` (S, S, 3) uint8 sRGB and ``mask`` (S, S) uint8 coverage, inside the mask's bounding box."""
    rows = np.flatnonzero(mask.max(axis=1))
    if rows.size == 0:
        return
    cols = np.flatnonzero(mask[rows[0] : rows[-1] + 1].max(axis=0))
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    m = _to_float(mask[box])
    for c, plane in enumerate(cv2.split(np.ascontiguousarray(colour[box]))):
        sub = albedo[c][box]
        diff = cv2.LUT(plane, _SRGB_TO_LINEAR)
        diff -= sub
        diff *= m
        sub += diff


def _blob_mask(
    rng: np.random.Generator,
    size: int,
    ppm: float,
    clusters: int,
    per_cluster: tuple[int, int],
    radius_mm: tuple[float, float],
    spread_mm: float,
    edge_noise: np.ndarray,
    roughness: float,
) -> np.ndarray:
    """Irregular soft blobs: clusters of ellipses, blurred, with noise-perturbed outlines.

    Drawn at quarter resolution (cheap), returned as (size, size) float32 in [0, 1].
    ``edge_noise`` is a (size, size) zero-mean unit-std field; it only acts near the blobs.
    """
    if clusters <= 0:
        return np.zeros((size, size), dtype=np.float32)
    low = max(size // 4, 16)
    lppm = ppm * low / size
    canvas = _canvas(low)
    for _ in range(clusters):
        centre = rng.uniform(0.05, 0.95, 2) * low
        for _ in range(int(rng.integers(per_cluster[0], per_cluster[1] + 1))):
            r = rng.uniform(*radius_mm) * lppm
            e = rng.uniform(1.0, 2.2)
            _ellipse(
                canvas, centre + rng.normal(0.0, spread_mm * lppm, 2), (r * e, r / e), rng.uniform(0, 180)
            )
    soft = _resize(_blur(canvas, max(0.3 * radius_mm[0] * lppm, 0.6)), size)
    presence = np.minimum(soft * np.float32(4.0), np.float32(1.0))
    return _smoothstep(soft + np.float32(roughness) * edge_noise * presence, 0.35, 0.65)


def _fibres(rng: np.random.Generator, size: int, ppm: float) -> np.ndarray:
    """Anisotropic streaks (muscle/connective fibres, ~0.7 mm apart) at a random angle, (S, S)."""
    across = int(np.clip(size / (0.7 * ppm), 4, size // 3))
    grid = _gauss(rng, (max(3, across // 12), across))
    streaks = cv2.resize(grid, (size, size), interpolation=cv2.INTER_CUBIC)
    rot = cv2.getRotationMatrix2D((size / 2, size / 2), rng.uniform(0, 180), 1.0)
    return cv2.warpAffine(streaks, rot, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def _normalise_relief(height: np.ndarray, peak_to_peak_m: float) -> np.ndarray:
    """Relief centred on zero and scaled to the given peak-to-peak (metres), float32."""
    lo, hi, _, _ = cv2.minMaxLoc(height)
    out = (height - np.float32(0.5 * (lo + hi))) * np.float32(peak_to_peak_m / max(hi - lo, 1e-9))
    return out.astype(np.float32)


# --------------------------------------------------------------------------------------------
# Tissue
# --------------------------------------------------------------------------------------------


def _vessel_trees(
    rng: np.random.Generator,
    canvas: np.ndarray,
    ppm: float,
    trees: int,
    width_mm: tuple[float, float],
    max_segments: int,
) -> None:
    """Draw branching vessels into ``canvas``: random-walk segments that taper and thin at each
    branch, at most ``max_segments`` segments per tree."""
    size = canvas.shape[0]
    step = max(1.5, 1.0 * ppm)  # ~1 mm per step
    for _ in range(trees):
        start, heading = _border_start(rng, size, 2.0)
        stack = [(start, heading, rng.uniform(*width_mm) * ppm, True)]
        drawn = 0
        while stack and drawn < max_segments:
            p0, h0, w_px, trunk = stack.pop(0)
            n = int(rng.integers(50, 110)) if trunk else int(rng.integers(10, 40))
            pts = _walk(rng, p0, h0, n, step, 0.05)
            half = n // 2
            _stroke(canvas, pts[: half + 1], w_px)
            _stroke(canvas, pts[half:], 0.8 * w_px)
            drawn += 1
            if w_px < 0.8:
                continue
            for _ in range(int(rng.integers(1, 4))):
                k = int(rng.integers(n // 5, n))
                d = pts[k + 1] - pts[k]
                hk = float(np.arctan2(d[1], d[0])) + rng.choice([-1.0, 1.0]) * rng.uniform(0.4, 1.1)
                stack.append((pts[k], hk, w_px * (0.8 if k > half else 1.0) * rng.uniform(0.45, 0.75), False))


def _tissue_layers(
    rng: np.random.Generator, size: int, ppm: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """In-vivo tissue.

    Colour fields, fine grain, fibres (where resolvable), deep vessels, fat, blood, wetness and
    relief are built on a half-resolution grid and upsampled; the thin superficial vessels are
    drawn at full resolution. Returns planar albedo (3, S, S), relief (S, S) in arbitrary units and
    specular (S, S) in [0, 1], all float32.
    """
    h = _half(size)
    hp = ppm * h / size
    f = _fbm(rng, h, 18.0 * hp, 6, channels=5, persistence=0.55)
    mid = _fbm(rng, h, 0.8 * hp, 2)[0]  # fine grain (~0.8 mm)

    pink = _jitter(_lin(214, 112, 106), rng, 0.08)
    red = _jitter(_lin(172, 48, 44), rng, 0.10)
    orange = _jitter(_lin(212, 122, 80), rng, 0.10)
    pale = _jitter(_lin(225, 165, 150), rng, 0.06)
    alb = np.empty((3, h, h), dtype=np.float32)
    alb[:] = pink[:, None, None]
    _lerp_into(alb, np.clip(0.5 + 0.4 * (f[0] + rng.uniform(-0.7, 0.7)), 0.0, 1.0), red)
    _lerp_into(alb, np.clip(0.3 * f[1] + rng.uniform(-0.1, 0.2), 0.0, 0.6), orange)
    _lerp_into(alb, _smoothstep(f[1] - f[0], 1.4, 2.6) * np.float32(0.45), pale)
    shade = np.exp(np.float32(0.15) * f[2])
    shade *= 1.0 + np.float32(0.06) * mid
    if rng.random() < 0.6 and 0.7 * hp >= 2.5:  # fibrous regions (muscle, fascia), where resolvable
        fib = _fibres(rng, h, hp)
        fib *= _smoothstep(f[3], -0.5, 0.8)
        fib *= np.float32(rng.uniform(0.05, 0.12))
        shade += fib
    alb *= shade[None]

    # deep vessels: wide, blurred, purplish, faint
    deep = _canvas(h)
    _vessel_trees(rng, deep, hp, int(rng.integers(1, 4)), (1.2, 3.0), 6)
    _lerp_into(
        alb,
        _blur(deep, 0.6 * hp) * np.float32(rng.uniform(0.25, 0.5)),
        _jitter(_lin(120, 45, 80), rng, 0.1),
    )

    # fat: lobulated, partly translucent yellow clusters
    fat = _blob_mask(
        rng, h, hp, int(rng.integers(0, 4)), (3, 9), (1.5, 4.5), 5.0, 0.6 * f[3] + 0.4 * mid, 0.3
    )
    fat *= np.float32(rng.uniform(0.6, 0.9))
    _lerp_into(alb, fat, _jitter(_lin(238, 200, 118), rng, 0.06))
    alb *= (1.0 + np.float32(0.15) * fat * mid)[None]

    # blood: pools (dark where thick, red and thin at the rims) and smears (thick random strokes)
    blood = _blob_mask(
        rng, h, hp, int(rng.integers(0, 3)), (1, 4), (2.0, 7.0), 3.0, 0.7 * f[4] + 0.3 * mid, 0.35
    )
    smear = _canvas(h)
    for _ in range(int(rng.integers(0, 4))):
        pts = _walk(rng, rng.uniform(0, h, 2), rng.uniform(0, 2 * np.pi), 12, 1.5 * hp, 0.08)
        _stroke(smear, pts, rng.uniform(1.0, 4.0) * hp)
    smear_soft = _blur(smear, 0.6 * hp)
    smear_m = _smoothstep(smear_soft + 0.3 * f[4] * np.minimum(4.0 * smear_soft, 1.0), 0.2, 0.8)
    blood = np.maximum(blood, smear_m * np.float32(rng.uniform(0.5, 0.9)))
    _lerp_into(alb, blood * np.float32(0.9), _jitter(_lin(150, 18, 16), rng, 0.1))
    _lerp_into(alb, _smoothstep(blood, 0.5, 1.0) * np.float32(rng.uniform(0.3, 0.7)), _lin(80, 6, 8))

    # specular: wet baseline, wet patches, shiny blood and fat
    spec = np.clip(0.38 + 0.16 * f[3] + 0.05 * mid, 0.0, 1.0)
    np.maximum(spec, _smoothstep(f[4] + 0.3 * mid, 0.9, 1.6), out=spec)
    np.maximum(spec, np.float32(0.9) * blood, out=spec)
    np.maximum(spec, np.float32(0.5) * fat, out=spec)

    # relief (unit-less): smooth bumps + creased folds (ridged noise) + fat lumps - blood filling hollows
    ridge = 1.0 - np.sqrt(f[0] * f[0] + np.float32(0.02))
    height = 0.3 * f[2] + 0.2 * f[4] + 0.8 * ridge * np.abs(ridge) + 0.8 * fat - 0.2 * blood

    # full resolution: superficial vessels (thin, sharp, dark red)
    up = _upsample([*alb, spec, height], size)
    albedo, spec, height = up[:3], up[3], up[4]
    sup = _canvas(size)
    _vessel_trees(rng, sup, ppm, int(rng.integers(2, 6)), (0.25, 0.9), 8)
    sup_m = _blur(sup, 0.12 * ppm)
    _lerp_into(albedo, sup_m * np.float32(rng.uniform(0.5, 0.85)), _jitter(_lin(125, 18, 30), rng, 0.1))
    sup_m *= np.float32(0.15)
    height += sup_m
    np.clip(albedo, 0.0, 1.0, out=albedo)
    return albedo, height, spec


def _make_tissue(rng: np.random.Generator, size: int, ppm: float) -> tuple[np.ndarray, ...]:
    """In-vivo tissue at ``ppm`` texels/mm.

    Returns planar albedo (3, S, S), height (S, S) in metres and specular (S, S), all float32.
    """
    albedo, height, spec = _tissue_layers(rng, size, ppm)
    return albedo, _normalise_relief(height, rng.uniform(1.5e-3, 3.0e-3)), spec


# --------------------------------------------------------------------------------------------
# Phantom
# --------------------------------------------------------------------------------------------


def _make_phantom(rng: np.random.Generator, size: int, ppm: float) -> tuple[np.ndarray, ...]:
    """Silicone suture pad at ``ppm`` texels/mm.

    Returns planar albedo (3, S, S), height (S, S) in metres and specular (S, S), all float32.
    """
    s = size
    h = _half(size)
    hp = ppm * h / size
    f = _fbm(rng, h, 12.0 * hp, 5, channels=3, persistence=0.5)

    skins = [
        (236, 196, 178),
        (226, 172, 158),
        (240, 208, 186),
        (222, 182, 150),
        (232, 186, 176),
        (214, 160, 150),
    ]
    base = _jitter(_lin(*skins[int(rng.integers(len(skins)))]), rng, 0.04)
    # half resolution: subtle mottling (brightness and a slight red/yellow shift), incision lips,
    # fake-blood stains (low-opacity red paint), matte-ish specular with oily/wet films, relief
    alb = np.empty((3, h, h), dtype=np.float32)
    alb[:] = base[:, None, None]
    alb *= (1.0 + np.float32(0.035) * f[0])[None]
    alb *= 1.0 + np.float32(0.025) * f[1][None] * np.array([1.0, -0.4, -1.0], dtype=np.float32)[:, None, None]

    heading = rng.uniform(0, np.pi)
    length_px = rng.uniform(0.4, 0.8) * s
    n = max(int(length_px / max(1.0, 0.5 * ppm)), 8)
    centre = s * (0.5 + rng.uniform(-0.15, 0.15, 2))
    start = centre - 0.5 * length_px * np.array([np.cos(heading), np.sin(heading)])
    line = _walk(rng, start, heading, n, length_px / n, 0.006, smooth=12)  # full-res texels
    lips = _canvas(h)
    _stroke(lips, line * (h / s), rng.uniform(2.5, 5.0) * hp)
    lips_m = _blur(lips, 0.8 * hp)
    _lerp_into(alb, lips_m * np.float32(rng.uniform(0.15, 0.35)), _jitter(_lin(205, 120, 115), rng, 0.06))
    stains = _blob_mask(rng, h, hp, int(rng.integers(0, 3)), (1, 3), (1.0, 4.0), 2.0, f[2], 0.35)
    _lerp_into(alb, stains * np.float32(rng.uniform(0.3, 0.7)), _jitter(_lin(150, 28, 32), rng, 0.1))
    spec = np.clip(rng.uniform(0.12, 0.28) + 0.06 * f[1], 0.0, 1.0)
    np.maximum(spec, np.float32(0.6) * _smoothstep(f[2], 1.0, 1.8), out=spec)
    np.maximum(spec, np.float32(0.7) * stains, out=spec)
    height = 0.4 * f[0] - 0.4 * lips_m

    # full resolution: pores, the cut (exposing a red or yellow inner layer), stitch holes, scratches
    up = _upsample([*alb, spec, height], s)
    albedo, spec, height = up[:3], up[3], up[4]
    pores = _grain(rng, s, 0.5 * ppm)
    pores *= np.float32(0.03)
    pores += np.float32(1.0)
    albedo *= pores[None]

    cut, holes, scratches = _canvas(s), _canvas(s), _canvas(s)
    _stroke(cut, line, rng.uniform(0.4, 1.2) * ppm)
    # old stitch holes in pairs across the incision, a few strays, some with small tears
    tangent = np.diff(line, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    every = max(1, round(rng.uniform(4.0, 8.0) * ppm / (length_px / n)))
    idx = np.arange(int(rng.integers(0, 3)), len(normal), every)
    idx = idx[rng.random(idx.size) < rng.uniform(0.4, 0.95)]
    offset = rng.uniform(2.0, 4.0) * ppm
    strays = rng.uniform(0, s, (int(rng.integers(0, 6)), 2))
    for c in np.concatenate([line[idx] + normal[idx] * offset, line[idx] - normal[idx] * offset, strays]):
        r = rng.uniform(0.25, 0.5) * ppm
        c = c + rng.normal(0, 0.3 * ppm, 2)
        _ellipse(holes, c, (r * rng.uniform(1.0, 1.6), r), rng.uniform(0, 180))
        if rng.random() < 0.4:
            _stroke(holes, np.stack([c, c + rng.normal(0, 1.0 * ppm, 2)]), 1, 160)
    for _ in range(int(rng.integers(0, 5))):  # faint scratches / knife marks (thin distractors)
        pts = _walk(
            rng, rng.uniform(0, s, 2), rng.uniform(0, 2 * np.pi), 10, rng.uniform(0.5, 1.5) * ppm, 0.05
        )
        _stroke(scratches, pts, 1, int(rng.integers(80, 200)))

    cut_m = _blur(cut, 0.1 * ppm)
    holes_m = _blur(holes, 0.08 * ppm)
    inner = (_lin(150, 50, 55), _lin(200, 150, 80), _lin(120, 40, 45))[int(rng.integers(3))]
    _lerp_into(albedo, cut_m * np.float32(rng.uniform(0.7, 0.95)), _jitter(inner, rng, 0.08))
    _lerp_into(albedo, holes_m * np.float32(rng.uniform(0.6, 0.9)), _jitter(_lin(120, 70, 65), rng, 0.08))
    scratch_col = np.clip(1.15 * base if rng.random() < 0.5 else 0.6 * base, 0.0, 1.0)
    _lerp_into(albedo, _to_float(scratches) * np.float32(0.5), scratch_col)
    np.clip(albedo, 0.0, 1.0, out=albedo)

    np.maximum(spec, np.float32(0.5) * cut_m, out=spec)
    cut_m *= np.float32(1.5)
    height -= cut_m
    holes_m *= np.float32(1.0)
    height -= holes_m
    return albedo, _normalise_relief(height, rng.uniform(0.3e-3, 0.6e-3)), spec


# --------------------------------------------------------------------------------------------
# Printed photo
# --------------------------------------------------------------------------------------------


def _draw_instrument(
    rng: np.random.Generator, colour: np.ndarray, mask: np.ndarray, photo_ppm: float
) -> None:
    """A shaft entering from a border (dark or metallic, cylindrically shaded) with metallic jaws.

    Draws sRGB uint8 values into ``colour`` (S, S, 3) and coverage into ``mask`` (S, S).
    """
    s = mask.shape[0]
    start, heading = _border_start(rng, s, 5.0)
    d = np.array([np.cos(heading), np.sin(heading)])
    nrm = np.array([-d[1], d[0]])
    width = rng.uniform(5.0, 9.0) * photo_ppm
    tip = start + d * rng.uniform(0.3, 0.65) * s
    metallic = rng.random() < 0.35
    base = rng.uniform(150, 200) if metallic else rng.uniform(25, 55)
    blue = rng.uniform(1.0, 1.08)
    stripes = 9
    for k in range(stripes):  # cylindrical shading, stripe by stripe across the shaft
        t = (k + 0.5) / stripes * 2.0 - 1.0
        shade = base * (0.55 + 0.45 * np.sqrt(max(0.0, 1.0 - t * t)))
        if abs(t - 0.35) < 0.15:  # specular stripe
            shade = 235.0 if metallic else 150.0
        seg = np.stack([start, tip]) + nrm * t * width * 0.5
        w = np.ceil(width / stripes) + 1
        _paint(colour, mask, seg, w, (shade, shade, min(255.0, shade * blue)))
    jaw_len = rng.uniform(6.0, 12.0) * photo_ppm
    opening = rng.uniform(0.05, 0.45)
    grey = rng.uniform(160, 215)
    for sgn in (-1.0, 1.0):
        a = heading + sgn * opening
        tri = np.stack(
            [
                tip + nrm * sgn * width * 0.35,
                tip - nrm * sgn * width * 0.05,
                tip + jaw_len * np.array([np.cos(a), np.sin(a)]),
            ]
        )
        cv2.fillPoly(colour, [_pts(tri)], (grey, grey, grey), cv2.LINE_8, _CV_SHIFT)
        cv2.polylines(colour, [_pts(tri)], True, (grey, grey, grey), 2, cv2.LINE_8, _CV_SHIFT)
        cv2.fillPoly(mask, [_pts(tri)], 255, cv2.LINE_AA, _CV_SHIFT)


def _make_printed(rng: np.random.Generator, size: int, ppm: float) -> tuple[np.ndarray, ...]:
    """Printed surgical photo on paper at ``ppm`` texels/mm.

    Returns planar albedo (3, S, S), height (S, S) in metres and specular (S, S), all float32.
    """
    s = size
    # the photo: an in-vivo scene at a random scale on paper, made at half the texture's
    # resolution (a printed endoscope frame carries less detail than the paper could) with the
    # smooth paper relief, then upsampled
    h = _half(s)
    hp = ppm * h / s
    photo_hp = hp * rng.uniform(0.5, 1.6)
    scene, _, spec_scene = _tissue_layers(rng, h, photo_hp)
    # prints are saturated and contrasty: push every channel away from the grey
    grey = scene.mean(axis=0)
    scene -= grey[None]
    scene *= np.float32(rng.uniform(1.15, 1.5))
    scene += grey[None]
    # the photo's specular highlights, baked in as small white spots on the wettest parts
    hl_noise = _fbm(rng, h, 1.2 * photo_hp, 3, fade=False)[0]
    glint = hl_noise * np.float32(0.3)
    glint += spec_scene
    _lerp_into(scene, _smoothstep(glint, rng.uniform(1.3, 1.5), 1.6), 0.92)
    # gentle cylindrical bend along a random direction + faint ~15 mm cockling, < 1 mm in total
    b = rng.uniform(0, np.pi)
    ramp = np.arange(h, dtype=np.float32) * np.float32(1.0 / h)
    t = np.add.outer(ramp * np.float32(np.sin(b)), ramp * np.float32(np.cos(b)))
    t -= np.float32(0.5 * (np.sin(b) + np.cos(b)))
    bend = t * t
    cockle = _grain(rng, h, 15.0 * hp)
    cockle *= np.float32(0.01)
    bend += cockle
    up = _upsample([*scene, hl_noise, bend], s)
    albedo, gloss_noise, height = up[:3], up[3], up[4]
    photo_ppm = photo_hp * s / h

    # painted overlays in sRGB uint8: instruments and thread-like curves (distractors)
    colour = np.zeros((s, s, 3), dtype=np.uint8)
    mask = _canvas(s)
    for _ in range(int(rng.integers(0, 3))):
        _draw_instrument(rng, colour, mask, photo_ppm)
    thread_cols = (
        (45, 25, 70),
        (25, 30, 40),
        (30, 60, 140),
        (225, 230, 220),
        (90, 170, 110),
        (200, 190, 150),
    )
    for _ in range(int(rng.integers(1, 7))):
        col = np.clip(
            np.array(thread_cols[int(rng.integers(len(thread_cols)))]) * rng.uniform(0.8, 1.2), 0, 255
        )
        pts = _walk(
            rng, rng.uniform(0, s, 2), rng.uniform(0, 2 * np.pi), int(rng.integers(20, 80)), photo_ppm, 0.06
        )
        w = rng.uniform(0.2, 0.7) * photo_ppm
        _paint(colour, mask, pts, w, tuple(float(v) for v in col))
    _composite(albedo, colour, mask)

    # print gamut (paper white, inks never reach black), halftone screen, paper grain
    np.clip(albedo, 0.0, 1.0, out=albedo)
    paper = _jitter(_lin(240, 238, 232), rng, 0.02)
    albedo *= np.float32(0.965)
    albedo += np.float32(0.035)
    albedo *= paper[:, None, None]
    lum = albedo.mean(axis=0)
    period = max(2.2, 0.17 * ppm)  # 150 lpi screen, or the finest one the texture can show
    a = rng.uniform(0, np.pi / 2)
    x = np.arange(s, dtype=np.float32) * np.float32(2 * np.pi / period)
    ca, sa = np.float32(np.cos(a)), np.float32(np.sin(a))
    screen = np.cos(np.add.outer(x * sa, x * ca))  # cos(u) * cos(v), u = x ca + y sa, v = y ca - x sa
    screen *= np.cos(np.add.outer(x * ca, -x * sa))
    midtones = np.float32(1.0) - lum  # halftone dots are most visible in the midtones
    midtones *= lum
    midtones *= np.float32(4.0 * rng.uniform(0.04, 0.1))
    screen *= midtones
    grain = _grain(rng, s, 1.5)
    grain *= np.float32(0.03)
    screen += grain
    screen += np.float32(1.0)
    albedo *= screen[None]
    np.clip(albedo, 0.0, 1.0, out=albedo)

    # matte (or semi-gloss) paper; ink slightly glossier than bare paper
    gloss = np.float32(rng.uniform(0.03, 0.22))
    spec = lum * np.float32(-0.3 / max(float(paper.mean()), 1e-3))
    spec += np.float32(1.3)
    gloss_noise *= np.float32(0.15)
    spec += gloss_noise
    spec *= gloss
    return albedo, _normalise_relief(height, rng.uniform(0.2e-3, 0.9e-3)), spec


_MAKERS: dict[str, Callable[[np.random.Generator, int, float], tuple[np.ndarray, ...]]] = {
    "tissue": _make_tissue,
    "phantom": _make_phantom,
    "printed": _make_printed,
}


def make_surface_texture(kind: str, size: int, extent_m: float, rng: np.random.Generator) -> SurfaceTexture:
    """Generate a random surface texture of the given kind.

    Args:
        kind: one of :data:`TEXTURE_KINDS` -- ``"tissue"`` (legacy in-vivo), ``"phantom"``
            (silicone suture pad, on-site Set 1) or ``"printed"`` (colour print of a surgical
            scene on paper, on-site Set 2).
        size: texels S along each side (>= 16).
        extent_m: side length of the square patch in metres (e.g. 0.1); feature sizes (vessel
            widths, fat lumps, stitch holes, ...) are physical and scale with it.
        rng: random generator; the same generator state gives the same texture.

    Returns:
        A :class:`SurfaceTexture` with albedo (S, S, 3) float32 linear RGB in [0, 1], height
        (S, S) float32 metres (tissue 1.5-3 mm peak-to-peak, phantom 0.3-0.6 mm, printed
        0.2-0.9 mm), specular (S, S) float32 in [0, 1] and ``extent_m``.

    Raises:
        ValueError: unknown kind, size < 16 or non-positive extent.
    """
    if kind not in _MAKERS:
        raise ValueError(f"unknown texture kind {kind!r}; valid kinds: {', '.join(TEXTURE_KINDS)}")
    if int(size) < 16:
        raise ValueError(f"texture size must be >= 16, got {size}")
    if not extent_m > 0:
        raise ValueError(f"extent_m must be positive, got {extent_m}")
    size = int(size)
    ppm = size / (extent_m * 1e3)  # texels per millimetre
    albedo, height, spec = _MAKERS[kind](rng, size, ppm)
    return SurfaceTexture(
        albedo=cv2.merge([np.ascontiguousarray(p, dtype=np.float32) for p in albedo]),
        height=np.ascontiguousarray(height, dtype=np.float32),
        specular=np.ascontiguousarray(np.clip(spec, 0.0, 1.0), dtype=np.float32),
        extent_m=float(extent_m),
    )
