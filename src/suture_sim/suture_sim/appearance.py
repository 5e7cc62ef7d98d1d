# SPDX-License-Identifier: Apache-2.0
"""Camera and domain appearance: turns a composited linear-RGB render into an 8-bit camera frame.

The renderer composites a linear-RGB float32 image (scene radiance, nominally in [0, 1]); this
module applies everything the endoscope and its video chain do to it, with per-frame parameters
held in a :class:`Look` drawn per domain by :func:`sample_look`:

1. internal resolution: the image is area-downsampled by ``internal_scale`` (the on-site camera's
   effective resolution is lower than the output; it is upsampled again at the end);
2. optics: Gaussian defocus and linear motion blur (lengths given in output pixels);
3. exposure: global gain and radial vignetting (light falloff of the endoscope);
4. sensor colour: white-balance gains and a 3x3 colour matrix (spectral response / colour
   correction), applied as one matrix with ``cv2.transform``;
5. sensor noise: shot noise as the Gaussian approximation of Poisson noise, variance
   ``shot_noise_gain * x`` for a linear signal x (i.e. about ``x / shot_noise_gain`` photo-electrons),
   plus signal-independent read noise of std ``read_noise_sigma`` -- one normal draw per pixel and
   channel with std ``sqrt(read_noise_sigma**2 + shot_noise_gain * max(x, 0))``;
6. tone curve: power-law gamma, an S-curve contrast term and a black-level lift, then 8-bit
   quantisation;
7. optional unsharp masking (the legacy video chain sharpens), upsampling back to the output size,
   and optional JPEG compression round trip.

The ``legacy`` domain mimics da Vinci video frames (warm colour, mostly sharp, mild noise, full
resolution, mild sharpening and light compression); ``on-site`` mimics a different endoscope
(cooler/greener cast, desaturated colour matrix with a hue shift, lifted blacks, flat contrast,
several times the legacy shot and read noise, slightly lower internal resolution 0.8-0.95, mild
defocus, stronger vignetting, JPEG artefacts). ``random`` draws every parameter from ranges that
hold both and reach well beyond them (domain randomisation for training a model meant for
cameras not seen in training). The gap between the domains is in colour, tone
and noise rather than in detail: an on-site thread stays resolvable, as it is for a real second
endoscope of similar resolution (a 0.5-0.7 internal scale with strong defocus capped even a
model trained on 1000 on-site images at 53-61 % IoU).

The same :class:`Look` is applied to the left and the right image of a stereo frame; every call
of :func:`apply_look` makes its own noise draws. Everything is deterministic under the
``np.random.Generator`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from statistics import NormalDist

import cv2
import numpy as np

#: Domains accepted by :func:`sample_look`.
DOMAINS: tuple[str, ...] = ("legacy", "on-site", "random")

#: Standard normal quantised to 256 levels (inverse CDF at bin centres, renormalised to unit std):
#: indexing it with random bytes is several times faster than ``Generator.standard_normal``.
_GAUSS_LUT = np.array([NormalDist().inv_cdf((i + 0.5) / 256.0) for i in range(256)], dtype=np.float32)
_GAUSS_LUT /= _GAUSS_LUT.std()

#: Rec. 709 luma weights (linear RGB).
_LUMA = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class Look:
    """Per-frame camera/domain parameters (immutable, hashable; compare with ``==``).

    Attributes:
        domain: the domain the look was drawn for (informational).
        gain: global exposure gain applied to the linear image (1 = unchanged).
        vignetting: radial falloff strength, see :func:`vignetting` (0 = none).
        color_matrix: 3x3 row-major matrix applied to linear RGB column vectors after white
            balance; rows sum to 1, so it maps grey to grey.
        white_balance: per-channel (R, G, B) linear gains applied before ``color_matrix``.
        gamma: tone-curve exponent; linear x is encoded as x ** (1 / gamma).
        contrast: S-curve strength blended onto the gamma-encoded value (0 = none, < 0 flattens).
        black_level: output level (fraction of full scale) of a black input, the lifted blacks of
            an analogue-ish chain.
        defocus_sigma_px: Gaussian defocus blur std in output pixels (0 = sharp).
        motion_blur_px: motion blur length in output pixels (< 1 = none).
        motion_blur_angle_deg: motion direction, degrees counter-clockwise from the image x axis.
        read_noise_sigma: std of the signal-independent Gaussian read noise, linear units.
        shot_noise_gain: shot-noise variance per unit linear signal (variance = gain * x).
        internal_scale: effective sensor resolution as a fraction of the output (1 = full).
        sharpen: unsharp-mask amount applied to the 8-bit image (0 = none).
        jpeg_quality: JPEG quality (1-100) of a compression round trip, or None for none.
    """

    domain: str
    gain: float
    vignetting: float
    color_matrix: tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]
    white_balance: tuple[float, float, float]
    gamma: float
    contrast: float
    black_level: float
    defocus_sigma_px: float
    motion_blur_px: float
    motion_blur_angle_deg: float
    read_noise_sigma: float
    shot_noise_gain: float
    internal_scale: float
    sharpen: float
    jpeg_quality: int | None

    @property
    def color_matrix_array(self) -> np.ndarray:
        """``color_matrix`` as a (3, 3) float64 array."""
        return np.array(self.color_matrix, dtype=np.float64)

    def camera_matrix(self) -> np.ndarray:
        """(3, 3) float32 matrix applying gain, white balance and colour matrix in one step."""
        m = self.gain * self.color_matrix_array @ np.diag(self.white_balance)
        return m.astype(np.float32)

    @staticmethod
    def neutral(domain: str = "neutral") -> Look:
        """A look that only applies a plain 2.2 gamma encoding (no blur, noise, cast or vignetting)."""
        eye = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
        return Look(
            domain, 1.0, 0.0, eye, (1.0, 1.0, 1.0), 2.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, None
        )


# --------------------------------------------------------------------------------------------
# Sampling
# --------------------------------------------------------------------------------------------


def _saturation_matrix(s: float) -> np.ndarray:
    """Scale chroma by s around the luma axis (rows sum to 1)."""
    return s * np.eye(3) + (1.0 - s) * np.outer(np.ones(3), _LUMA)


def _hue_rotation(deg: float) -> np.ndarray:
    """Rotation by deg about the grey axis (1, 1, 1) of RGB space (Rodrigues; rows sum to 1)."""
    t = np.deg2rad(deg)
    k = np.ones(3) / np.sqrt(3.0)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.cos(t) * np.eye(3) + np.sin(t) * kx + (1.0 - np.cos(t)) * np.outer(k, k)


def _crosstalk(rng: np.random.Generator, amount: float) -> np.ndarray:
    """Random channel crosstalk: off-diagonal leaks of up to ``amount``, rows renormalised to 1."""
    m = np.eye(3) + rng.uniform(0.0, amount, (3, 3)) * (1.0 - np.eye(3))
    return m / m.sum(axis=1, keepdims=True)


def _as_tuple3x3(m: np.ndarray) -> tuple[tuple[float, float, float], ...]:
    return tuple(tuple(float(v) for v in row) for row in m)  # type: ignore[return-value]


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def _random_look(rng: np.random.Generator) -> Look:
    """A look of the ``random`` domain (ranges in :func:`sample_look`)."""
    u = rng.uniform
    matrix = _saturation_matrix(u(0.3, 1.6)) @ _hue_rotation(u(-30.0, 30.0)) @ _crosstalk(rng, 0.25)
    return Look(
        domain="random",
        gain=u(0.5, 1.6),
        vignetting=u(0.0, 1.2),
        color_matrix=_as_tuple3x3(matrix),
        white_balance=(u(0.6, 1.4), u(0.85, 1.15), u(0.6, 1.4)),
        gamma=u(1.4, 2.8),
        contrast=u(-0.3, 0.5),
        black_level=u(0.0, 0.08),
        defocus_sigma_px=u(0.8, 1.6) if rng.random() < 0.2 else u(0.0, 0.8),
        motion_blur_px=u(1.0, 5.0) if rng.random() < 0.3 else 0.0,
        motion_blur_angle_deg=u(0.0, 180.0),
        read_noise_sigma=_log_uniform(rng, 5e-4, 0.025),
        shot_noise_gain=_log_uniform(rng, 1e-5, 3e-3),
        internal_scale=1.0 if rng.random() < 0.5 else u(0.7, 1.0),
        sharpen=u(0.0, 0.8) if rng.random() < 0.5 else 0.0,
        jpeg_quality=int(rng.integers(30, 96)) if rng.random() < 0.7 else None,
    )


def sample_look(domain: str, rng: np.random.Generator) -> Look:
    """Draw the camera/domain parameters of one frame.

    Args:
        domain: ``"legacy"`` (da Vinci-like in-vivo videos), ``"on-site"`` (the other endoscope)
            or ``"random"`` (domain randomisation, wider than both).
        rng: random generator; the same generator state gives the same look.

    Returns:
        A :class:`Look`. Ranges per domain (uniform unless noted):

        ========================  ===========================  ==============================
        parameter                 legacy                       on-site
        ========================  ===========================  ==============================
        gain                      0.85-1.15                    0.75-1.25
        vignetting                0.15-0.4                     0.4-0.9
        white balance R, G, B     1.02-1.12, 1, 0.80-0.92      0.78-0.90, 1.0-1.08, 0.95-1.10
        saturation / hue shift    1.05-1.3 / +-3 deg           0.7-0.9 / 4-12 deg (+ crosstalk)
        gamma / contrast / black  2.1-2.4 / 0.1-0.3 / 0-0.01   1.7-2.0 / -0.15-0.05 / 0.015-0.05
        defocus sigma (px)        0-0.6 (15%: 0.6-1.5)         0.3-0.9
        motion blur (px)          20%: 1-4                     20%: 1-3
        read noise sigma          0.001-0.003                  0.006-0.014
        shot noise gain           2e-5-1e-4                    5e-4-1.5e-3
        internal scale            1                            0.8-0.95
        sharpen                   0.1-0.4                      0
        JPEG quality              75-95                        55-85
        ========================  ===========================  ==============================

        ``random``: gain 0.5-1.6, vignetting 0-1.2, white balance R and B 0.6-1.4, G 0.85-1.15,
        saturation 0.3-1.6, hue shift +-30 deg with crosstalk up to 0.25, gamma 1.4-2.8,
        contrast -0.3-0.5, black level 0-0.08, defocus 0-0.8 px (20 %: 0.8-1.6), motion blur
        30 %: 1-5 px, read noise 5e-4-0.025 and shot-noise gain 1e-5-3e-3 (both log-uniform),
        internal scale 1 (50 %) or 0.7-1, sharpening 0-0.8 on half of the frames, JPEG quality
        30-95 on 70 % of the frames (none otherwise).

    Raises:
        ValueError: unknown domain.
    """
    u = rng.uniform
    if domain == "legacy":
        matrix = _saturation_matrix(u(1.05, 1.3)) @ _hue_rotation(u(-3.0, 3.0))
        return Look(
            domain=domain,
            gain=u(0.85, 1.15),
            vignetting=u(0.15, 0.4),
            color_matrix=_as_tuple3x3(matrix),
            white_balance=(u(1.02, 1.12), 1.0, u(0.80, 0.92)),
            gamma=u(2.1, 2.4),
            contrast=u(0.1, 0.3),
            black_level=u(0.0, 0.01),
            defocus_sigma_px=u(0.6, 1.5) if rng.random() < 0.15 else u(0.0, 0.6),
            motion_blur_px=u(1.0, 4.0) if rng.random() < 0.2 else 0.0,
            motion_blur_angle_deg=u(0.0, 180.0),
            read_noise_sigma=u(0.001, 0.003),
            shot_noise_gain=u(2e-5, 1e-4),
            internal_scale=1.0,
            sharpen=u(0.1, 0.4),
            # Legacy frames come from recorded surgical videos: always lossy-compressed.
            jpeg_quality=int(rng.integers(75, 96)),
        )
    if domain == "on-site":
        matrix = _saturation_matrix(u(0.7, 0.9)) @ _hue_rotation(u(4.0, 12.0)) @ _crosstalk(rng, 0.12)
        return Look(
            domain=domain,
            gain=u(0.75, 1.25),
            vignetting=u(0.4, 0.9),
            color_matrix=_as_tuple3x3(matrix),
            white_balance=(u(0.78, 0.90), u(1.0, 1.08), u(0.95, 1.10)),
            gamma=u(1.7, 2.0),
            contrast=u(-0.15, 0.05),
            black_level=u(0.015, 0.05),
            defocus_sigma_px=u(0.3, 0.9),
            motion_blur_px=u(1.0, 3.0) if rng.random() < 0.2 else 0.0,
            motion_blur_angle_deg=u(0.0, 180.0),
            read_noise_sigma=u(0.006, 0.014),
            shot_noise_gain=u(5e-4, 1.5e-3),
            internal_scale=u(0.8, 0.95),
            sharpen=0.0,
            jpeg_quality=int(rng.integers(55, 86)),
        )
    if domain == "random":
        return _random_look(rng)
    raise ValueError(f"unknown domain {domain!r}; valid domains: {', '.join(DOMAINS)}")


# --------------------------------------------------------------------------------------------
# Effects
# --------------------------------------------------------------------------------------------


@lru_cache(maxsize=8)
def _radius2(height: int, width: int) -> np.ndarray:
    """(H, W) float32 squared distance from the image centre over that of the corner pixels."""
    y = (np.arange(height, dtype=np.float32) - np.float32((height - 1) / 2)) ** 2
    x = (np.arange(width, dtype=np.float32) - np.float32((width - 1) / 2)) ** 2
    r2 = np.add.outer(y, x)
    r2 *= np.float32(4.0 / max((height - 1) ** 2 + (width - 1) ** 2, 1))
    r2.setflags(write=False)
    return r2


def vignetting(height: int, width: int, strength: float) -> np.ndarray:
    """Radial light falloff ``1 / (1 + strength * r**2) ** 2``.

    ``r`` is the distance from the image centre divided by that of the corner pixels, so the centre
    gets 1 and the corners ``1 / (1 + strength) ** 2`` (0.25 at strength 1). Returns a new (H, W)
    float32 array in (0, 1]; all ones for strength 0.
    """
    if strength < 0:
        raise ValueError(f"vignetting strength must be >= 0, got {strength}")
    v = _radius2(int(height), int(width)) * np.float32(strength)
    v += np.float32(1.0)
    np.multiply(v, v, out=v)
    return np.reciprocal(v, out=v)


@lru_cache(maxsize=4)
def _vignetting3(height: int, width: int, strength: float) -> np.ndarray:
    """Read-only (H, W, 3) float32 vignetting map; cached, so the second eye of a frame reuses it."""
    v = vignetting(height, width, strength)
    v3 = cv2.merge([v, v, v])
    v3.setflags(write=False)
    return v3


def _motion_kernel(length_px: float, angle_deg: float) -> np.ndarray:
    """Normalised (k, k) float32 line kernel of the given length and direction (bilinear splats)."""
    k = int(np.ceil(length_px)) | 1
    kernel = np.zeros((k + 2, k + 2), dtype=np.float64)
    t = np.linspace(-0.5 * length_px, 0.5 * length_px, max(4 * k, 8))
    a = np.deg2rad(angle_deg)
    x = t * np.cos(a) + (k + 1) / 2
    y = -t * np.sin(a) + (k + 1) / 2
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    for dy, dx, w in (
        (0, 0, (1 - fx) * (1 - fy)),
        (0, 1, fx * (1 - fy)),
        (1, 0, (1 - fx) * fy),
        (1, 1, fx * fy),
    ):
        np.add.at(kernel, (y0 + dy, x0 + dx), w)
    return (kernel / kernel.sum()).astype(np.float32)


@lru_cache(maxsize=32)
def _tone_lut(gamma: float, contrast: float, black_level: float) -> np.ndarray:
    """4096-entry uint8 table: linear [0, 1] (sampled at i / 4095) -> tone-mapped 8-bit output."""
    x = np.linspace(0.0, 1.0, 4096)
    y = x ** (1.0 / gamma)
    y = (1.0 - contrast) * y + contrast * (y * y * (3.0 - 2.0 * y))
    y = black_level + (1.0 - black_level) * y
    lut = np.round(np.clip(y, 0.0, 1.0) * 255.0).astype(np.uint8)
    lut.setflags(write=False)
    return lut


@lru_cache(maxsize=32)
def _noise_std_lut(read_sigma: float, shot_gain: float) -> np.ndarray:
    """256-entry float32 table: 8-bit-quantised linear signal -> noise std (bin centres)."""
    x = (np.arange(256) + 0.5) / 256.0
    lut = np.sqrt(read_sigma**2 + shot_gain * x).astype(np.float32)
    lut[0] = np.sqrt(read_sigma**2 + shot_gain * 0.25 / 256.0)
    lut.setflags(write=False)
    return lut


def _gauss_noise(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Approximately standard-normal float32 noise (256-level quantised, tails cut at 2.9 sigma)."""
    n = int(np.prod(shape))
    return cv2.LUT(rng.integers(0, 256, n, dtype=np.uint8), _GAUSS_LUT).reshape(shape)


def apply_look(image: np.ndarray, look: Look, rng: np.random.Generator) -> np.ndarray:
    """Apply camera/domain effects to a composited linear-RGB image.

    Args:
        image: (H, W, 3) float32 linear RGB scene radiance, nominally in [0, 1] (values above 1
            saturate). Not modified.
        look: per-frame parameters from :func:`sample_look` (use the same one for both eyes).
        rng: random generator for the noise draws (the only randomness here).

    Returns:
        (H, W, 3) uint8 RGB camera frame.

    Shot noise uses the Gaussian approximation of Poisson noise: std
    ``sqrt(read_noise_sigma**2 + shot_noise_gain * x)`` with the signal x quantised to 8 bits for
    the std look-up and standard-normal draws quantised to 256 levels. Noise is drawn at the
    internal (sensor) resolution, so on-site noise is blotchy after upsampling, as from a
    low-resolution sensor scaled up. The colour matrix and the blurs are linear and commute, and
    the vignetting varies slowly, so their order hardly matters; all of them act before the noise.
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {img.shape}")
    height, width = img.shape[:2]
    if img.dtype != np.float32:
        img = img.astype(np.float32)

    # 1. internal (sensor) resolution, exposure + white balance + colour matrix (one 3x3 matrix);
    #    the first operation makes the working copy (the input is never written)
    scale = float(look.internal_scale)
    h, w = height, width
    if scale < 0.999:
        h, w = max(2, round(height * scale)), max(2, round(width * scale))
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        cv2.transform(img, look.camera_matrix(), dst=img)
    else:
        scale = 1.0
        img = cv2.transform(img, look.camera_matrix())

    # 2. optics (lengths in output pixels -> sensor pixels) and vignetting
    sigma = look.defocus_sigma_px * scale
    if sigma >= 0.25:
        cv2.GaussianBlur(img, (0, 0), sigma, dst=img, borderType=cv2.BORDER_REFLECT)
    length = look.motion_blur_px * scale
    if length >= 1.0:
        kernel = _motion_kernel(length, look.motion_blur_angle_deg)
        cv2.filter2D(img, -1, kernel, dst=img, borderType=cv2.BORDER_REFLECT)
    if look.vignetting > 0:
        cv2.multiply(img, _vignetting3(h, w, float(look.vignetting)), dst=img)

    # 3. sensor noise, one draw per pixel and channel
    if look.read_noise_sigma > 0 or look.shot_noise_gain > 0:
        level = cv2.convertScaleAbs(img, alpha=256.0, beta=-0.5)  # ~floor(256 |x|), saturated at 255
        std = cv2.LUT(level, _noise_std_lut(float(look.read_noise_sigma), float(look.shot_noise_gain)))
        noise = _gauss_noise(rng, img.shape)
        cv2.multiply(noise, std, dst=noise)
        cv2.add(img, noise, dst=img)

    # 4. tone curve and 8-bit quantisation through a 4096-entry table
    np.clip(img, 0.0, 1.0, out=img)
    img *= np.float32(4095.0)
    img += np.float32(0.5)
    out = np.take(
        _tone_lut(float(look.gamma), float(look.contrast), float(look.black_level)), img.astype(np.uint16)
    )

    # 5. video chain: sharpening, upsampling to the output size, compression
    if look.sharpen > 0:
        soft = cv2.GaussianBlur(out, (0, 0), 1.0)
        out = cv2.addWeighted(out, 1.0 + look.sharpen, soft, -look.sharpen, 0.0)
    if (h, w) != (height, width):
        out = cv2.resize(out, (width, height), interpolation=cv2.INTER_LINEAR)
    if look.jpeg_quality is not None:
        bgr = cv2.cvtColor(out, cv2.COLOR_RGB2BGR)
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(look.jpeg_quality)])
        if not ok:  # pragma: no cover - OpenCV always encodes a valid uint8 image
            raise RuntimeError("JPEG encoding failed")
        out = cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    return out
