# SPDX-License-Identifier: Apache-2.0
"""Rendering of one view of a scene: a ray-cast tissue surface and z-buffered tubes.

The tissue surface is a height field ``z = z0 + gx*x + gy*y - relief(x, y)`` in
the left camera optical frame (metres); each pixel's ray is intersected with it
by a few fixed-point steps, so its texture is stereo-consistent. Threads and
instrument parts are tubes (an axis polyline and a radius) rasterised as
projected capsules: every segment tests a small window of pixels, all windows
together go through one z-buffer pass (``np.minimum.at``), so crossings are
occluded correctly in each view. Output is linear RGB float32 before the
camera effects of ``appearance``.

Arrays: images are (H, W, 3) float32 linear RGB; per-pixel buffers are (H, W).
Owner codes in ``ViewRender.owner``: ``SURFACE`` (-1), ``INSTRUMENT`` (-2), or
the index (>= 0) of the thread that is front-most at the pixel.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from suture_common.camera import StereoCamera
from suture_sim.textures import SurfaceTexture

SURFACE = -1
INSTRUMENT = -2

#: Half-width (px) under which a thin thread still owns the pixel its centreline
#: passes through: the pixel centre is at most sqrt(2)/2 px from a line crossing it.
MIN_CORE_RADIUS_PX = 0.71
#: Length of one braid repeat along a thread (m).
BRAID_PERIOD = 6e-4


@dataclass
class Surface:
    """The tissue height field (see module docstring) and its texture patch.

    ``origin`` (2,) is the (x, y) position in metres of the texture's corner (texel 0, 0).
    """

    depth0: float
    slope: np.ndarray
    texture: SurfaceTexture
    origin: np.ndarray

    def __post_init__(self) -> None:
        texel = self.texture.extent_m / self.texture.height.shape[0]
        grad_y, grad_x = np.gradient(self.texture.height.astype(np.float32), texel)
        self._relief_gradient = (grad_x.astype(np.float32), grad_y.astype(np.float32))

    @property
    def texel(self) -> float:
        """Side of one texture texel, metres."""
        return self.texture.extent_m / self.texture.height.shape[0]

    def depth(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Surface depth z (m) under points (x, y) (same-shape arrays, metres)."""
        relief = self.sample(self.texture.height, x, y).astype(np.float64)
        return self.depth0 + self.slope[0] * x + self.slope[1] * y - relief

    def sample(self, field: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear sample of a texture-space ``field`` (S, S) or (S, S, C) at points (x, y).

        Returns float32 of shape x.shape (+ (C,)); outside the patch the texture is mirrored.
        """
        x = np.asarray(x)
        scale = np.float32(1.0 / self.texel)
        map_x = ((x - np.float32(self.origin[0])) * scale - np.float32(0.5)).astype(np.float32, copy=False)
        map_y = ((np.asarray(y) - np.float32(self.origin[1])) * scale - np.float32(0.5)).astype(
            np.float32, copy=False
        )
        as_image = (lambda m: m) if x.ndim == 2 else (lambda m: m.reshape(1, -1))
        sampled = cv2.remap(
            field, as_image(map_x), as_image(map_y), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
        )
        return sampled.reshape(x.shape + field.shape[2:])

    def relief_gradient(self) -> tuple[np.ndarray, np.ndarray]:
        """d(relief)/dx and d(relief)/dy in texture space, (S, S) float32 each (unitless)."""
        return self._relief_gradient


@dataclass
class Tube:
    """A thread or an instrument part: axis (N, 3) metres, radius (m), material.

    ``segment_radii``: length of the rasterised segments in units of the tube's pixel
    radius; a straight wide shaft needs no short segments, and longer ones test fewer
    pixels outside it.
    """

    axis: np.ndarray
    radius: float
    colour: np.ndarray
    owner: int
    specular: float = 0.4
    braid: float = 0.0
    shininess: float = 0.3
    segment_radii: float = 0.5

    @property
    def arc(self) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.axis, axis=0), axis=1))])


@dataclass
class ViewRender:
    """One rendered view: linear RGB image, front-most depth (m), owner codes, thread mask."""

    image: np.ndarray
    depth: np.ndarray
    owner: np.ndarray

    @property
    def thread_mask(self) -> np.ndarray:
        return self.owner >= 0


@dataclass
class Lighting:
    """Endoscope light: a point source near the optical centres, with 1/d^2 falloff
    normalised at ``reference_distance`` metres."""

    position: np.ndarray
    reference_distance: float
    ambient: float = 0.12


def render_view(
    camera: StereoCamera, view: str, surface: Surface, tubes: list[Tube], lighting: Lighting
) -> ViewRender:
    """Render ``view`` ('left' or 'right') of the scene in linear RGB."""
    image, depth = _render_surface(camera, view, surface, lighting)
    owner = np.full(depth.shape, SURFACE, dtype=np.int16)
    _draw_tubes(camera, view, tubes, lighting, image, depth, owner)
    return ViewRender(image, depth, owner)


@functools.lru_cache(maxsize=4)
def _pixel_rays(camera: StereoCamera) -> tuple[np.ndarray, np.ndarray]:
    """Ray slopes (x/z, y/z) of every pixel, (H, W) float32 each; shared by both views."""
    u, v = np.meshgrid(np.arange(camera.width, dtype=np.float32), np.arange(camera.height, dtype=np.float32))
    ray_x, ray_y = camera.rays(u, v)
    return ray_x.astype(np.float32), ray_y.astype(np.float32)


def _render_surface(
    camera: StereoCamera, view: str, surface: Surface, lighting: Lighting
) -> tuple[np.ndarray, np.ndarray]:
    """Shaded tissue (H, W, 3) float32 and its depth (H, W) float32, metres.

    Vector quantities are kept as separate (H, W) components: reductions over a trailing
    axis of length 3 are several times slower in numpy.
    """
    ray_x, ray_y = _pixel_rays(camera)
    centre_x = np.float32(camera.optical_centre(view)[0])
    slope_x, slope_y = np.float32(surface.slope[0]), np.float32(surface.slope[1])
    denominator = 1.0 - slope_x * ray_x - slope_y * ray_y
    plane_numerator = np.float32(surface.depth0) + slope_x * centre_x
    depth = plane_numerator / denominator
    for _ in range(3):  # fixed point on the relief; it converges to far below a texel
        relief = surface.sample(surface.texture.height, centre_x + depth * ray_x, depth * ray_y)
        depth = (plane_numerator - relief) / denominator
    x = centre_x + depth * ray_x
    y = depth * ray_y
    albedo = surface.sample(surface.texture.albedo, x, y)
    shine = surface.sample(surface.texture.specular, x, y)
    grad_x, grad_y = surface.relief_gradient()
    normal_x = slope_x - surface.sample(grad_x, x, y)
    normal_y = slope_y - surface.sample(grad_y, x, y)
    inv_normal = 1.0 / np.sqrt(normal_x * normal_x + normal_y * normal_y + 1.0)
    light = lighting.position.astype(np.float32)
    light_x, light_y, light_z = light[0] - x, light[1] - y, light[2] - depth
    light_sq = light_x * light_x + light_y * light_y + light_z * light_z
    inv_light = 1.0 / np.sqrt(light_sq)
    eye_x, eye_y, eye_z = centre_x - x, -y, -depth
    inv_eye = 1.0 / np.sqrt(eye_x * eye_x + eye_y * eye_y + eye_z * eye_z)
    half_x = light_x * inv_light + eye_x * inv_eye
    half_y = light_y * inv_light + eye_y * inv_eye
    half_z = light_z * inv_light + eye_z * inv_eye
    inv_half = 1.0 / np.sqrt(half_x * half_x + half_y * half_y + half_z * half_z)
    diffuse = np.clip((normal_x * light_x + normal_y * light_y - light_z) * inv_normal * inv_light, 0.0, 1.0)
    cos_half = np.clip((normal_x * half_x + normal_y * half_y - half_z) * inv_normal * inv_half, 0.0, 1.0)
    c2 = cos_half * cos_half
    c4 = c2 * c2
    c8 = c4 * c4
    c16 = c8 * c8
    phong = c16 * c16 * c16 * c8 * c4  # cos^60 by squaring: np.power is 10x slower
    falloff = np.float32(lighting.reference_distance**2) / light_sq
    lit = np.float32(lighting.ambient) + diffuse * falloff
    image = albedo * lit[..., None]
    image += (shine * phong * falloff)[..., None]
    return image, depth


def _draw_tubes(
    camera: StereoCamera,
    view: str,
    tubes: list[Tube],
    lighting: Lighting,
    image: np.ndarray,
    depth: np.ndarray,
    owner: np.ndarray,
) -> None:
    """Rasterise all tubes into ``image``, ``depth`` and ``owner`` in place."""
    fragments = [
        f for f in (_tube_fragments(camera, view, tube, lighting) for tube in tubes) if f is not None
    ]
    if not fragments:
        return
    pix, z_front, owners, alpha, colour, core = (
        np.concatenate(parts) for parts in zip(*fragments, strict=True)
    )
    flat_depth = depth.reshape(-1)
    flat_owner = owner.reshape(-1)
    flat_image = image.reshape(-1, 3)
    # Core fragments compete in the z-buffer (with the tissue surface already in it).
    core_pix, core_z = pix[core], z_front[core].astype(flat_depth.dtype)
    np.minimum.at(flat_depth, core_pix, core_z)
    won = core_z <= flat_depth[core_pix]
    won_pix = core_pix[won]
    flat_owner[won_pix] = owners[core][won]
    won_alpha = alpha[core][won][:, None]
    flat_image[won_pix] = won_alpha * colour[core][won] + (1.0 - won_alpha) * flat_image[won_pix]
    # Anti-aliased fringes blend over whatever is behind them, without owning the pixel.
    fringe = ~core
    fringe &= z_front < flat_depth[pix]
    fringe &= flat_owner[pix] != owners
    if np.any(fringe):
        f_pix, f_alpha = pix[fringe], alpha[fringe]
        best = np.zeros(flat_depth.size, dtype=np.float32)
        np.maximum.at(best, f_pix, f_alpha)
        top = f_alpha >= best[f_pix]
        a = f_alpha[top][:, None]
        flat_image[f_pix[top]] = a * colour[fringe][top] + (1.0 - a) * flat_image[f_pix[top]]


def _tube_fragments(
    camera: StereoCamera, view: str, tube: Tube, lighting: Lighting
) -> tuple[np.ndarray, ...] | None:
    """Pixels covered by one tube: (flat index, front depth, owner, coverage, colour, is_core)."""
    uv = camera.project(tube.axis, view)
    z = tube.axis[:, 2]
    arc = tube.arc
    radius_px = tube.radius * camera.fx / z
    # Segments about max(2 px, radius) long keep every window small.
    step_px = np.linalg.norm(np.diff(uv, axis=0), axis=1)
    target = max(2.0, tube.segment_radii * float(np.median(radius_px)))
    keep = np.unique(
        np.concatenate(
            [
                np.searchsorted(np.cumsum(np.r_[0, step_px]), np.arange(0, step_px.sum(), target)),
                [len(uv) - 1],
            ]
        )
    )
    uv, z, arc, radius_px, axis = uv[keep], z[keep], arc[keep], radius_px[keep], tube.axis[keep]
    p0, p1 = uv[:-1], uv[1:]
    reach = np.maximum(radius_px[:-1], radius_px[1:]) + 1.0
    low = np.floor(np.minimum(p0, p1) - reach[:, None]).astype(np.int64)
    # Each segment tests its own bounding window, row by row: a wide instrument shaft
    # costs its own area, not the largest window times the number of segments.
    window = np.ceil(np.abs(p1 - p0) + 2 * reach[:, None]).astype(np.int64) + 1  # (S, 2) width, height
    counts = window[:, 0] * window[:, 1]
    seg = np.repeat(np.arange(len(p0)), counts)
    within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    width = window[seg, 0]
    cand = low[seg] + np.column_stack([within % width, within // width])  # (sum(counts), 2) pixels
    inside = (
        (cand[:, 0] >= 0) & (cand[:, 0] < camera.width) & (cand[:, 1] >= 0) & (cand[:, 1] < camera.height)
    )
    cand, seg = cand[inside], seg[inside]
    if cand.size == 0:
        return None
    d = (p1 - p0)[seg]
    rel = cand - p0[seg]
    length_sq = np.maximum(np.sum(d * d, axis=1), 1e-12)
    t_raw = np.sum(rel * d, axis=1) / length_sq
    t = np.clip(t_raw, 0.0, 1.0)
    # Round caps between two segments only fill the outside of bends: with the axis
    # tilted in depth they would otherwise poke through the neighbouring segment.
    inner_cap = ((t_raw < 0) & (seg > 0)) | ((t_raw > 1) & (seg < len(p0) - 1))
    offset = rel - t[:, None] * d
    dist = np.linalg.norm(offset, axis=1)
    r_px = radius_px[seg] + t * (radius_px[seg + 1] - radius_px[seg])
    covered = dist <= r_px + 0.5
    if not np.any(covered):
        return None
    cand, seg, t, dist, r_px, offset, d, inner_cap = (
        a[covered] for a in (cand, seg, t, dist, r_px, offset, d, inner_cap)
    )
    z_axis = z[seg] + t * (z[seg + 1] - z[seg])
    metric_offset = dist * z_axis / camera.fx
    z_front = z_axis - np.sqrt(np.maximum(tube.radius**2 - metric_offset**2, 0.0))
    z_front[inner_cap] += tube.radius
    core = dist <= np.maximum(r_px, MIN_CORE_RADIUS_PX)
    alpha = np.clip(np.minimum(r_px + 0.5 - dist, np.minimum(2.0 * r_px, 1.0)), 0.0, 1.0)
    # Cylinder shading: position across the tube in [-1, 1] gives the normal.
    side = np.sign(d[:, 0] * offset[:, 1] - d[:, 1] * offset[:, 0])
    across = np.clip(side * dist / np.maximum(r_px, 0.5), -1.0, 1.0)
    facing = np.sqrt(1.0 - across**2)
    s = arc[seg] + t * (arc[seg + 1] - arc[seg])
    braid = 1.0 + tube.braid * np.sin(2 * np.pi * (s / BRAID_PERIOD + 0.5 * across))
    points = axis[seg] + t[:, None] * (axis[seg + 1] - axis[seg])
    light_distance = np.linalg.norm(points - lighting.position[None, :], axis=1)
    falloff = (lighting.reference_distance / np.maximum(light_distance, 1e-3)) ** 2
    diffuse = (0.3 + 0.7 * facing) * braid * falloff
    highlight = tube.specular * np.exp(-(((across - 0.25) / tube.shininess) ** 2)) * falloff
    colour = tube.colour[None, :] * diffuse[:, None] + highlight[:, None]
    pix = cand[:, 1] * camera.width + cand[:, 0]
    owners = np.full(pix.shape, tube.owner, dtype=np.int16)
    return pix, z_front, owners, alpha.astype(np.float32), colour.astype(np.float32), core
