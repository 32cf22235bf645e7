"""A scene of known geometry for the LiDAR's tests and bench (``bench/lidar.py``): a square of ground (z = 0) and a
car-sized box standing on it, turned about z, both sampled as points; and the analytic ray cast it is held to.

The ground's samples are denser near the sensor (their distance from the sensor's foot has density ∝ 1 / r³), so a
footprint holds about as many of them near and far; the box's faces are sampled uniformly. Nothing of the ground
lies under the box.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: The sensor's height above the ground (nuScenes' LIDAR_TOP: 1.84 m).
HEIGHT = 1.84


@dataclass
class PlaneBox:
    half_side: float = 30.0                     # the ground square: |x|, |y| <= half_side (world, metres)
    box_centre: tuple = (3.0, 9.0)               # the box's centre on the ground (x, y)
    box_size: tuple = (1.8, 4.5, 1.5)            # (w, l, h) metres
    box_yaw_deg: float = 25.0                    # the box's turn about z
    sensor: tuple = (0.0, 0.0, HEIGHT)
    box_to_world: np.ndarray = field(init=False)

    def __post_init__(self):
        c, s = np.cos(np.deg2rad(self.box_yaw_deg)), np.sin(np.deg2rad(self.box_yaw_deg))
        T = np.eye(4)
        T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
        T[:3, 3] = (*self.box_centre, self.box_size[2] / 2)
        self.box_to_world = T

    def lidar_to_world(self, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
        T = np.eye(4)
        T[:3, 3] = np.asarray(self.sensor) + np.asarray(offset)
        return T

    def sample(self, ground_points: int, box_density: float, seed: int = 0) -> tuple:
        """(points (N, 3) float64 world, colours (N, 3) float32): the ground (grey 0.4) then the box (0.8)."""
        rng = np.random.default_rng(seed)
        r0, r1 = 2.0, self.half_side * np.sqrt(2)
        # density ∝ 1/r³ on the plane: r has pdf ∝ 1/r², i.e. 1/r uniform
        r = 1.0 / rng.uniform(1.0 / r1, 1.0 / r0, ground_points)
        a = rng.uniform(0, 2 * np.pi, ground_points)
        g = np.stack([self.sensor[0] + r * np.cos(a), self.sensor[1] + r * np.sin(a), np.zeros_like(r)], 1)
        g = g[(np.abs(g[:, 0]) <= self.half_side) & (np.abs(g[:, 1]) <= self.half_side)]
        local = (g - self.box_to_world[:3, 3]) @ self.box_to_world[:3, :3]
        g = g[~np.all(np.abs(local[:, :2]) <= np.asarray(self.box_size[:2]) / 2, axis=1)]
        w, l, h = self.box_size
        faces = []  # (centre, axis1 * half-extent, axis2 * half-extent) in the box frame; no bottom face
        faces.append(((0, 0, h / 2), (w / 2, 0, 0), (0, l / 2, 0)))
        for sx in (-1, 1):
            faces.append(((sx * w / 2, 0, 0), (0, l / 2, 0), (0, 0, h / 2)))
        for sy in (-1, 1):
            faces.append(((0, sy * l / 2, 0), (w / 2, 0, 0), (0, 0, h / 2)))
        parts = []
        for c, e1, e2 in faces:
            area = 4 * np.linalg.norm(e1) * np.linalg.norm(e2)
            n = rng.poisson(box_density * area)
            st = rng.uniform(-1, 1, (n, 2))
            parts.append(np.asarray(c) + st[:, :1] * np.asarray(e1) + st[:, 1:] * np.asarray(e2))
        b = np.concatenate(parts) @ self.box_to_world[:3, :3].T + self.box_to_world[:3, 3]
        pts = np.concatenate([g, b])
        rgb = np.concatenate([np.full((len(g), 3), 0.4), np.full((len(b), 3), 0.8)]).astype(np.float32)
        return pts, rgb

    def cast(self, origin: np.ndarray, dirs: np.ndarray) -> tuple:
        """Analytic first hits of rays from ``origin`` (3,) world along ``dirs`` (..., 3) world unit vectors:
        (range (...,) float64, inf = none; surface (...,) int: -1 none, 0 ground, 1 the box)."""
        o = np.asarray(origin, np.float64)
        d = np.asarray(dirs, np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            tg = np.where(d[..., 2] < 0, -o[2] / d[..., 2], np.inf)
            p = o + tg[..., None] * d
        tg = np.where((np.abs(p[..., 0]) <= self.half_side) & (np.abs(p[..., 1]) <= self.half_side), tg, np.inf)
        # slabs in the box frame
        R, c = self.box_to_world[:3, :3], self.box_to_world[:3, 3]
        ol, dl = (o - c) @ R, d @ R
        half = np.asarray(self.box_size) / 2
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - ol) / dl, (half - ol) / dl
        tnear = np.nanmax(np.minimum(t1, t2), -1)
        tfar = np.nanmin(np.maximum(t1, t2), -1)
        tb = np.where((tnear <= tfar) & (tnear > 0), tnear, np.inf)
        rng = np.minimum(tg, tb)
        surface = np.where(np.isinf(rng), -1, np.where(tb <= tg, 1, 0))
        return rng, surface

    def face(self, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """(...,) int: which surface a ray meets first, the box's faces told apart (-1 none, 0 ground, 1.. box
        faces by the axis and side of the hit's box-frame coordinate nearest its face)."""
        rng, surface = self.cast(origin, dirs)
        p = np.asarray(origin) + np.where(np.isinf(rng), 0, rng)[..., None] * np.asarray(dirs)
        local = (p - self.box_to_world[:3, 3]) @ self.box_to_world[:3, :3]
        rel = np.abs(local) / (np.asarray(self.box_size) / 2)
        axis = np.argmax(rel, -1)
        side = np.take_along_axis(local, axis[..., None], -1)[..., 0] > 0
        return np.where(surface == 1, 1 + 2 * axis + side, surface)


def edge_clearance(scene: PlaneBox, origin: np.ndarray, d0: np.ndarray, e1: np.ndarray, e2: np.ndarray,
                   radius_rad: float, samples: int = 12) -> np.ndarray:
    """(...,) bool: the rays d0 whose neighbours at ``radius_rad`` (``samples`` of them around a circle, and half
    that radius) all meet the same surface (face) as the ray: at least that far from any edge."""
    here = scene.face(origin, d0)
    ok = np.ones(here.shape, bool)
    for k in range(samples):
        a = 2 * np.pi * k / samples
        for f in (0.5, 1.0):
            dd = d0 + np.tan(radius_rad * f) * (np.cos(a) * e1 + np.sin(a) * e2)
            dd /= np.linalg.norm(dd, axis=-1, keepdims=True)
            ok &= scene.face(origin, dd) == here
    return ok
