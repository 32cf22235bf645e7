"""Render the ground-truth drive with Cycles on the CPU and write the street folder (bpy).

Cameras are OpenCV (``core.geometry.cameras``); a pixel's depth and instance id come from a second, one-sample render
whose material override emits (camera z, object index) sampled at pixel centres (a 0.01 px box filter), so depth is
exact at (u + 0.5, v + 0.5) rather than an anti-aliased blend of foreground and background. Renders carry no
stamp (time, date), so reruns are byte-identical.

This module resets the running Blender session: run it in its own process (``python -m scpainter_blender.street``).
"""

from __future__ import annotations

import json
import os
import time

import bpy
import numpy as np
from mathutils import Matrix

from ..core.geometry import cameras, trajectory
from ..core import outputs
from .build import build_scene, recorded_path
from .dataset import GENERATOR_VERSION, StreetParams, view_name
from .materials import black_world, depth_override
from .predictions import write_drive


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
        views[view_name(shift)] = trajectory.shift_trajectory(w2c, left_m=shift)
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

    write_drive(out_dir, images, depth, instance, K, views, params.camera_height_m)
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(out_dir, "street.blend"), compress=True)
    info = {"generator_version": GENERATOR_VERSION, "params": {**params.__dict__, "shifts_m": list(params.shifts_m)},
            "views": list(views), "cars": scene_info["cars"], "blender": bpy.app.version_string,
            "timings_s": {"build": t_build - t0, "render": t_render - t_build,
                          "total": time.perf_counter() - t0, "renders": n_renders}}
    outputs.write_json(os.path.join(out_dir, "street.json"), info)
    return info
