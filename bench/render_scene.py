"""A synthetic street for the renderer's benchmarks, in numpy alone (no Blender, runs on the device machine too).

World (docs/design.md §3): metres, Z up, the road along +Y. A box street: road plane z = 0 with lane marks, building
fronts at x = ±12 m, a far wall at y = 140 m standing in for the sky. The source cameras drive along the middle
lane (x = 0, 1.6 m high, 1 m apart) at 518 x 294 pixels, fx = 300, as the ground-truth street; their pixels
are ray-cast against the boxes to give a VGGT-like cloud (one point per source pixel, textured colours). The
car is the procedural Gaussian car, parked in the right lane 12 m ahead of the output camera.
"""

from __future__ import annotations

import numpy as np
import torch

from backend.render import frames as fr
from scpainter_blender.core import job as job_mod
from scpainter_blender.core import shapes

SRC_W, SRC_H, SRC_F = 518, 294, 300.0


def camera_to_world_rotation() -> np.ndarray:
    """OpenCV camera axes in the world: x right = +X, y down = -Z, z forward = +Y."""
    return np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def world_to_camera(x: float, y: float, z: float = 1.6) -> np.ndarray:
    w2c = np.eye(4)
    R = camera_to_world_rotation().T
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ np.array([x, y, z])
    return w2c


def intrinsics(width: int, height: int, fov_x_deg: float = 80.0) -> np.ndarray:
    f = 0.5 * width / np.tan(np.radians(fov_x_deg) / 2)
    return np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def _texture(p: np.ndarray, which: np.ndarray) -> np.ndarray:
    x, y, z = p.T
    rgb = np.empty_like(p)
    road = which == 0
    lane = (np.abs(np.abs(x) - 1.75) < 0.07) & ((y % 6.0) < 3.0)
    rgb[road] = 0.25 + 0.03 * np.sin(7.1 * x[road, None] + 3.3 * y[road, None])
    rgb[road & lane] = 0.9
    wall = which == 1
    window = ((z % 3.0) > 1.0) & ((z % 3.0) < 2.2) & ((y % 4.0) > 1.0) & ((y % 4.0) < 3.0)
    rgb[wall] = np.array([0.6, 0.45, 0.35]) + 0.05 * np.sin(y[wall, None])
    rgb[wall & window] = np.array([0.15, 0.2, 0.3])
    sky = which == 2
    rgb[sky] = np.array([0.5, 0.7, 0.95]) - 0.004 * z[sky, None]
    return np.clip(rgb, 0.0, 1.0)


def source_cloud(frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions (P, 3) float64 world, colours (P, 3) float32, frame (P,) int64): one point per source pixel."""
    v, u = np.mgrid[0:SRC_H, 0:SRC_W] + 0.5
    d_cam = np.stack([(u - SRC_W / 2) / SRC_F, (v - SRC_H / 2) / SRC_F, np.ones_like(u)], -1).reshape(-1, 3)
    d = d_cam @ camera_to_world_rotation().T
    out_p, out_c, out_f = [], [], []
    for f in range(frames):
        c = np.array([0.0, float(f), 1.6])
        t_road = np.where(d[:, 2] < 0, -c[2] / np.where(d[:, 2] < 0, d[:, 2], -1.0), np.inf)
        t_wall = np.where(d[:, 0] != 0, (np.sign(d[:, 0]) * 12.0 - c[0]) / np.where(d[:, 0] != 0, d[:, 0], 1.0),
                          np.inf)
        t_far = (c[1] + 140.0 - c[1]) / d[:, 1]
        t = np.stack([t_road, t_wall, t_far], 1)
        which = np.argmin(t, 1)
        p = c + t[np.arange(len(t)), which, None] * d
        out_p.append(p)
        out_c.append(_texture(p, which).astype(np.float32))
        out_f.append(np.full(len(p), f, np.int64))
    return np.concatenate(out_p), np.concatenate(out_c), np.concatenate(out_f)


def car_gaussians(n: int, seed: int = 0):
    """The procedural car (metres, on z = 0, front towards +Y), red."""
    return shapes.procedural_car_gaussians(count=n, seed=seed, paint=(0.7, 0.1, 0.1))


def build(n_points: int, n_gaussians: int, width: int = 1024, height: int = 576, device="cpu", seed: int = 0,
          car_distance: float = 12.0) -> tuple[fr.Scene, dict]:
    """The benchmark scene as the render command holds it, and one output frame entry (frame 0, camera at the
    start of the drive, the car ``car_distance`` m ahead in the right lane). ``n_points`` are drawn from the
    source cloud."""
    rng = np.random.default_rng(seed)
    frames = max(1, int(np.ceil(n_points / (SRC_W * SRC_H))))
    xyz, rgb, frame = source_cloud(frames)
    pick = np.sort(rng.choice(len(xyz), size=n_points, replace=False)) if n_points < len(xyz) else slice(None)
    xyz, rgb, frame = xyz[pick], rgb[pick], frame[pick]
    origin = np.array([0.0, 0.0, 1.6])
    dev = torch.device(device)
    scene = fr.Scene(origin=origin, device=dev)
    if n_points:
        scene.xyz = torch.as_tensor((xyz - origin).astype(np.float32), device=dev)
        scene.rgb = torch.as_tensor(rgb, device=dev)
        scene.frame = torch.as_tensor(frame, device=dev)
        scene.frames_present = frozenset(np.unique(frame).tolist())
    if n_gaussians:
        A = np.eye(4)
        A[:3, 3] = (3.5, car_distance, 0.0)
        scene.assets.append(fr.make_asset("car", car_gaussians(n_gaussians, seed), {0: A}, dev))
    entry = job_mod.Frame(0, intrinsics(width, height), world_to_camera(0.0, 0.0), list(range(frames)))
    return scene, entry
