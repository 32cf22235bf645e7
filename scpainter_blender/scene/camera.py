"""The recorded camera: a Blender camera animated per frame with its OpenCV pose and exact intrinsics.

Poses are keyed as location + quaternion (continuous signs), never Euler angles, so the path cannot flip between
frames. Intrinsics: lens and shifts are keyed per frame (CONSTANT) only when they vary; fx != fy becomes the
scene's pixel aspect, which is one value per scene, so a per-frame change of fx/fy is reported, not hidden.
"""

from __future__ import annotations

import bpy
import numpy as np

from ..core.geometry import cameras, trajectory
from . import compat, keys, kinds


def create_recorded_camera(name: str, world_to_camera, K, width: int, height: int, frame_start: int,
                           collection, sensor_width: float = 36.0, frames=None):
    """Camera object keyed at scene frames ``frames`` (S,) increasing (default: frame_start + i). Returns (object,
    settings of its first frame, warnings)."""
    T = cameras.as_matrix4(world_to_camera)
    K = np.asarray(K, np.float64)
    S = len(T)
    params = [cameras.blender_camera_from_K(K[i], width, height, sensor_width=sensor_width) for i in range(S)]
    warnings = []
    data = bpy.data.cameras.new(name)
    p0 = params[0]
    data.sensor_fit = p0.sensor_fit
    data.sensor_width, data.sensor_height = p0.sensor_width, p0.sensor_height
    data.lens, data.shift_x, data.shift_y = p0.lens, p0.shift_x, p0.shift_y
    data.clip_start, data.clip_end = 0.05, 10000.0
    obj = bpy.data.objects.new(name, data)
    collection.objects.link(obj)

    frames = frame_start + np.arange(S) if frames is None else np.asarray(frames, np.int64)
    lens = np.array([p.lens for p in params])
    shifts = np.array([[p.shift_x, p.shift_y] for p in params])
    if S > 1 and (np.ptp(lens) > 1e-9 * lens[0] or np.ptp(shifts, axis=0).max() > 1e-12):
        fc = compat.new_action_fcurves(data, f"{name} intrinsics")
        compat.key_fcurve(fc, "lens", 0, frames, lens, "CONSTANT")
        compat.key_fcurve(fc, "shift_x", 0, frames, shifts[:, 0], "CONSTANT")
        compat.key_fcurve(fc, "shift_y", 0, frames, shifts[:, 1], "CONSTANT")
    ratio = K[:, 0, 0] / K[:, 1, 1]
    if np.ptp(ratio) > 1e-9:
        err_px = float(np.max(np.abs(ratio / ratio[0] - 1.0)) * max(width, height) / 2)
        warnings.append(f"fx/fy varies across frames (up to {err_px:.3g} px at the image edge); the scene's "
                        "single pixel aspect uses frame 0")

    key_camera_path(obj, T, frames, f"{name} path")
    return obj, p0, warnings


def apply_render_settings(scene, cam: cameras.BlenderCamera):
    """Resolution, 100 % scale and pixel aspect that make ``cam`` reproduce its K."""
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = cam.resolution_x, cam.resolution_y, 100
    r.pixel_aspect_x, r.pixel_aspect_y = cam.pixel_aspect_x, cam.pixel_aspect_y


def render_size(scene) -> tuple:
    """(width, height) in pixels of the scene's whole frame: its resolution times its percentage, rounded down as
    Blender's render does (``BKE_render_resolution``: 23 px at 50 % is 11)."""
    r = scene.render
    return r.resolution_x * r.resolution_percentage // 100, r.resolution_y * r.resolution_percentage // 100


def render_region(scene) -> tuple:
    """(left, top, width, height) in pixels of the whole frame (rows down, DESIGN §3) of the image Blender's render
    writes: the render region when *Render Region* and *Crop to Render Region* are both on (its borders, fractions of
    the frame with y up, taken to whole pixels as Blender does: float32 products truncated, checked with Cycles),
    else the whole frame (a region without crop still writes a whole-frame image)."""
    W, H = render_size(scene)
    r = scene.render
    if not (r.use_border and r.use_crop_to_border):
        return 0, 0, W, H
    # Blender multiplies in float32 (0.9 · 60 is 54 there, 53.99… in float64) and truncates; y counts from the bottom
    x0, x1, y0, y1 = (int(np.float32(b) * np.float32(n)) for b, n in
                      ((r.border_min_x, W), (r.border_max_x, W), (r.border_min_y, H), (r.border_max_y, H)))
    return x0, H - y1, x1 - x0, y1 - y0


def output_size(scene) -> tuple:
    """(width, height) of the image the scene renders: ``render_region``'s."""
    return render_region(scene)[2:]


def K_of_camera_object(scene, cam_obj) -> np.ndarray:
    """Our K for a Blender camera object with the scene's render settings (at the current frame), for the image the
    render writes: the whole frame's K with the principal point moved by the cropped region's corner
    (``render_region``)."""
    d, r = cam_obj.data, scene.render
    W, H = render_size(scene)
    K = cameras.K_from_blender_camera(cameras.BlenderCamera(
        lens=d.lens, sensor_width=d.sensor_width, sensor_height=d.sensor_height, sensor_fit=d.sensor_fit,
        shift_x=d.shift_x, shift_y=d.shift_y, resolution_x=W, resolution_y=H,
        pixel_aspect_x=r.pixel_aspect_x, pixel_aspect_y=r.pixel_aspect_y))
    left, top = render_region(scene)[:2]
    K = np.array(K, dtype=np.float64)
    K[0, 2] -= left
    K[1, 2] -= top
    return K


def world_to_camera(cam_obj) -> np.ndarray:
    """OpenCV world_to_camera (4, 4) of a camera object as the scene is evaluated now (its matrix_world)."""
    M = np.array(cam_obj.matrix_world, dtype=np.float64)
    M[:3, :3] /= np.linalg.norm(M[:3, :3], axis=0)  # a scaled camera object still sees the same rays
    return cameras.world_to_camera_from_blender(M)


def world_to_camera_per_frame(scene, cam_obj, frames) -> np.ndarray:
    """OpenCV world_to_camera (S, 4, 4) of a camera object at each frame, whatever drives it (keys, drivers,
    constraints, parents): the scene is evaluated frame by frame; the current frame is restored after."""
    current = scene.frame_current
    out = np.empty((len(frames), 4, 4))
    try:
        for i, f in enumerate(frames):
            scene.frame_set(int(f))
            out[i] = world_to_camera(cam_obj)
    finally:
        scene.frame_set(current)
    return out


def key_camera_path(cam_obj, world_to_camera, frames, action_name: str):
    """Key location + continuous quaternions of ``cam_obj`` at ``frames`` from OpenCV world_to_camera (S, 4, 4)."""
    M = cameras.blender_matrix_world(world_to_camera)
    quat = cameras.continuous_quaternions(cameras.rotation_to_quaternion(M[:, :3, :3]))
    cam_obj.rotation_mode = "QUATERNION"
    cam_obj.location = M[0, :3, 3].tolist()
    cam_obj.rotation_quaternion = quat[0].tolist()
    fc = compat.new_action_fcurves(cam_obj, action_name)
    for i in range(3):
        compat.key_fcurve(fc, "location", i, frames, M[:, i, 3])
    for i in range(4):
        compat.key_fcurve(fc, "rotation_quaternion", i, frames, quat[:, i])


def shift_label(shift_m: float) -> str:
    return f"{abs(shift_m):g} m {'left' if shift_m > 0 else 'right'}" if shift_m else "recorded"


def create_camera_path(context, source, shift_m: float, name: str | None = None):
    """A new camera following ``source`` (the recorded camera) shifted sideways, keyed at every scene frame.

    ``shift_m`` > 0 moves left of the direction of travel, < 0 right (docs/design.md §3 heading). The camera data is a
    copy of the source's (same lens, sensor and shift keys), the new object becomes the scene's active camera.
    """
    scene = context.scene
    frames = np.arange(scene.frame_start, scene.frame_end + 1)
    w2c = world_to_camera_per_frame(scene, source, frames)
    shifted = trajectory.shift_trajectory(w2c, left_m=shift_m)
    name = name or f"Camera path {shift_label(shift_m)}"
    obj = bpy.data.objects.new(name, source.data.copy())
    for coll in source.users_collection:
        coll.objects.link(obj)
    key_camera_path(obj, shifted, frames, f"{name} path")
    kinds.mark(obj, kinds.CAMERA_PATH)
    obj[keys.SHIFT_M] = float(shift_m)
    obj[keys.SOURCE_CAMERA] = source.name
    scene.camera = obj
    return obj
