# SPDX-License-Identifier: Apache-2.0
"""A physically based second renderer on Blender Cycles (``suture-sim --renderer cycles``).

It renders the scene that ``scene._sample_scene`` drew (the same tissue height field, thread
centrelines, instruments and stereo camera as the raster renderer of ``render``) with Cycles'
path tracer, and returns the same :class:`~suture_sim.render.ViewRender` per view, so the ground
truth is annotated by the same code in ``scene``:

* tissue: the height field as a smooth mesh, one vertex per texel (mirrored a margin beyond the
  patch), with a principled BSDF: the texture's albedo, subsurface scattering of about a
  millimetre, and a wet clear coat whose weight and roughness follow the texture's specular map;
* threads: tube meshes along the centrelines with a principled BSDF, a braid pattern (two
  helical bands in the tube's arc-length/angle coordinates) on colour and bump for braided ones;
* instruments: metallic tubes (shaft and two jaws);
* two point lights beside the optical centres (the endoscope's light guides), no ambient light
  beyond what the tissue reflects; depth of field focused on the target thread with a circle of
  confusion of 1 to 2 px at a third nearer than the focus.

The linear image then gets the domain's camera effects (``appearance.apply_look``: colour,
vignetting, sensor noise, tone curve, JPEG) in ``scene``, as the raster renderer's does.

Ground-truth passes. Cycles writes the object-index and depth passes from each pixel's first
sample only, so a second render per view with one sample at the pixel centre (filter width
0.01 px) and no depth of field gives them exactly: the owner of the pixel centre and its
planar depth. In that render the threads' cross-sections stand square to the line of sight and
are widened across it to at least ``MASK_RADIUS_PX`` (their depth extent stays the true radius):
the convention of the raster renderer, under which a thread thinner than a pixel still owns the
pixels its centreline passes through and its front lies one radius before its axis. Object
indices: tissue 1, instruments 2, thread k ``THREAD_INDEX + k``.

Camera. Blender's camera looks down its -Z axis with +Y up; the optical frame has z forward and
y down, so the camera object is the optical frame turned by pi about x. Focal length fx and the
principal point (as lens shift) reproduce the rectified pinhole ``StereoCamera`` exactly; Cycles
samples pixel (c, r) around raster point (c + 0.5, r + 0.5), where the pinhole model puts pixel
centres on integers. Blender's non-square pixels cannot be written to EXR, so where fy != fx
the whole scene is stretched by fy / fx along y instead (:func:`_stretch_to_square_pixels`): a
square-pixel camera of focal length fx then sees every point where the camera of focal lengths
(fx, fy) sees the unstretched one, at the same depth.

``bpy`` (the ``--with-blender`` extra of ``ros2_ws/setup.sh``) and ``OpenEXR`` are imported when a
frame is rendered, never by importing this module. Blender holds one global scene per process: a
render resets it first, so frames are independent; the path tracer's seed is fixed, so the same
frame renders to the same pixels.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from suture_common.camera import StereoCamera
from suture_sim.render import (
    BRAID_PERIOD,
    INSTRUMENT,
    MIN_CORE_RADIUS_PX,
    SURFACE,
    Lighting,
    Surface,
    Tube,
    ViewRender,
)

#: Default path-tracing samples per pixel of the image render.
DEFAULT_SAMPLES = 16

TISSUE_INDEX = 1
INSTRUMENT_INDEX = 2
THREAD_INDEX = 10

#: Light bounces of a path (half of them diffuse, half glossy at most).
MAX_BOUNCES = 4
#: Sides of a tube's polygonal cross-section (threads and instruments).
TUBE_SIDES = 10
#: Mirrored margin of the tissue mesh beyond the texture patch, as a fraction of its side.
TISSUE_MARGIN = 0.125
#: Half-width (px) of a thread in the ground-truth render: a little over the raster renderer's
#: core radius, so the pixel its centreline passes through is covered whatever the polygon.
MASK_RADIUS_PX = MIN_CORE_RADIUS_PX + 0.04


class CyclesUnavailableError(RuntimeError):
    """Blender's ``bpy`` module (or OpenEXR) is not installed: the cycles renderer needs the extra."""


@dataclass(frozen=True)
class CyclesSettings:
    """Render settings; ``threads`` 0 lets Cycles use every core."""

    samples: int = DEFAULT_SAMPLES
    threads: int = 0


def import_bpy():
    """Import ``bpy`` (and check OpenEXR), or raise :class:`CyclesUnavailableError`.

    Blender reports on standard output that it found no audio device, which is dropped. Its
    audio module is built against NumPy 1.x and prints a long warning (plus a caught
    ImportError) on standard error when NumPy 2 loads it; the renderer never plays audio, so
    exactly that warning is dropped and any other error output of the import is passed on.
    """
    try:
        import OpenEXR  # noqa: F401 - checked here so a missing extra fails before rendering

        captured = io.StringIO()
        with contextlib.redirect_stderr(captured), _blender_log_silenced():
            import bpy
    except ImportError as error:
        raise CyclesUnavailableError(
            f"the cycles renderer needs Blender's bpy module and OpenEXR ({error}); "
            "install them with `bash ros2_ws/setup.sh --with-blender`"
        ) from None
    if "compiled using NumPy 1.x" not in captured.getvalue():
        sys.stderr.write(captured.getvalue())
    return bpy


def render_stereo(
    camera: StereoCamera,
    surface: Surface,
    tubes: list[Tube],
    lighting: Lighting,
    rng: np.random.Generator,
    settings: CyclesSettings = CyclesSettings(),
) -> tuple[ViewRender, ViewRender]:
    """Render the left and right views of a scene with Cycles (linear RGB, ground-truth passes).

    ``rng`` draws the render's own choices (light placement, focus, aperture, materials'
    fine parameters); the scene's geometry is fixed by the arguments.
    """
    bpy = import_bpy()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    blender = bpy.context.scene
    _configure(blender, camera, settings)
    _add_tissue(bpy, blender, surface, rng)
    threads = [tube for tube in tubes if tube.owner >= 0]
    for tube in tubes:
        if tube.owner == INSTRUMENT:
            _add_instrument(bpy, blender, tube)
    midpoint = np.array([camera.baseline / 2, 0.0, 0.0])
    for tube in threads:
        _add_thread(bpy, blender, tube, midpoint, rng)
    _add_lights(bpy, blender, lighting, rng)
    _focus(blender, camera, threads, rng)
    _stretch_to_square_pixels([obj for obj in blender.collection.objects if obj != blender.camera], camera)
    views = []
    with tempfile.TemporaryDirectory(prefix="suture-cycles-") as folder:
        for view in ("left", "right"):
            _place_camera(blender, camera, view)
            masks = [_add_mask_thread(bpy, blender, tube, camera, view) for tube in threads]
            _stretch_to_square_pixels(masks, camera)
            owner, depth = _render_ground_truth(blender, masks, Path(folder) / f"{view}_gt.exr")
            image = _render_image(blender, masks, Path(folder) / f"{view}.exr", settings)
            views.append(ViewRender(image, depth, owner))
            for mask in masks:
                mesh = mask.data
                bpy.data.objects.remove(mask)
                bpy.data.meshes.remove(mesh)
    return views[0], views[1]


def _configure(blender, camera: StereoCamera, settings: CyclesSettings) -> None:
    render = blender.render
    render.engine = "CYCLES"
    render.resolution_x, render.resolution_y = camera.width, camera.height
    render.resolution_percentage = 100
    render.threads_mode = "FIXED" if settings.threads else "AUTO"
    if settings.threads:
        render.threads = settings.threads
    render.use_compositing = False
    render.use_sequencer = False
    render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    render.image_settings.color_depth = "32"
    render.image_settings.exr_codec = "ZIP"
    blender.view_settings.view_transform = "Standard"
    cycles = blender.cycles
    cycles.device = "CPU"
    cycles.use_denoising = False
    cycles.use_adaptive_sampling = False
    cycles.seed = 0
    cycles.max_bounces = MAX_BOUNCES
    cycles.diffuse_bounces = MAX_BOUNCES // 2
    cycles.glossy_bounces = MAX_BOUNCES // 2
    cycles.transmission_bounces = 0
    cycles.volume_bounces = 0
    cycles.transparent_max_bounces = 0
    cycles.caustics_reflective = False
    cycles.caustics_refractive = False
    cycles.use_light_tree = False  # two lights: sampling them directly is cheaper
    layer = blender.view_layers[0]
    layer.use_pass_z = True
    layer.use_pass_object_index = True
    world = blender.world or _new_world(blender)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0

    camera_data = _bpy().data.cameras.new("endoscope")
    camera_data.sensor_fit = "HORIZONTAL"
    camera_data.sensor_width = 36.0
    camera_data.lens = camera.fx * camera_data.sensor_width / camera.width
    camera_data.clip_start = 0.005
    camera_data.clip_end = 2.0
    # Lens shift in units of the image width (horizontal sensor fit); see the module docstring.
    camera_data.shift_x = (camera.width / 2 - 0.5 - camera.cx) / camera.width
    camera_data.shift_y = (camera.cy - camera.height / 2 + 0.5) / camera.width
    endoscope = _bpy().data.objects.new("endoscope", camera_data)
    endoscope.rotation_euler = (np.pi, 0.0, 0.0)
    blender.collection.objects.link(endoscope)
    blender.camera = endoscope


def _bpy():
    import bpy

    return bpy


def _new_world(blender):
    blender.world = _bpy().data.worlds.new("world")
    return blender.world


def _stretch_to_square_pixels(objects, camera: StereoCamera) -> None:
    """Stretch ``objects`` (their geometry and position) by fy / fx along y; see the module
    docstring. The camera itself, on the x axis, is never stretched."""
    stretch = camera.fy / camera.fx
    for obj in objects:
        obj.scale[1] = stretch
        obj.location[1] *= stretch


def _place_camera(blender, camera: StereoCamera, view: str) -> None:
    blender.camera.location = tuple(float(c) for c in camera.optical_centre(view))


def _mesh_object(
    bpy, blender, name: str, vertices: np.ndarray, faces: list[np.ndarray], uv: np.ndarray | None
):
    """A smooth-shaded mesh object of (V, 3) ``vertices`` and faces given as (F, k) arrays (one
    per polygon size), optional per-corner ``uv`` (corners in the order of ``faces``), linked
    into the scene."""
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(vertices))
    mesh.vertices.foreach_set("co", vertices.astype(np.float32).ravel())
    corners = np.concatenate([f.ravel() for f in faces]).astype(np.int32)
    sizes = np.concatenate([np.full(len(f), f.shape[1]) for f in faces])
    count = len(sizes)
    mesh.loops.add(len(corners))
    mesh.loops.foreach_set("vertex_index", corners)
    mesh.polygons.add(count)
    mesh.polygons.foreach_set("loop_start", np.r_[0, np.cumsum(sizes)[:-1]].astype(np.int32))
    if uv is not None:
        mesh.uv_layers.new(name="UVMap").uv.foreach_set("vector", uv.astype(np.float32).ravel())
    mesh.polygons.foreach_set("use_smooth", np.ones(count, dtype=bool))
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    blender.collection.objects.link(obj)
    return obj


def _grid_faces(rows: int, cols: int) -> np.ndarray:
    """(F, 4) quads of a rows x cols vertex grid, wound so that their normals face -z."""
    index = np.arange(rows * cols).reshape(rows, cols)
    return np.stack([index[:-1, :-1], index[1:, :-1], index[1:, 1:], index[:-1, 1:]], axis=-1).reshape(-1, 4)


def _add_tissue(bpy, blender, surface: Surface, rng: np.random.Generator) -> None:
    texture = surface.texture
    size = texture.size
    margin = round(TISSUE_MARGIN * size)
    cells = np.arange(-margin, size + margin)
    x = surface.origin[0] + (cells + 0.5) * surface.texel
    y = surface.origin[1] + (cells + 0.5) * surface.texel
    grid_x, grid_y = np.meshgrid(x, y)
    depth = surface.depth(grid_x, grid_y)  # mirrored beyond the patch, as the raster renderer sees it
    vertices = np.column_stack([grid_x.ravel(), grid_y.ravel(), depth.ravel()])
    faces = _grid_faces(len(cells), len(cells))
    # Texture row i is image row i (Blender's image rows start at v = 0): no flip.
    u, v = np.meshgrid((cells + 0.5) / size, (cells + 0.5) / size)
    uv = np.column_stack([u.ravel(), v.ravel()])[faces.ravel()]
    tissue = _mesh_object(bpy, blender, "tissue", vertices, [faces], uv)
    tissue.pass_index = TISSUE_INDEX

    pixels = np.concatenate([texture.albedo, texture.specular[..., None]], axis=-1).astype(np.float32)
    image = bpy.data.images.new("tissue", size, size, alpha=True, float_buffer=True)
    image.colorspace_settings.name = "Non-Color"
    image.alpha_mode = "CHANNEL_PACKED"
    image.pixels.foreach_set(pixels.ravel())
    image.pack()

    material = bpy.data.materials.new("tissue")
    nodes, links = material.node_tree.nodes, material.node_tree.links
    bsdf = nodes["Principled BSDF"]
    sampler = nodes.new("ShaderNodeTexImage")
    sampler.image = image
    sampler.extension = "MIRROR"
    sampler.interpolation = "Linear"
    links.new(sampler.outputs["Color"], bsdf.inputs["Base Color"])
    links.new(sampler.outputs["Color"], bsdf.inputs["Subsurface Radius"])
    bsdf.subsurface_method = "BURLEY"
    bsdf.inputs["Subsurface Weight"].default_value = rng.uniform(0.3, 0.6)
    bsdf.inputs["Subsurface Scale"].default_value = rng.uniform(0.5e-3, 1.5e-3)
    bsdf.inputs["Roughness"].default_value = rng.uniform(0.45, 0.6)
    bsdf.inputs["IOR"].default_value = 1.4
    # The wet film: a clear coat whose weight follows the specular map, glossier where wetter.
    wet = nodes.new("ShaderNodeMath")
    wet.operation = "MULTIPLY"
    wet.inputs[1].default_value = rng.uniform(0.6, 1.0)
    links.new(sampler.outputs["Alpha"], wet.inputs[0])
    links.new(wet.outputs[0], bsdf.inputs["Coat Weight"])
    gloss = nodes.new("ShaderNodeMapRange")
    gloss.inputs["To Min"].default_value = 0.25
    gloss.inputs["To Max"].default_value = 0.04
    links.new(sampler.outputs["Alpha"], gloss.inputs["Value"])
    links.new(gloss.outputs["Result"], bsdf.inputs["Coat Roughness"])
    bsdf.inputs["Coat IOR"].default_value = 1.33
    tissue.data.materials.append(material)


def _tube_frames(
    axis: np.ndarray, eye: np.ndarray, facing: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit tangent, side and depth directions of an (N, 3) axis, each (N, 3).

    The side direction lies across the line of sight from ``eye``. The depth direction is the
    line of sight itself when ``facing`` (cross-sections stand square to the view, so the
    surface a ray meets at the centreline is one radius in front of the axis however steeply
    the thread dips, as the raster renderer models it), else the normal of a round tube.
    """
    tangent = np.gradient(axis, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    sight = axis - eye
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    side = np.cross(tangent, sight)
    degenerate = np.linalg.norm(side, axis=1) < 1e-6
    side[degenerate] = np.cross(tangent, [1.0, 0.0, 0.0])[degenerate]
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    return tangent, side, sight if facing else np.cross(side, tangent)


def _tube_mesh(
    axis: np.ndarray,
    side_radius: np.ndarray,
    depth_radius: np.ndarray,
    eye: np.ndarray,
    facing: bool = False,
) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """Vertices, faces (quads, then the two end caps) and per-corner UVs (arc / BRAID_PERIOD,
    angle / 2 pi; zero on the caps) of a closed tube with elliptical cross-sections of
    semi-axes ``side_radius`` and ``depth_radius`` (N,) along the frames of :func:`_tube_frames`.
    The ends are extended by the side radius, as the raster renderer's round caps are."""
    tangent, side, normal = _tube_frames(axis, eye, facing)
    axis = np.vstack(
        [axis[:1] - tangent[:1] * side_radius[0], axis, axis[-1:] + tangent[-1:] * side_radius[-1]]
    )
    side_radius = np.r_[side_radius[0], side_radius, side_radius[-1]]
    depth_radius = np.r_[depth_radius[0], depth_radius, depth_radius[-1]]
    tangent, side, normal = (np.vstack([a[:1], a, a[-1:]]) for a in (tangent, side, normal))
    angle = np.linspace(0.0, 2 * np.pi, TUBE_SIDES, endpoint=False)
    rings = (
        axis[:, None, :]
        + (side_radius[:, None, None] * np.cos(angle)[None, :, None]) * side[:, None, :]
        + (depth_radius[:, None, None] * np.sin(angle)[None, :, None]) * normal[:, None, :]
    )
    n = len(axis)
    ring = np.arange(TUBE_SIDES)
    nxt = (ring + 1) % TUBE_SIDES
    start = (np.arange(n - 1) * TUBE_SIDES)[:, None]
    faces = np.stack(
        [start + ring, start + TUBE_SIDES + ring, start + TUBE_SIDES + nxt, start + nxt], axis=-1
    ).reshape(-1, 4)
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(axis, axis=0), axis=1))] / BRAID_PERIOD
    along = np.stack([arc[:-1], arc[1:], arc[1:], arc[:-1]], axis=-1)  # (n-1, 4)
    around = np.stack([ring, ring, ring + 1, ring + 1], axis=-1) / TUBE_SIDES  # (sides, 4)
    uv = np.stack(np.broadcast_arrays(along[:, None, :], around[None, :, :]), axis=-1).reshape(-1, 2)
    vertices = rings.reshape(-1, 3)
    # Each end closed by one polygon, wound to face outwards.
    last = (n - 1) * TUBE_SIDES
    caps = np.stack([ring, last + ring[::-1]])
    return vertices, [faces, caps], np.vstack([uv, np.zeros((caps.size, 2))])


def _add_thread(bpy, blender, tube: Tube, eye: np.ndarray, rng: np.random.Generator):
    radius = np.full(len(tube.axis), tube.radius)
    vertices, faces, uv = _tube_mesh(tube.axis, radius, radius, eye)
    thread = _mesh_object(bpy, blender, f"thread_{tube.owner}", vertices, faces, uv)
    thread.pass_index = THREAD_INDEX + tube.owner

    material = bpy.data.materials.new(f"thread_{tube.owner}")
    nodes, links = material.node_tree.nodes, material.node_tree.links
    bsdf = nodes["Principled BSDF"]
    colour = np.clip(tube.colour, 0.0, 1.0)
    bsdf.inputs["Roughness"].default_value = float(np.clip(tube.shininess + 0.15, 0.2, 0.7))
    bsdf.inputs["Specular IOR Level"].default_value = float(0.3 + tube.specular)
    bsdf.inputs["Sheen Weight"].default_value = rng.uniform(0.0, 0.3)
    if tube.braid > 0:
        # Two helical bands crossing: sin(2 pi (s + 2 a)) * sin(2 pi (s - 2 a)) in [-1, 1].
        coords = nodes.new("ShaderNodeUVMap")
        split = nodes.new("ShaderNodeSeparateXYZ")
        links.new(coords.outputs["UV"], split.inputs[0])
        bands = []
        for sign in (1.0, -1.0):
            scaled = _math(nodes, links, "MULTIPLY", split.outputs["Y"], 2.0 * sign)
            summed = _math(nodes, links, "ADD", split.outputs["X"], scaled)
            turned = _math(nodes, links, "MULTIPLY", summed, 2 * np.pi)
            bands.append(_math(nodes, links, "SINE", turned, 0.0))
        pattern = _math(nodes, links, "MULTIPLY", bands[0], bands[1])
        shade = _math(nodes, links, "MULTIPLY_ADD", pattern, float(tube.braid), 1.0)
        tint = nodes.new("ShaderNodeMix")
        tint.data_type = "RGBA"
        tint.blend_type = "MULTIPLY"
        tint.inputs["Factor"].default_value = 1.0
        tint.inputs[6].default_value = (*colour, 1.0)
        links.new(shade, tint.inputs[7])
        links.new(tint.outputs[2], bsdf.inputs["Base Color"])
        bump = nodes.new("ShaderNodeBump")
        bump.inputs["Distance"].default_value = 0.3 * tube.radius
        links.new(pattern, bump.inputs["Height"])
        links.new(bump.outputs["Normal"], bsdf.inputs["Normal"])
    else:
        bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    thread.data.materials.append(material)
    return thread


def _math(nodes, links, operation: str, first, second, third=None):
    """A Math node's output: ``operation`` on a socket and a socket or a constant (or two)."""
    node = nodes.new("ShaderNodeMath")
    node.operation = operation
    for slot, value in enumerate((first, second, third)):
        if value is None:
            continue
        if isinstance(value, (int, float)):
            node.inputs[slot].default_value = value
        else:
            links.new(value, node.inputs[slot])
    return node.outputs[0]


def _add_mask_thread(bpy, blender, tube: Tube, camera: StereoCamera, view: str):
    """The thread as seen by the ground-truth render of ``view``: at least MASK_RADIUS_PX wide
    in that view, the true radius deep."""
    eye = camera.optical_centre(view)
    depth = tube.axis[:, 2]
    side = np.maximum(tube.radius, MASK_RADIUS_PX * depth / min(camera.fx, camera.fy))
    vertices, faces, _ = _tube_mesh(tube.axis, side, np.full(len(depth), tube.radius), eye, facing=True)
    mask = _mesh_object(bpy, blender, f"mask_{tube.owner}", vertices, faces, None)
    mask.pass_index = THREAD_INDEX + tube.owner
    return mask


def _add_instrument(bpy, blender, tube: Tube) -> None:
    radius = np.full(len(tube.axis), tube.radius)
    vertices, faces, _ = _tube_mesh(tube.axis, radius, radius, np.zeros(3))
    part = _mesh_object(bpy, blender, "instrument", vertices, faces, None)
    part.pass_index = INSTRUMENT_INDEX
    material = bpy.data.materials.new("steel")
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*np.clip(tube.colour * 1.4, 0, 1), 1.0)
    bsdf.inputs["Metallic"].default_value = 1.0
    bsdf.inputs["Roughness"].default_value = 0.3 if tube.radius > 1e-3 else 0.4
    part.data.materials.append(material)


def _add_lights(bpy, blender, lighting: Lighting, rng: np.random.Generator) -> None:
    """Two point lights beside the optical centres; their power makes a white Lambertian surface
    facing them at ``lighting.reference_distance`` about as bright as the raster renderer's."""
    spread = rng.uniform(0.003, 0.005)
    # A point light of power P gives a facing Lambertian surface of albedo a at distance d the
    # radiance a * P / (4 pi^2 d^2): two lights together give radiance a at the reference distance.
    power = 4 * np.pi**2 * lighting.reference_distance**2 / 2
    for side in (-1.0, 1.0):
        light = bpy.data.lights.new(f"light_{side:+.0f}", type="POINT")
        light.energy = power * rng.uniform(0.9, 1.1)
        light.shadow_soft_size = rng.uniform(0.0005, 0.0015)
        light.color = (1.0, rng.uniform(0.95, 1.0), rng.uniform(0.88, 0.97))
        lamp = bpy.data.objects.new(light.name, light)
        lamp.location = tuple(float(c) for c in lighting.position + np.array([side * spread, 0.0, 0.0]))
        blender.collection.objects.link(lamp)


def _focus(blender, camera: StereoCamera, threads: list[Tube], rng: np.random.Generator) -> None:
    """Set a mild depth of field focused near the target thread."""
    focus = float(np.median(threads[0].axis[:, 2])) * rng.uniform(0.92, 1.08)
    # Circle of confusion (px) at depth z: fx * aperture * |z - focus| / (z * focus).
    blur_px = rng.uniform(1.0, 2.0)  # at a third nearer than the focus
    aperture = blur_px * (2 / 3) * focus / (camera.fx * (1 / 3))
    data = blender.camera.data
    data.dof.focus_distance = focus
    # Cycles' aperture radius is (lens / 1000) / (2 * f-stop) in scene units (metres).
    data.dof.aperture_fstop = (data.lens / 1000) / aperture


def _render_ground_truth(blender, masks: list, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Owner codes (H, W) int16 and planar depth (H, W) float32 of the pixel centres."""
    for obj in blender.collection.objects:
        if obj.name.startswith("thread_"):
            obj.hide_render = True
    for mask in masks:
        mask.hide_render = False
    cycles = blender.cycles
    cycles.samples = 1
    cycles.filter_width = 0.01
    cycles.max_bounces = 0
    blender.camera.data.dof.use_dof = False
    passes = _render(blender, path)
    index = np.rint(passes["Object Index"]).astype(np.int32)
    owner = np.full(index.shape, SURFACE, dtype=np.int16)
    owner[index == INSTRUMENT_INDEX] = INSTRUMENT
    threads = index >= THREAD_INDEX
    owner[threads] = index[threads] - THREAD_INDEX
    depth = passes["Depth"].astype(np.float32)
    return owner, depth


def _render_image(blender, masks: list, path: Path, settings: CyclesSettings) -> np.ndarray:
    """Linear RGB (H, W, 3) float32 of the physically based render."""
    for obj in blender.collection.objects:
        if obj.name.startswith("thread_"):
            obj.hide_render = False
    for mask in masks:
        mask.hide_render = True
    cycles = blender.cycles
    cycles.samples = settings.samples
    cycles.filter_width = 1.5
    cycles.max_bounces = MAX_BOUNCES
    blender.camera.data.dof.use_dof = True
    return _render(blender, path)["Combined"][..., :3].copy()


@contextlib.contextmanager
def _blender_log_silenced() -> Iterator[None]:
    """Send the process's standard output to /dev/null meanwhile: Blender prints its render
    progress there from C, past ``sys.stdout``, which would garble a command's output."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def _render(blender, path: Path) -> dict[str, np.ndarray]:
    """Render the scene to a multilayer EXR at ``path`` and read its passes back, rows top first:
    'Combined' (H, W, 4), 'Depth' and 'Object Index' (H, W)."""
    import OpenEXR

    blender.render.filepath = str(path)
    with _blender_log_silenced():
        _bpy().ops.render.render(write_still=True)
    passes = {}
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        for part in exr.parts:
            name = part.name().split(".", 1)[-1]
            channels = part.channels
            keys = sorted(channels, key=lambda k: "RGBAXZ".find(k[-1]))
            planes = [channels[k].pixels for k in keys]
            passes[name] = planes[0] if len(planes) == 1 else np.stack(planes, axis=-1)
    os.remove(path)
    return passes
