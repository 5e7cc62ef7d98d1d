# SPDX-License-Identifier: Apache-2.0
"""Random stereo scenes by topology, rendered into frames with exact ground truth.

``generate_frame(config, index)`` is the simulator's one entry point: it draws a
scene from ``np.random.default_rng([config.seed, index])`` (so any frame can be
regenerated alone, in any order), renders both views and returns a
``SimFrame`` holding the images and the ground truth of docs/interfaces.md:

* masks of every visible thread (target and others; never the instrument);
* the target's centreline from the cut tip projected into both views, as
  (N, 3) arrays (u, v, visible). Both views use the same 3D samples, so row i
  of the left and right sequences lie on the same image row; consecutive
  samples are about 1 px apart in the left view. ``visible`` is 1.0 where the
  target itself is the front-most surface at that pixel, 0.0 where another
  strand, its own upper strand or an instrument covers it, or where it lies
  under the tissue surface;
* the 3D centreline from the cut tip (``path``, (M, 3) metres, every 0.5 mm, in
  the left camera optical frame; every 0.1 mm for the hard topologies, whose
  hooks bend at radii down to 0.3 mm) and its length;
* the grasp pose at ``config.grasp_arc_length`` (0.05 m) of arc from the tip,
  oriented by ``suture_common.grasp`` (x along the thread, z the approach).
  The arc is measured along the target's true centreline, through stretches
  that something hides; a thread end that enters the tissue does so at least
  10 mm of arc beyond the grasp point, so the grasp point is never buried (an
  instrument may still hide it).

Physical ranges (docs/interfaces.md and the paper's simulation): thread diameter
0.2 to 0.6 mm, length 60 to 150 mm, lying on or draped above a tissue surface so
that every target point is 50 to 150 mm from the camera.

Topologies: the paper's five (``TOPOLOGIES``, cycled by ``mixed``) and three
hard ones (``HARD_TOPOLOGIES``, cycled by ``hard``) taken from the failures on
frames that this simulator did not make:

* ``hooked``: the cut end curls into a hairpin whose arms lie side by side, or a
  hook whose tip arm the thread crosses; bend radius 0.3 to 2 mm, the bend
  ending within 15 mm of the cut tip (``geometry.hooked_curve``);
* ``wide_occlusion``: one or two instrument shafts 5 to 8.5 mm thick, with
  jaws, lie across (or, in about 30 % of draws, along) the target and hide 5 to
  25 mm of its arc in each view, with the thread visible on both sides of every
  hidden stretch; the grasp point may be hidden;
* ``along_rows``: the target runs within 10 degrees of the image rows over at
  least 30 mm of arc, where stereo depth is ill-conditioned.

The hard topologies draw thread diameters from 0.1 to 0.6 mm (log-uniform), and
in half of their frames the target's far end enters the tissue: the buried part
stays in the sequences and the path, marked hidden like any covered point, and
is in neither mask. Frames of the five paper topologies are unchanged by them:
each topology draws from its own random stream.

The ``random`` domain (domain randomisation for training) draws the same scenes as the other
domains and then changes their appearance from a random stream of its own (so ``legacy`` and
``on-site`` frames stay as they were for a seed): the background cycles through tissue, phantom
and printed with its colours remapped, threads get any colour that contrasts with it (the named
ones or random ones) and a diameter of 1 to 8 px in the image, the instruments' colours vary and
30 % of the frames of topologies without one get a thin instrument, the light's ambient share and
position vary, and the camera look is the ``random`` one of ``appearance.sample_look``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from suture_common.camera import StereoCamera
from suture_common.grasp import grasp_rotation, point_at_arc_length, rotation_to_quaternion
from suture_sim import appearance, geometry, textures
from suture_sim.cycles import DEFAULT_SAMPLES
from suture_sim.render import INSTRUMENT, Lighting, Surface, Tube, ViewRender, render_view

TOPOLOGIES = ("straight", "curved", "self_intersected", "crossed", "occluded")
HARD_TOPOLOGIES = ("hooked", "wide_occlusion", "along_rows")
#: Names that draw a different topology frame by frame, cycling through the listed ones.
MIXTURES = {"mixed": TOPOLOGIES, "hard": HARD_TOPOLOGIES}
#: Every value ``SimConfig.topology`` accepts.
TOPOLOGY_CHOICES = (*TOPOLOGIES, *HARD_TOPOLOGIES, *MIXTURES)
DOMAINS = ("legacy", "on-site", "random")
BACKGROUNDS = ("tissue", "phantom", "printed")
#: ``raster``: the fast ray-cast renderer of ``render``; ``cycles``: Blender Cycles (``cycles``).
RENDERERS = ("raster", "cycles")

#: Thread colours, linear RGB albedo (violet and undyed polyglactin, green, blue, black, white).
THREAD_COLOURS = {
    "violet": (0.16, 0.05, 0.30),
    "green": (0.03, 0.22, 0.06),
    "blue": (0.03, 0.08, 0.35),
    "black": (0.015, 0.015, 0.02),
    "white": (0.80, 0.80, 0.75),
    "undyed": (0.60, 0.45, 0.25),
}

#: A thread colour is used on a background only if one linear-RGB channel of the two differs by
#: at least this factor (against the background's median albedo): a thread that no annotator
#: could see (white on a pale phantom) must not be in the ground-truth mask.
MIN_COLOUR_CONTRAST = 2.0

#: Random domain: thread diameter in the image (px at the thread's median depth), log-uniform.
RANDOM_DIAMETER_PX = (1.0, 8.0)
#: Random domain: share of the frames of topologies without an instrument that get one.
RANDOM_INSTRUMENT_SHARE = 0.3

MIN_DEPTH, MAX_DEPTH = 0.050, 0.150
MIN_LENGTH, MAX_LENGTH = 0.060, 0.150
MIN_DIAMETER, MAX_DIAMETER = 0.0002, 0.0006
BORDER_PX = 8
PATH_STEP = 5e-4
#: An instrument crosses the thread: a shaft of at most 6 mm crossing at 40 degrees or more
#: hides at most ~9.3 mm of it. Scenes where it lies along the thread are redrawn.
MAX_HIDDEN_ARC = 0.010
#: Hard topologies: thinnest thread diameter (m).
THIN_DIAMETER = 0.0001
#: wide_occlusion: arc of the target (m) that the shafts hide in each view.
MIN_SHAFT_HIDDEN, MAX_SHAFT_HIDDEN = 0.005, 0.025
#: along_rows: the target stays within ROW_ANGLE degrees of the image rows over ROW_STRETCH m.
ROW_ANGLE, ROW_STRETCH = 10.0, 0.030
#: A thread end that enters the tissue does so this far (m of arc) beyond the grasp point.
BURIED_END_MARGIN = 0.010


class SceneError(RuntimeError):
    """No valid scene was found for the requested configuration (too many rejected draws)."""


@dataclass(frozen=True)
class SimConfig:
    """What to simulate. ``background`` None means: tissue for legacy, phantom or
    printed (alternating) for on-site, tissue, phantom and printed in turn for random.
    ``samples`` is the Cycles renderer's samples per pixel."""

    topology: str
    camera: StereoCamera
    domain: str = "legacy"
    seed: int = 0
    background: str | None = None
    grasp_arc_length: float = 0.05
    frame_period_ns: int = 100_000_000
    start_ns: int = 1_700_000_000_000_000_000
    renderer: str = "raster"
    samples: int = DEFAULT_SAMPLES

    def __post_init__(self) -> None:
        if self.renderer not in RENDERERS:
            raise ValueError(f"unknown renderer {self.renderer!r}; choose raster or cycles")
        if self.samples < 1:
            raise ValueError(f"samples must be at least 1, got {self.samples}")
        if self.topology not in TOPOLOGY_CHOICES:
            raise ValueError(
                f"unknown topology {self.topology!r}; choose one of {', '.join(TOPOLOGY_CHOICES)}"
            )
        if self.domain not in DOMAINS:
            raise ValueError(f"unknown domain {self.domain!r}; choose one of {', '.join(DOMAINS)}")
        if self.background is not None and self.background not in BACKGROUNDS:
            raise ValueError(
                f"unknown background {self.background!r}; choose one of {', '.join(BACKGROUNDS)}"
            )
        if not 0 < self.grasp_arc_length < MIN_LENGTH:
            raise ValueError(f"grasp arc length must be in (0, {MIN_LENGTH}) m, got {self.grasp_arc_length}")

    def topology_of(self, index: int) -> str:
        cycle = MIXTURES.get(self.topology)
        return cycle[index % len(cycle)] if cycle is not None else self.topology

    def background_of(self, index: int) -> str:
        if self.background is not None:
            return self.background
        if self.domain == "random":
            return BACKGROUNDS[index % len(BACKGROUNDS)]
        return "tissue" if self.domain == "legacy" else ("phantom", "printed")[index % 2]


@dataclass
class SimFrame:
    """One stereo frame and its ground truth (see module docstring for conventions).

    Images are (H, W, 3) uint8 RGB; masks (H, W) uint8 in {0, 255}; sequences (N, 3)
    float64 (u, v, visible); ``path`` (M, 3) metres; ``tip_hint`` (2,) left pixel.
    """

    index: int
    stamp_ns: int
    topology: str
    background: str
    camera: StereoCamera
    left_image: np.ndarray
    right_image: np.ndarray
    left_mask: np.ndarray
    right_mask: np.ndarray
    left_sequence: np.ndarray
    right_sequence: np.ndarray
    path: np.ndarray
    length: float
    grasp_position: np.ndarray
    grasp_quaternion: np.ndarray
    tip_hint: np.ndarray
    diameter: float
    extras: dict = field(default_factory=dict)


@dataclass
class _Scene:
    surface: Surface
    tubes: list[Tube]
    target: np.ndarray  # (N, 3) dense centreline from the cut tip, SAMPLE_STEP apart
    radius: float


def generate_frame(config: SimConfig, index: int) -> SimFrame:
    """Draw, render and annotate frame ``index`` of ``config`` (deterministic)."""
    topology = config.topology_of(index)
    topology_key = (*TOPOLOGIES, *HARD_TOPOLOGIES).index(topology)
    rng = np.random.default_rng([config.seed, index, topology_key])
    # The random domain's own draws (trailing 2): the scene draws of ``rng`` stay those of the
    # other domains, and those domains never touch this stream.
    extra = None
    if config.domain == "random":
        extra = np.random.default_rng([config.seed, index, topology_key, 2])
    background = config.background_of(index)
    camera = config.camera
    for _ in range(60):
        try:
            scene = _sample_scene(topology, background, camera, rng)
        except geometry.ShapeError:
            continue
        lighting = Lighting(
            position=np.array([camera.baseline / 2, rng.uniform(-0.003, 0.003), -0.002]),
            reference_distance=float(np.median(scene.target[:, 2])) * rng.uniform(0.85, 1.15),
        )
        if extra is not None:
            scene, lighting = _randomise(scene, lighting, topology, camera, extra)
        if config.renderer == "cycles":
            from suture_sim import cycles

            # The render's own draws (lights, focus, materials) come from a stream of their own
            # (the trailing 1): the ground truth and the look stay the raster renderer's.
            left, right = cycles.render_stereo(
                camera,
                scene.surface,
                scene.tubes,
                lighting,
                np.random.default_rng([config.seed, index, topology_key, 1]),
                cycles.CyclesSettings(samples=config.samples),
            )
        else:
            left = render_view(camera, "left", scene.surface, scene.tubes, lighting)
            right = render_view(camera, "right", scene.surface, scene.tubes, lighting)
        frame = _annotate(config, index, topology, background, scene, left, right, rng, extra)
        if frame is not None:
            return frame
    raise SceneError(
        f"could not draw a valid {topology} scene for {camera.width}x{camera.height} "
        f"with fx={camera.fx:.0f} px after 60 tries; check the camera intrinsics"
    )


def _random_colour(background: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A linear-RGB thread albedo (3,) that contrasts with the (3,) ``background`` median albedo as
    :func:`contrasting_colours` asks: a named colour (jittered) in half of the draws, else any."""
    named = [THREAD_COLOURS[n] for n in contrasting_colours(background[None, None, :])]
    for _ in range(50):
        if named and rng.random() < 0.5:
            colour = np.array(named[rng.integers(len(named))]) * rng.uniform(0.6, 1.4, 3)
        else:
            colour = np.exp(rng.uniform(np.log(0.01), np.log(0.9), 3))
        colour = np.clip(colour, 0.005, 0.95)
        ratio = np.log(colour / np.maximum(background, 1e-3))
        if np.max(np.abs(ratio)) >= np.log(MIN_COLOUR_CONTRAST):
            return colour
    return np.array(THREAD_COLOURS["black"] if background.max() > 0.1 else THREAD_COLOURS["white"])


def _randomise(
    scene: _Scene, lighting: Lighting, topology: str, camera: StereoCamera, rng: np.random.Generator
) -> tuple[_Scene, Lighting]:
    """The random domain's appearance of a drawn scene (module docstring); ``rng`` is its own
    stream. Thicker threads are lifted by the change of radius, so they rest where they did."""
    texture = scene.surface.texture
    remap = appearance._saturation_matrix(rng.uniform(0.4, 1.5)) @ appearance._hue_rotation(
        rng.uniform(-60.0, 60.0)
    )
    gains = rng.uniform(0.6, 1.4, 3) * rng.uniform(0.6, 1.3)
    albedo = np.clip(texture.albedo @ (remap * gains[None, :]).T.astype(np.float32), 0.0, 1.0)
    surface = Surface(
        depth0=scene.surface.depth0,
        slope=scene.surface.slope,
        texture=replace(texture, albedo=albedo.astype(np.float32)),
        origin=scene.surface.origin,
    )
    background = np.median(albedo.reshape(-1, 3), axis=0)
    tubes: list[Tube] = []
    target, radius = scene.target, scene.radius
    for tube in scene.tubes:
        if tube.owner == INSTRUMENT:
            tint = rng.uniform(0.9, 1.1, 3)
            tubes.append(replace(tube, colour=np.clip(tube.colour * rng.uniform(0.4, 1.8) * tint, 0.02, 0.9)))
            continue
        depth = float(np.median(tube.axis[:, 2]))
        diameter_px = np.exp(rng.uniform(*np.log(RANDOM_DIAMETER_PX)))
        new_radius = 0.5 * diameter_px * depth / camera.fx
        axis = tube.axis - np.array([0.0, 0.0, new_radius - tube.radius])
        if tube.owner == 0:
            target, radius = axis, new_radius
        tubes.append(
            replace(
                tube,
                axis=axis,
                radius=new_radius,
                colour=_random_colour(background, rng),
                specular=rng.uniform(0.0, 0.8),
                braid=rng.choice([0.0, rng.uniform(0.05, 0.4)]),
                shininess=rng.uniform(0.15, 0.6),
            )
        )
    if topology not in ("occluded", "wide_occlusion") and rng.random() < RANDOM_INSTRUMENT_SHARE:
        tubes += _instrument(target, camera, rng, THIN_INSTRUMENT)
    lighting = Lighting(
        position=lighting.position + np.r_[rng.uniform(-0.004, 0.004, 2), 0.0],
        reference_distance=lighting.reference_distance * rng.uniform(0.8, 1.25),
        ambient=rng.uniform(0.03, 0.35),
    )
    return _Scene(surface, tubes, target, radius), lighting


def _sample_scene(topology: str, background: str, camera: StereoCamera, rng: np.random.Generator) -> _Scene:
    if topology in HARD_TOPOLOGIES:
        return _sample_hard_scene(topology, background, camera, rng)
    radius = rng.uniform(MIN_DIAMETER, MAX_DIAMETER) / 2
    length = rng.uniform(MIN_LENGTH, MAX_LENGTH)
    shape = {"self_intersected": "loop", "straight": "straight"}.get(
        topology,
        rng.choice(["curved", "curved", "straight"]) if topology in ("crossed", "occluded") else "curved",
    )
    curve = geometry.rotate(
        geometry.planar_curve(length, geometry.curvature_profile(shape, length, rng)),
        rng.uniform(0, 2 * np.pi),
    )
    self_crossings = geometry.find_crossings(curve)
    if (shape == "loop") != bool(self_crossings):
        raise geometry.ShapeError("loop topology needs a self-crossing and only loops may have one")
    if any(c.angle < np.radians(20) or min(c.s_first, c.s_second) < 0.008 for c in self_crossings):
        raise geometry.ShapeError("self-crossing too shallow or too close to the cut tip")
    if geometry.has_close_approach(curve, None, self_crossings, 0.0015):
        raise geometry.ShapeError("thread touches itself away from a crossing")

    depth0, centre = _place(curve, camera, rng)
    curve = curve - curve.mean(axis=0) + centre
    planar = [curve]
    crossings = [(0, 0, c) for c in self_crossings]
    radii = [radius]
    if topology == "crossed":
        other, other_crossings = _crossing_thread(curve, length, rng)
        planar.append(other)
        radii.append(rng.uniform(MIN_DIAMETER, MAX_DIAMETER) / 2)
        crossings += [(0, 1, c) for c in other_crossings]

    surface = _surface(background, camera, depth0, rng)
    base = [surface.depth(c[:, 0], c[:, 1]) - r for c, r in zip(planar, radii, strict=True)]
    lifts = [geometry.random_lift(len(c), rng) for c in planar]
    geometry.raise_over_crossings(lifts, base, crossings, radii, rng)
    threads = [np.column_stack([c, b - lift]) for c, b, lift in zip(planar, base, lifts, strict=True)]

    target = _target_in_view(threads[0], camera)

    tubes = _thread_tubes([target, *threads[1:]], radii, surface, rng)
    if topology == "occluded":
        tubes += _instrument(target, camera, rng, THIN_INSTRUMENT)
    return _Scene(surface, tubes, target, radius)


def _sample_hard_scene(
    topology: str, background: str, camera: StereoCamera, rng: np.random.Generator
) -> _Scene:
    """A scene of one of ``HARD_TOPOLOGIES`` (see the module docstring)."""
    radius = np.exp(rng.uniform(np.log(THIN_DIAMETER), np.log(MAX_DIAMETER))) / 2
    length = rng.uniform(MIN_LENGTH, MAX_LENGTH)
    hook = None
    if topology == "hooked":
        curve, hook = geometry.hooked_curve(length, radius, rng)
        n = len(curve)
        # Both arms of the hook rest on the tissue, so they touch in the image as on it.
        lift_weight = 1.0 - geometry.taper(n, hook.free_from + 0.005, hook.free_from + 0.010)
    elif topology == "along_rows":
        stretch = rng.uniform(ROW_STRETCH + 0.002, min(0.060, length - 0.005))
        start = rng.uniform(0.0, length - stretch)
        curve = geometry.along_rows_curve(length, start, stretch, rng)
        n = len(curve)
        # The straight stretch rests on the tissue: a drape would tilt it in the image.
        lift_weight = np.maximum(
            geometry.taper(n, start - 0.008, start - 0.003),
            1.0 - geometry.taper(n, start + stretch + 0.003, start + stretch + 0.008),
        )
    else:
        shape = rng.choice(["curved", "curved", "straight"])
        curve = geometry.planar_curve(length, geometry.curvature_profile(shape, length, rng))
        n = len(curve)
        lift_weight = np.ones(n)
    if topology != "along_rows":
        curve = geometry.rotate(curve, rng.uniform(0, 2 * np.pi))
    crossings = geometry.find_crossings(curve)
    if len(crossings) != (1 if hook is not None and hook.crossing else 0):
        raise geometry.ShapeError("only a crossing hook may cross itself, and only once")
    if crossings and (
        crossings[0].s_first > hook.bend_end
        or crossings[0].angle < np.radians(20)
        or crossings[0].s_first < 8e-4
    ):
        raise geometry.ShapeError("the hook must cross its tip arm clearly, away from the cut tip")
    free = 0 if hook is None else round(hook.free_from / geometry.SAMPLE_STEP)
    if geometry.has_close_approach(curve[free:], None, [], 0.0015) or (
        free and geometry.has_close_approach(curve[free:], curve[: free - 60], [], 0.0015)
    ):
        raise geometry.ShapeError("thread touches itself away from the hook")

    depth0, centre = _place(curve, camera, rng)
    curve = curve - curve.mean(axis=0) + centre
    surface = _surface(background, camera, depth0, rng)
    base = surface.depth(curve[:, 0], curve[:, 1]) - radius
    lift = geometry.random_lift(n, rng) * lift_weight
    geometry.raise_over_crossings([lift], [base], [(0, 0, c) for c in crossings], [radius], rng)
    depth = base - lift
    if length >= 0.060 + BURIED_END_MARGIN + 0.003 and rng.random() < 0.5:
        buried_from = length - rng.uniform(0.003, min(0.012, length - 0.060 - BURIED_END_MARGIN))
        # The thread rests on the tissue before it dives in at 20 to 60 degrees.
        rests = geometry.taper(n, buried_from - 0.008, buried_from - 0.003)
        s = np.arange(n) * geometry.SAMPLE_STEP
        dive = np.tan(np.radians(rng.uniform(20, 60))) * np.maximum(s - buried_from, 0.0)
        depth = base - lift * rests + dive
    target = _target_in_view(np.column_stack([curve, depth]), camera)
    if topology == "along_rows" and _row_aligned_arc(camera, target) < ROW_STRETCH:
        raise geometry.ShapeError("the target's straight stretch is not along the image rows")

    tubes = _thread_tubes([target], [radius], surface, rng)
    if topology == "wide_occlusion":
        for _ in range(rng.choice([1, 1, 2])):
            across = rng.random() < 0.7
            kind = replace(WIDE_INSTRUMENT, angle_deg=(40.0, 90.0) if across else (10.0, 30.0))
            tubes += _instrument(target, camera, rng, kind)
    return _Scene(surface, tubes, target, radius)


def _surface(background: str, camera: StereoCamera, depth0: float, rng: np.random.Generator) -> Surface:
    """A tissue surface of ``background`` at ``depth0`` (m) with a random slope."""
    # The texture patch covers the field of view at the surface's depth with some margin
    # for its slope; beyond it the texture mirrors. Texels stay ~2 px or finer.
    extent = 2.0 * max(camera.width / camera.fx, camera.height / camera.fy) * depth0
    size = 512 if camera.width <= 800 else 1024
    texture = textures.make_surface_texture(background, size, extent, rng)
    return Surface(
        depth0=depth0,
        slope=rng.uniform(-0.15, 0.15, size=2),
        texture=texture,
        origin=np.array([camera.baseline / 2 - extent / 2, -extent / 2]),
    )


def _thread_tubes(
    axes: list[np.ndarray], radii: list[float], surface: Surface, rng: np.random.Generator
) -> list[Tube]:
    """One tube per thread (the target first), in colours that contrast with the surface."""
    colours = rng.choice(contrasting_colours(surface.texture.albedo), size=len(axes))
    return [
        Tube(
            axis=axis,
            radius=radii[k],
            colour=np.array(THREAD_COLOURS[colours[k]]) * rng.uniform(0.8, 1.2),
            owner=k,
            specular=rng.uniform(0.05, 0.5),
            braid=rng.choice([0.0, rng.uniform(0.05, 0.25)]),
            shininess=rng.uniform(0.2, 0.45),
        )
        for k, axis in enumerate(axes)
    ]


def _row_aligned_arc(camera: StereoCamera, target: np.ndarray) -> float:
    """Longest arc (m) of the (N, 3) target, sampled every SAMPLE_STEP, whose direction in
    the left image (over 2 mm chords) stays within ``ROW_ANGLE`` degrees of the rows."""
    uv = camera.project(target, "left")
    half = round(0.001 / geometry.SAMPLE_STEP)
    chord = uv[2 * half :] - uv[: -2 * half]
    along = np.degrees(np.arctan2(np.abs(chord[:, 1]), np.abs(chord[:, 0]))) <= ROW_ANGLE
    # Longest run of aligned chords, counted in samples.
    run_id = np.cumsum(~along)
    longest = np.bincount(run_id[along]).max() if along.any() else 0
    return float(longest * geometry.SAMPLE_STEP)


def _target_in_view(thread: np.ndarray, camera: StereoCamera) -> np.ndarray:
    """The target thread resampled by arc length and cut to MAX_LENGTH; ShapeError unless it stays
    within the depth range and inside both views."""
    target = geometry.resample_by_arc_length(thread)
    if geometry.arc_length(target) > MAX_LENGTH:
        target = target[: int(MAX_LENGTH / geometry.SAMPLE_STEP) + 1]
    if not (target[:, 2].min() >= MIN_DEPTH and target[:, 2].max() <= MAX_DEPTH):
        raise geometry.ShapeError("thread leaves the 50-150 mm depth range")
    if not _inside(camera, target, BORDER_PX):
        raise geometry.ShapeError("target leaves a view")
    return target


def contrasting_colours(albedo: np.ndarray) -> list[str]:
    """Names of the thread colours visible on a background of (S, S, 3) linear-RGB ``albedo``.

    Visible means: in some channel the thread's albedo and the background's median albedo
    differ by at least :data:`MIN_COLOUR_CONTRAST` times.
    """
    background = np.median(albedo.reshape(-1, 3), axis=0)
    names = []
    for name, colour in THREAD_COLOURS.items():
        ratio = np.log(np.maximum(colour, 1e-3) / np.maximum(background, 1e-3))
        if np.max(np.abs(ratio)) >= np.log(MIN_COLOUR_CONTRAST):
            names.append(name)
    return names


def _place(curve: np.ndarray, camera: StereoCamera, rng: np.random.Generator) -> tuple[float, np.ndarray]:
    """Surface depth and planar centre so that the curve's footprint fits both views."""
    size = curve.max(axis=0) - curve.min(axis=0)
    usable = np.array([camera.width, camera.height]) - 2 * (BORDER_PX + 25)
    per_depth = usable / np.array([camera.fx, camera.fy])
    # Lifts, relief and slope bring parts of the thread up to ~20 % nearer the camera.
    needed = 1.25 * max(size[0] / per_depth[0] + 4 * camera.baseline / per_depth[0], size[1] / per_depth[1])
    low = max(MIN_DEPTH + 0.012, needed)
    high = MAX_DEPTH - 0.025
    if low > high:
        raise geometry.ShapeError("thread too large for the field of view")
    depth0 = rng.uniform(low, high)
    slack = np.maximum(per_depth * depth0 / 1.2 - size, 0.0) / 2
    centre = np.array([camera.baseline / 2, 0.0]) + rng.uniform(-slack, slack)
    centre += (
        np.array([camera.cx - (camera.width - 1) / 2, camera.cy - (camera.height - 1) / 2])
        / np.array([camera.fx, camera.fy])
        * depth0
    )
    return depth0, centre


def _crossing_thread(
    target: np.ndarray, target_length: float, rng: np.random.Generator
) -> tuple[np.ndarray, list[geometry.Crossing]]:
    """A second planar thread that crosses the target at 20 to 90 degrees."""
    length = rng.uniform(0.04, 0.12)
    shape = rng.choice(["straight", "curved"])
    other = geometry.planar_curve(length, geometry.curvature_profile(shape, length, rng))
    s_target = rng.uniform(0.25, 0.85) * target_length
    s_other = rng.uniform(0.3, 0.7) * length
    angle = np.radians(rng.uniform(20, 90)) * rng.choice([-1, 1])
    t_target = geometry.tangent_at(target, s_target)
    t_other = geometry.tangent_at(other, s_other)
    heading = np.arctan2(t_target[1], t_target[0]) + angle - np.arctan2(t_other[1], t_other[0])
    other = geometry.rotate(other, heading)
    i_t = round(s_target / geometry.SAMPLE_STEP)
    i_o = round(s_other / geometry.SAMPLE_STEP)
    other = other - other[i_o] + target[i_t]
    crossings = geometry.find_crossings(target, other)
    if not crossings or any(c.angle < np.radians(15) or c.s_first < 0.008 for c in crossings):
        raise geometry.ShapeError("crossing too shallow or too near the cut tip")
    if geometry.has_close_approach(target, other, crossings, 0.0015):
        raise geometry.ShapeError("second thread runs alongside the target")
    if np.min(np.linalg.norm(other - target[0], axis=1)) < 0.008:
        raise geometry.ShapeError("second thread covers the cut tip")
    return other, crossings


@dataclass(frozen=True)
class _InstrumentKind:
    """Ranges an instrument is drawn from: where along the target (share of its samples),
    the angle between shaft and thread (deg), shaft radius (m), hover of the tip above the
    thread (m), how far past the thread the shaft's end lies (m, beyond its radius when
    ``tip_past_edge``), the shaft's rise towards the camera (deg), jaw length (m) and the
    shaft's rasterised segment length (``render.Tube.segment_radii``)."""

    where: tuple[float, float]
    angle_deg: tuple[float, float]
    radius: tuple[float, float]
    hover: tuple[float, float]
    tip_past: tuple[float, float]
    tip_past_edge: bool
    elevation_deg: tuple[float, float]
    jaw_length: tuple[float, float]
    segment_radii: float = 0.5


THIN_INSTRUMENT = _InstrumentKind(
    (0.3, 0.8),
    (40.0, 90.0),
    (0.0015, 0.003),
    (0.004, 0.012),
    (0.003, 0.008),
    False,
    (10.0, 35.0),
    (0.005, 0.008),
)
#: da Vinci and dVRK shafts: 5 to 8.5 mm thick, jaws about 1 cm long.
WIDE_INSTRUMENT = _InstrumentKind(
    (0.15, 0.85),
    (40.0, 90.0),
    (0.0025, 0.00425),
    (0.002, 0.010),
    (0.001, 0.008),
    True,
    (5.0, 25.0),
    (0.008, 0.013),
    segment_radii=2.0,
)


def _instrument(
    target: np.ndarray, camera: StereoCamera, rng: np.random.Generator, kind: _InstrumentKind
) -> list[Tube]:
    """A grey instrument shaft with two jaws whose tip lies just past the target, hiding a
    stretch of it in ``kind.where`` of its length."""
    i = int(rng.uniform(*kind.where) * len(target))
    tangent = target[min(i + 5, len(target) - 1), :2] - target[max(i - 5, 0), :2]
    tangent /= np.linalg.norm(tangent)
    angle = np.radians(rng.uniform(*kind.angle_deg)) * rng.choice([-1, 1])
    direction = geometry.rotate(tangent[None, :], angle)[0]
    shaft_radius = rng.uniform(*kind.radius)
    # The shaft passes over the target point on the left camera's ray through it, so it
    # hides the thread in the left view and, a few pixels of disparity away, in the right.
    tip_depth = target[i, 2] - rng.uniform(*kind.hover) - shaft_radius
    over = target[i, :2] * tip_depth / target[i, 2]
    past = rng.uniform(*kind.tip_past) + (shaft_radius if kind.tip_past_edge else 0.0)
    tip = np.r_[over + direction * past, tip_depth]
    elevation = np.tan(np.radians(rng.uniform(*kind.elevation_deg)))
    t = np.linspace(0.0, 0.2, 200)
    shaft = np.column_stack([tip[:2] - t[:, None] * direction, tip_depth - elevation * t])
    shaft = shaft[: _frames_until_outside(camera, shaft, shaft_radius)]
    grey = rng.uniform(0.25, 0.55)
    tubes = [
        Tube(
            shaft,
            shaft_radius,
            np.array([grey, grey, grey * 1.05]),
            INSTRUMENT,
            specular=0.9,
            shininess=0.25,
            segment_radii=kind.segment_radii,
        )
    ]
    opening = np.radians(rng.uniform(5, 20))
    jaw_length = rng.uniform(*kind.jaw_length)
    for sign in (-1, 1):
        jaw_dir = geometry.rotate(direction[None, :], sign * opening)[0]
        s = np.linspace(0.0, jaw_length, 20)
        jaw = np.column_stack([tip[:2] + s[:, None] * jaw_dir, np.full(s.size, tip_depth)])
        tubes.append(Tube(jaw, 0.35 * shaft_radius, np.array([0.12, 0.12, 0.13]), INSTRUMENT, specular=0.6))
    return tubes


def _frames_until_outside(camera: StereoCamera, axis: np.ndarray, radius: float) -> int:
    """Number of leading axis points to keep: up to the first one whose tube lies wholly
    outside both views (or nearer than 2 cm), so that no pixel is spent off-screen."""
    gone = np.ones(len(axis), dtype=bool)
    reach = radius * camera.fx / np.maximum(axis[:, 2], 1e-3)
    for view in ("left", "right"):
        uv = camera.project(axis, view)
        outside_x = (uv[:, 0] < -reach) | (uv[:, 0] > camera.width + reach)
        gone &= outside_x | (uv[:, 1] < -reach) | (uv[:, 1] > camera.height + reach)
    gone |= axis[:, 2] < 0.02
    outside = np.flatnonzero(gone)
    return int(outside[0]) + 1 if outside.size else len(axis)


def _inside(camera: StereoCamera, points: np.ndarray, border: float) -> bool:
    for view in ("left", "right"):
        uv = camera.project(points, view)
        if not (
            np.all(uv[:, 0] >= border)
            and np.all(uv[:, 0] <= camera.width - 1 - border)
            and np.all(uv[:, 1] >= border)
            and np.all(uv[:, 1] <= camera.height - 1 - border)
        ):
            return False
    return True


def _longest_hidden_arc(samples: np.ndarray, *visible: np.ndarray) -> float:
    """Longest stretch of thread (m of arc) hidden in any view; ``samples`` (N, 3), flags (N,)."""
    steps = np.r_[0.0, np.linalg.norm(np.diff(samples, axis=0), axis=1)]
    longest = 0.0
    for flags in visible:
        hidden = flags == 0
        # Arc accumulated over each run of hidden samples, reset at every visible one.
        run_id = np.cumsum(~hidden)
        arc = np.bincount(run_id[hidden], weights=steps[hidden]) if hidden.any() else np.zeros(1)
        longest = max(longest, float(arc.max()))
    return longest


def _shafts_hide_a_stretch(
    camera: StereoCamera, view: str, render: ViewRender, samples: np.ndarray, visible: np.ndarray
) -> bool:
    """True when instruments hide ``MIN_SHAFT_HIDDEN`` to ``MAX_SHAFT_HIDDEN`` of arc of the
    target's (N, 3) ``samples`` in ``view``, and every hidden stretch that they cover has
    visible thread on both sides."""
    uv = np.rint(camera.project(samples, view)).astype(int)
    by_instrument = (visible == 0) & (render.owner[uv[:, 1], uv[:, 0]] == INSTRUMENT)
    steps = np.r_[0.0, np.linalg.norm(np.diff(samples, axis=0), axis=1)]
    if not MIN_SHAFT_HIDDEN <= steps[by_instrument].sum() <= MAX_SHAFT_HIDDEN:
        return False
    hidden = visible == 0
    run_id = np.cumsum(np.r_[True, hidden[1:] != hidden[:-1]])  # one id per run of equal flags
    covered_runs = np.unique(run_id[by_instrument])
    return not np.isin(covered_runs, (run_id[0], run_id[-1])).any()


def _visible(
    camera: StereoCamera, view: str, render: ViewRender, points: np.ndarray, radius: float
) -> np.ndarray:
    """1.0 where the target's own surface is front-most at the pixel of each point."""
    uv = np.rint(camera.project(points, view)).astype(int)
    owner = render.owner[uv[:, 1], uv[:, 0]]
    front = render.depth[uv[:, 1], uv[:, 0]]
    own_surface = np.abs(front - points[:, 2]) <= radius + 2e-4
    return ((owner == 0) & own_surface).astype(np.float64)


def _annotate(
    config: SimConfig,
    index: int,
    topology: str,
    background: str,
    scene: _Scene,
    left: ViewRender,
    right: ViewRender,
    rng: np.random.Generator,
    look_rng: np.random.Generator | None = None,
) -> SimFrame | None:
    """The frame's ground truth and camera images, or None where the scene breaks a rule of its
    topology. The look and its noise come from ``look_rng`` when given, else from ``rng``."""
    camera = config.camera
    target = scene.target
    # ~1 px spacing in the left view, the same 3D samples in both views.
    left_uv = camera.project(target, "left")
    pixel_arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(left_uv, axis=0), axis=1))])
    at = np.r_[np.arange(0.0, pixel_arc[-1], 1.0), pixel_arc[-1]]
    # Linear interpolation between 0.1 mm samples: the chord error is below 1e-6 m.
    samples = np.column_stack([np.interp(at, pixel_arc, target[:, k]) for k in range(3)])
    visible_left = _visible(camera, "left", left, samples, scene.radius)
    visible_right = _visible(camera, "right", right, samples, scene.radius)
    if not (visible_left[:3].all() and visible_right[:3].all()):
        return None  # the cut tip must be seen in both views
    if topology == "occluded" and (
        visible_left.all() or _longest_hidden_arc(samples, visible_left, visible_right) > MAX_HIDDEN_ARC
    ):
        return None  # the instrument missed the target, or lies along it instead of across
    if topology == "wide_occlusion" and not all(
        _shafts_hide_a_stretch(camera, view, render, samples, flags)
        for view, render, flags in (("left", left, visible_left), ("right", right, visible_right))
    ):
        return None
    path = target[:: 1 if topology in HARD_TOPOLOGIES else round(PATH_STEP / geometry.SAMPLE_STEP)]
    if not np.allclose(path[-1], target[-1]):
        path = np.vstack([path, target[-1]])
    position, tangent = point_at_arc_length(target, config.grasp_arc_length)
    quaternion = rotation_to_quaternion(grasp_rotation(position, tangent))
    look_rng = rng if look_rng is None else look_rng
    look = appearance.sample_look(config.domain, look_rng)
    hint_offset = rng.uniform(0, 3) * np.array([np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a)])
    return SimFrame(
        index=index,
        stamp_ns=config.start_ns + index * config.frame_period_ns,
        topology=topology,
        background=background,
        camera=camera,
        left_image=appearance.apply_look(left.image, look, look_rng),
        right_image=appearance.apply_look(right.image, look, look_rng),
        left_mask=(left.thread_mask * 255).astype(np.uint8),
        right_mask=(right.thread_mask * 255).astype(np.uint8),
        left_sequence=np.column_stack([camera.project(samples, "left"), visible_left]),
        right_sequence=np.column_stack([camera.project(samples, "right"), visible_right]),
        path=path,
        length=geometry.arc_length(target),
        grasp_position=position,
        grasp_quaternion=quaternion,
        tip_hint=left_uv[0] + hint_offset,
        diameter=2 * scene.radius,
    )
