"""Build the procedural street in bpy and render the ground-truth drive with Cycles on the CPU.

World: Blender's (Z up, metres); the road runs along +Y and the drive starts near the origin. Cameras are
OpenCV (``core.cameras``); a pixel's depth and instance id come from a second, one-sample render whose material
override emits (camera z, object index) sampled at pixel centres (a 0.01 px box filter), so depth is exact at
(u + 0.5, v + 0.5) rather than an anti-aliased blend of foreground and background.

This module resets the running Blender session: run it in its own process (``python -m scpainter_blender.street``).
"""

from __future__ import annotations

import json
import math
import os
import time

import bpy
import numpy as np
from mathutils import Matrix

from ..core import cameras, vggt
from ..core.shapes import MeshBuilder, add_car
from ..scene.compat import node_tree
from .dataset import GENERATOR_VERSION, StreetParams, view_name

# Street cross-section along x (metres): three lanes, parking strips, kerbs, sidewalks, building line.
ROAD_HALF = 5.25
PARKING_HALF = 7.25
KERB_HALF = 7.45
SIDEWALK_HALF = 10.5
KERB_HEIGHT = 0.15
BEND_LENGTH = 20.0  # metres over which the path drifts curve_m sideways


# --------------------------------------------------------------------------------------------------------------
# Geometry: core.shapes builds the arrays; this makes them Blender objects
# --------------------------------------------------------------------------------------------------------------

def to_object(builder: MeshBuilder, name, collection, pass_index=0):
    """One mesh object from a MeshBuilder whose material keys are Blender materials."""
    verts, faces, mats = builder.arrays()
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts.tolist(), [], faces)
    for m in builder.materials:
        mesh.materials.append(m)
    mesh.polygons.foreach_set("material_index", mats)
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    obj.pass_index = pass_index
    collection.objects.link(obj)
    return obj


# --------------------------------------------------------------------------------------------------------------
# Materials
# --------------------------------------------------------------------------------------------------------------

def _material(name):
    mat = bpy.data.materials.new(name)
    nt = node_tree(mat)
    bsdf = next(n for n in nt.nodes if n.type == "BSDF_PRINCIPLED")
    return mat, nt, bsdf


def plain(name, color, roughness=0.6, metallic=0.0):
    mat, _, bsdf = _material(name)
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    mat.diffuse_color = (*color, 1.0)
    return mat


def asphalt(name, seed):
    """Dark grey with fine noise and larger stains, so the road has texture to see alignment against."""
    mat, nt, bsdf = _material(name)
    tc = nt.nodes.new("ShaderNodeTexCoord")
    fine = nt.nodes.new("ShaderNodeTexNoise")
    fine.inputs["Scale"].default_value = 3.0
    fine.inputs["Detail"].default_value = 3.0  # each octave costs: 3 keep a CPU render of the drive cheap
    mapping = nt.nodes.new("ShaderNodeMapping")  # the seed moves the noise field
    mapping.inputs["Location"].default_value = (17.0 * seed, 0.0, 0.0)
    nt.links.new(tc.outputs["Object"], mapping.inputs["Vector"])
    nt.links.new(mapping.outputs["Vector"], fine.inputs["Vector"])
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.035, 0.035, 0.038, 1)
    ramp.color_ramp.elements[1].color = (0.16, 0.16, 0.165, 1)
    nt.links.new(fine.outputs["Fac"], ramp.inputs["Fac"])
    nt.links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.9
    return mat


def facade(name, wall, glass=(0.04, 0.06, 0.09), window=(1.6, 1.4)):
    """A wall with a grid of dark windows: a brick texture whose bricks are the windows, mortar the wall."""
    mat, nt, bsdf = _material(name)
    tc = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    comb = nt.nodes.new("ShaderNodeCombineXYZ")
    nt.links.new(tc.outputs["Object"], sep.inputs["Vector"])
    nt.links.new(sep.outputs["Y"], comb.inputs["X"])  # facades face ±X: windows tile the (y, z) plane
    nt.links.new(sep.outputs["Z"], comb.inputs["Y"])
    brick = nt.nodes.new("ShaderNodeTexBrick")
    brick.offset = 0.0
    brick.inputs["Scale"].default_value = 1.0
    brick.inputs["Brick Width"].default_value = window[0]
    brick.inputs["Row Height"].default_value = window[1]
    brick.inputs["Mortar Size"].default_value = 0.45
    brick.inputs["Color1"].default_value = (*glass, 1)
    brick.inputs["Color2"].default_value = tuple(c * 1.4 for c in glass) + (1,)
    brick.inputs["Mortar"].default_value = (*wall, 1)
    nt.links.new(comb.outputs["Vector"], brick.inputs["Vector"])
    nt.links.new(brick.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.7
    mat.diffuse_color = (*wall, 1.0)
    return mat


def sky_world(name="SCPainter street sky"):
    world = bpy.data.worlds.new(name)
    nt = node_tree(world, clear=True)
    tc = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].position = 0.0
    ramp.color_ramp.elements[0].color = (0.75, 0.82, 0.92, 1)
    ramp.color_ramp.elements[1].position = 0.5
    ramp.color_ramp.elements[1].color = (0.22, 0.42, 0.85, 1)
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = 1.0
    out = nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(tc.outputs["Generated"], sep.inputs["Vector"])  # world "Generated" = view direction
    nt.links.new(sep.outputs["Z"], ramp.inputs["Fac"])
    nt.links.new(ramp.outputs["Color"], bg.inputs["Color"])
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    world.cycles.sampling_method = "NONE"
    return world


def black_world():
    world = bpy.data.worlds.new("SCPainter black")
    bg = next(n for n in node_tree(world).nodes if n.type == "BACKGROUND")
    bg.inputs["Color"].default_value = (0, 0, 0, 1)
    bg.inputs["Strength"].default_value = 0.0
    return world


def depth_override():
    """Emission of (camera z in metres, object pass index, 1): read back from a float EXR."""
    mat = bpy.data.materials.new("SCPainter depth override")
    nt = node_tree(mat, clear=True)
    camdata = nt.nodes.new("ShaderNodeCameraData")
    info = nt.nodes.new("ShaderNodeObjectInfo")
    comb = nt.nodes.new("ShaderNodeCombineColor")
    emit = nt.nodes.new("ShaderNodeEmission")
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(camdata.outputs["View Z Depth"], comb.inputs[0])
    nt.links.new(info.outputs["Object Index"], comb.inputs[1])
    comb.inputs[2].default_value = 1.0
    nt.links.new(comb.outputs[0], emit.inputs["Color"])
    emit.inputs["Strength"].default_value = 1.0
    nt.links.new(emit.outputs[0], out.inputs["Surface"])
    return mat


# --------------------------------------------------------------------------------------------------------------
# The street
# --------------------------------------------------------------------------------------------------------------

def build_scene(params: StreetParams) -> dict:
    """Reset Blender and build the street; returns the parked cars' boxes (world metres) and the path length."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    rng = np.random.default_rng(params.seed)
    scene = bpy.context.scene
    coll = scene.collection
    length = params.num_frames * params.frame_spacing_m + 80.0
    y0, y1 = -30.0, length

    mats = {
        "road": asphalt("road", params.seed), "paint": plain("lane paint", (0.85, 0.85, 0.82), 0.5),
        "kerb": plain("kerb", (0.42, 0.42, 0.4), 0.8), "sidewalk": plain("sidewalk", (0.55, 0.53, 0.5), 0.85),
        "pole": plain("pole", (0.3, 0.32, 0.33), 0.4, 0.6), "glass": plain("car glass", (0.02, 0.025, 0.03), 0.1),
        "tyre": plain("tyre", (0.02, 0.02, 0.02), 0.9),
    }
    ground = MeshBuilder()
    ground.box((0, (y0 + y1) / 2, -0.05), (2 * PARKING_HALF, y1 - y0, 0.1), mats["road"])
    for side in (-1, 1):
        ground.box((side * (PARKING_HALF + KERB_HALF) / 2, (y0 + y1) / 2, KERB_HEIGHT / 2 - 0.05),
                   (KERB_HALF - PARKING_HALF, y1 - y0, KERB_HEIGHT + 0.1), mats["kerb"])
        ground.box((side * (KERB_HALF + SIDEWALK_HALF) / 2, (y0 + y1) / 2, KERB_HEIGHT / 2 - 0.05),
                   (SIDEWALK_HALF - KERB_HALF, y1 - y0, KERB_HEIGHT + 0.1), mats["sidewalk"])
        ground.box((side * (ROAD_HALF - 0.2), (y0 + y1) / 2, 0.002), (0.15, y1 - y0, 0.004), mats["paint"])
        for y in np.arange(y0 + rng.uniform(0, 6), y1, 15.0):
            ground.cylinder((side * (KERB_HALF + 0.5), y, KERB_HEIGHT + 2.5), 0.08, 5.0, 2, mats["pole"], 10)
    for lane_x in (-1.75, 1.75):  # dashed lane marks, 3 m on, 6 m off
        for y in np.arange(y0, y1, 9.0):
            ground.box((lane_x, y + 1.5, 0.002), (0.15, 3.0, 0.004), mats["paint"])
    to_object(ground, "street ground", coll)

    buildings = MeshBuilder()
    for side in (-1, 1):
        y = y0
        while y < y1:
            w = rng.uniform(7.0, 15.0)
            h = rng.uniform(6.0, 20.0)
            d = 10.0
            wall = tuple(rng.uniform([0.25, 0.2, 0.15], [0.75, 0.65, 0.55]))
            mat = facade(f"facade {side} {y:.0f}", wall, window=(rng.uniform(1.3, 2.2), rng.uniform(1.2, 1.6)))
            buildings.box((side * (SIDEWALK_HALF + d / 2), y + w / 2, h / 2), (d, w - 0.3, h), mat)
            y += w
    to_object(buildings, "street buildings", coll)

    cars = []
    drive_len = params.num_frames * params.frame_spacing_m
    slots = np.linspace(6.0, drive_len + 30.0, params.num_parked_cars)
    for k, y in enumerate(slots):
        side = 1 if k % 2 == 0 else -1
        builder = MeshBuilder()
        paint = plain(f"car paint {k}", tuple(rng.uniform(0.05, 0.8, 3)), 0.35, 0.2)
        add_car(builder, rng, paint, mats["glass"], mats["tyre"])
        obj = to_object(builder, f"parked car {k + 1}", coll, pass_index=k + 1)
        x = side * (ROAD_HALF + PARKING_HALF) / 2
        yaw = float(rng.uniform(-0.04, 0.04))
        obj.location = (x, float(y + rng.uniform(-2, 2)), 0.0)
        obj.rotation_euler = (0.0, 0.0, yaw)
        lo, hi = builder.bounds()  # the box that holds every part, wheels included
        M = np.array(obj.matrix_basis, dtype=np.float64)
        box = M.copy()
        box[:3, 3] = M[:3, :3] @ ((lo + hi) / 2) + M[:3, 3]
        cars.append({"name": obj.name, "instance": k + 1, "box_to_world": box.tolist(),
                     "size": (hi - lo).tolist()})

    sun = bpy.data.lights.new("sun", "SUN")
    sun.energy = 4.0
    sun.angle = math.radians(0.5)
    sun_obj = bpy.data.objects.new("sun", sun)
    sun_obj.rotation_euler = (math.radians(48), 0.0, math.radians(35))
    coll.objects.link(sun_obj)
    scene.world = sky_world()

    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    coll.objects.link(cam)
    scene.camera = cam
    return {"cars": cars}


def recorded_path(params: StreetParams) -> np.ndarray:
    """OpenCV world_to_camera (S, 4, 4) of the recorded drive: along +Y in the ego lane, a gentle bend."""
    S = params.num_frames
    y = np.arange(S) * params.frame_spacing_m
    x = params.lane_x_m + params.curve_m * (y / BEND_LENGTH) ** 2  # the same bend whatever the frame count
    dxdy = 2 * params.curve_m * y / BEND_LENGTH ** 2
    heading = np.stack([dxdy, np.ones(S), np.zeros(S)], axis=1)
    heading /= np.linalg.norm(heading, axis=1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0])
    p = math.radians(params.pitch_deg)
    z_ax = math.cos(p) * heading + math.sin(p) * up
    x_ax = np.cross(heading, up)
    x_ax /= np.linalg.norm(x_ax, axis=1, keepdims=True)
    y_ax = np.cross(z_ax, x_ax)
    T = np.tile(np.eye(4), (S, 1, 1))
    T[:, :3, :3] = np.stack([x_ax, y_ax, z_ax], axis=1)
    centres = np.stack([x, y, np.full(S, params.camera_height_m)], axis=1)
    T[:, :3, 3] = -np.einsum("nij,nj->ni", T[:, :3, :3], centres)
    return T


def _set_camera(scene, cam, K, w2c, params):
    bc = cameras.blender_camera_from_K(K, params.width, params.height)
    d = cam.data
    d.sensor_fit, d.sensor_width, d.sensor_height = bc.sensor_fit, bc.sensor_width, bc.sensor_height
    d.lens, d.shift_x, d.shift_y = bc.lens, bc.shift_x, bc.shift_y
    d.clip_start, d.clip_end = 0.05, 1000.0
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = params.width, params.height, 100
    r.pixel_aspect_x, r.pixel_aspect_y = bc.pixel_aspect_x, bc.pixel_aspect_y
    cam.matrix_world = Matrix(cameras.blender_matrix_world(w2c).tolist())  # Matrix(rows); a bare list would be columns


def _read_image(path, channels):
    """Pixels of an image file as (H, W, channels) float32, rows going down."""
    img = bpy.data.images.load(path, check_existing=False)
    try:
        W, H = img.size
        buf = np.empty(W * H * 4, dtype=np.float32)
        img.pixels.foreach_get(buf)
    finally:
        bpy.data.images.remove(img)
    return buf.reshape(H, W, 4)[::-1, :, :channels].copy()


def _configure_colour(scene, params):
    c = scene.cycles
    scene.render.engine = "CYCLES"
    c.device = "CPU"
    c.samples = params.samples
    c.use_adaptive_sampling = False
    c.use_denoising = False  # OIDN costs more than the render itself on 2 cores
    c.use_light_tree = False
    c.seed = params.seed
    c.max_bounces, c.diffuse_bounces, c.glossy_bounces = 3, 2, 1
    c.transmission_bounces, c.volume_bounces, c.transparent_max_bounces = 0, 0, 2
    c.caustics_reflective = c.caustics_refractive = False
    c.pixel_filter_type, c.filter_width = "BLACKMAN_HARRIS", 1.5
    scene.render.use_persistent_data = True
    for prop in scene.render.bl_rna.properties:  # no render time or date in the PNGs: byte-identical reruns
        if prop.identifier.startswith("use_stamp"):
            setattr(scene.render, prop.identifier, False)
    scene.view_settings.view_transform = "AgX"
    s = scene.render.image_settings
    s.file_format, s.color_mode, s.color_depth = "PNG", "RGB", "8"


def _configure_depth(scene):
    c = scene.cycles
    c.samples = 1
    c.use_denoising = False
    c.max_bounces = 0
    c.pixel_filter_type, c.filter_width = "BOX", 0.01
    s = scene.render.image_settings
    s.file_format, s.color_mode, s.color_depth, s.exr_codec = "OPEN_EXR", "RGB", "32", "NONE"


def render_drive(params: StreetParams, out_dir: str, log=print) -> dict:
    """Render every view of the drive into ``out_dir`` and write predictions.npz, metric.npz, street.json."""
    t0 = time.perf_counter()
    scene_info = build_scene(params)
    scene = bpy.context.scene
    cam = scene.camera
    S, W, H = params.num_frames, params.width, params.height
    K = np.array([[params.focal_px, 0, W / 2], [0, params.focal_px, H / 2], [0, 0, 1.0]])
    w2c = recorded_path(params)
    views = {"recorded": w2c}
    for shift in params.shifts_m:
        views[view_name(shift)] = cameras.shift_trajectory(w2c, left_m=shift)
    t_build = time.perf_counter()

    sky, black, override = scene.world, black_world(), depth_override()
    images = np.zeros((S, H, W, 3), np.float32)
    depth = np.zeros((S, H, W), np.float32)
    instance = np.zeros((S, H, W), np.uint8)
    n_renders, total = 0, S * (len(views) + 1)
    for name, poses in views.items():
        os.makedirs(os.path.join(out_dir, name), exist_ok=True)
        for i in range(S):
            _set_camera(scene, cam, K, poses[i], params)
            _configure_colour(scene, params)
            scene.world = sky
            scene.view_layers[0].material_override = None
            path = os.path.join(out_dir, name, f"frame_{i:06d}.png")
            scene.render.filepath = path
            bpy.ops.render.render(write_still=True)
            n_renders += 1
            if name == "recorded":
                images[i] = _read_image(path, 3)
                _configure_depth(scene)
                scene.world = black
                scene.view_layers[0].material_override = override
                exr = os.path.join(out_dir, f".depth_{i:06d}.exr")
                scene.render.filepath = exr
                bpy.ops.render.render(write_still=True)
                px = _read_image(exr, 3)
                os.remove(exr)
                n_renders += 1
                z = px[..., 0]
                depth[i] = np.where(z > 0, z, np.inf)
                instance[i] = np.rint(px[..., 1]).astype(np.uint8)
            log(json.dumps({"event": "progress", "stage": "street", "done": n_renders, "total": total}))
    scene.world = sky
    scene.view_layers[0].material_override = None
    _configure_colour(scene, params)
    t_render = time.perf_counter()

    write_predictions(out_dir, params, images, depth, K, w2c)
    np.savez(os.path.join(out_dir, "metric.npz"), world_to_camera=w2c, K=np.tile(K, (S, 1, 1)), depth=depth,
             instance=instance, camera_height_m=params.camera_height_m,
             world_from_vggt=_world_from_vggt(w2c, _metres_per_unit(depth, K, w2c)),
             metres_per_unit=_metres_per_unit(depth, K, w2c),
             **{f"world_to_camera_{k}": v for k, v in views.items() if k != "recorded"})
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(out_dir, "street.blend"), compress=True)
    info = {"generator_version": GENERATOR_VERSION, "params": {**params.__dict__, "shifts_m": list(params.shifts_m)},
            "views": list(views), "cars": scene_info["cars"], "blender": bpy.app.version_string,
            "timings_s": {"build": t_build - t0, "render": t_render - t_build,
                          "total": time.perf_counter() - t0, "renders": n_renders}}
    with open(os.path.join(out_dir, "street.json"), "w") as f:
        json.dump(info, f, indent=1)
    return info


def _metres_per_unit(depth, K, w2c) -> float:
    """VGGT's normalisation: the mean distance of all valid points from the first camera becomes 1."""
    hits = np.isfinite(depth)
    pts = []
    for i in range(len(depth)):
        rows, cols = np.nonzero(hits[i])
        pts.append(vggt.unproject_pixels(depth[i], K, w2c[i], rows, cols))
    P = np.concatenate(pts)
    c0 = cameras.camera_centers(w2c[0])
    return float(np.linalg.norm(P - c0, axis=1).mean())


def _world_from_vggt(w2c, metres_per_unit) -> np.ndarray:
    """VGGT world = first camera's OpenCV frame in VGGT units: x_world = c2w_0 (m x_vggt)."""
    M = cameras.rigid_inverse(w2c[0])
    M[:3, :3] *= metres_per_unit
    return M


def write_predictions(out_dir, params, images, depth, K, w2c):
    """The recorded drive in VGGT's layout: first camera at the origin, scale normalised, depth + confidence."""
    m = _metres_per_unit(depth, K, w2c)
    first = cameras.rigid_inverse(w2c[0])
    ext = w2c @ first  # camera i from the first camera's frame, still metric
    ext[0] = np.eye(4)  # exactly, not to rounding
    ext[:, :3, 3] /= m
    hit = np.isfinite(depth)
    far = float(depth[hit].max()) * 1.5 if hit.any() else 100.0
    d = np.where(hit, depth, far) / m
    # VGGT-like confidence (1 + exp(x) >= 1): high near, falling with distance, minimal on the sky
    conf = np.where(hit, 1.0 + 30.0 * np.exp(-np.where(hit, depth, 0) / 20.0), 1.0 + 1e-3).astype(np.float32)
    Kv = vggt.ours_K_to_vggt(np.tile(K, (len(depth), 1, 1)))
    wp = vggt.unproject_depth(d, np.tile(K, (len(depth), 1, 1)), ext).astype(np.float32)
    vggt.save_predictions(os.path.join(out_dir, "predictions.npz"), images, d, conf, ext, Kv, world_points=wp,
                          world_points_conf=conf)
