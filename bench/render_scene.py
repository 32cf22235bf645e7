"""A synthetic street for the renderer's benchmarks, in numpy alone (no Blender, runs on the device machine too).

World (docs/design.md §3): metres, Z up, the road along +Y. A box street: road plane z = 0 with lane marks, building
fronts at x = ±12 m, a far wall at y = 140 m standing in for the sky. The source cameras drive along the middle
lane (x = 0, 1.6 m high, 1 m apart) at 518 x 294 pixels, fx = 300, as the ground-truth street; their pixels
are ray-cast against the boxes to give a VGGT-like cloud (one point per source pixel, textured colours). The
car is the procedural Gaussian car, parked in the right lane 12 m ahead of the output camera.

Also a timing worker, so that bench/render.py can time another source tree (an older revision) with the same code
on the same inputs:

    python bench/render_scene.py --worker --tree DIR --data scene.npz [--threads 2] [--unset-wait-policy]

imports ``backend`` from DIR (first, before torch: a tree's own OMP_WAIT_POLICY default applies, unless
``--unset-wait-policy`` removes it again to see OpenMP's own default), builds the scene from the arrays of
``scene_arrays`` saved in scene.npz, then answers one JSON request per line on standard input with one JSON line on
standard output (``worker_request``; ``{"cmd": "load", "data": other.npz}`` swaps the scene, ``{"cmd": "quit"}``
ends). Nothing at this module's top level imports torch or the backend.
"""

from __future__ import annotations

import json
import os
import sys
import time

import numpy as np

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
    from scpainter_blender.core import shapes

    return shapes.procedural_car_gaussians(count=n, seed=seed, paint=(0.7, 0.1, 0.1))


#: The variation benches' library: (file stem, seed, paint) of each procedural car
LIBRARY_CARS = (("blue", 7, (0.1, 0.3, 0.8)), ("red", 8, (0.8, 0.1, 0.1)))


def car_library(folder: str, count: int) -> str:
    """``folder`` holding ``LIBRARY_CARS`` as Amodal3R PLYs of ``count`` Gaussians each (kept when already there);
    returns ``folder``."""
    from scpainter_blender.core import shapes

    os.makedirs(folder, exist_ok=True)
    for name, seed, paint in LIBRARY_CARS:
        path = os.path.join(folder, f"{name}.ply")
        if not os.path.isfile(path):
            shapes.save_as_amodal3r(path, shapes.procedural_car_gaussians(count=count, seed=seed, paint=paint))
    return folder


#: Where the cars of ``scene_arrays(..., cars=n)`` stand, relative to (0, car_distance): the first in the right
#: lane; the second 7 m behind it and 1 m further left (half hidden by the first); the third in the left lane.
CAR_OFFSETS = ((3.5, 0.0), (2.5, 7.0), (-3.5, -3.0))


def scene_arrays(n_points: int, n_gaussians: int, width: int = 1024, height: int = 576, seed: int = 0,
                 car_distance: float = 12.0, cars: int = 1) -> dict:
    """The benchmark scene as plain arrays (an .npz holds them without pickles): ``xyz`` (P, 3) float32 relative to
    ``origin``, ``rgb`` (P, 3) float32, ``frame`` (P,) int64, the car's Gaussians ``g_means`` ``g_scales``
    ``g_quats`` ``g_opacities`` ``g_sh`` in its own frame with ``object_to_world`` (4, 4), and the output frame
    ``K``, ``world_to_camera`` (frame 0, camera at the start of the drive, the car ``car_distance`` m ahead in the
    right lane), ``source_frames`` and ``size`` (width, height). ``n_points`` are drawn from the source cloud.
    With ``cars`` > 1 (at most 3, ``CAR_OFFSETS``) the ``n_gaussians`` are split between that many cars (seeds
    seed, seed + 1, ...), concatenated, ``g_car`` (N,) the car of each row and ``object_to_world`` (cars, 4, 4)."""
    rng = np.random.default_rng(seed)
    frames = max(1, int(np.ceil(n_points / (SRC_W * SRC_H))))
    xyz, rgb, frame = source_cloud(frames)
    pick = np.sort(rng.choice(len(xyz), size=n_points, replace=False)) if n_points < len(xyz) else slice(None)
    xyz, rgb, frame = xyz[pick], rgb[pick], frame[pick]
    origin = np.array([0.0, 0.0, 1.6])
    out = {"origin": origin, "xyz": (xyz - origin).astype(np.float32), "rgb": rgb, "frame": frame,
           "K": intrinsics(width, height), "world_to_camera": world_to_camera(0.0, 0.0),
           "source_frames": np.arange(frames, dtype=np.int64), "size": np.array([width, height])}
    if n_gaussians and cars == 1:
        g = car_gaussians(n_gaussians, seed)
        A = np.eye(4)
        A[:3, 3] = (3.5, car_distance, 0.0)
        out.update(g_means=g.means, g_scales=g.scales, g_quats=g.quats, g_opacities=g.opacities, g_sh=g.sh,
                   object_to_world=A)
    elif n_gaussians:
        gs = [car_gaussians(n_gaussians // cars, seed + c) for c in range(cars)]
        A = np.tile(np.eye(4), (cars, 1, 1))
        for c in range(cars):
            A[c, :3, 3] = (CAR_OFFSETS[c][0], car_distance + CAR_OFFSETS[c][1], 0.0)
        out.update({f"g_{k}": np.concatenate([getattr(g, k) for g in gs])
                    for k in ("means", "scales", "quats", "opacities", "sh")})
        out.update(g_car=np.repeat(np.arange(cars), [len(g.means) for g in gs]), object_to_world=A)
    return out


def scene_from_arrays(a: dict, device="cpu"):
    """(Scene, Frame) as the render command holds them, from ``scene_arrays``' arrays, with whichever ``backend``
    and ``scpainter_blender`` are first on sys.path (this tree's, or the tree a worker times)."""
    import torch

    from backend.render import frames as fr
    from scpainter_blender.core import job as job_mod
    from scpainter_blender.core.splats import gaussians as splats

    dev = torch.device(device)
    scene = fr.Scene(origin=np.asarray(a["origin"], np.float64), device=dev)
    if len(a["xyz"]):
        scene.xyz = torch.as_tensor(np.asarray(a["xyz"], np.float32), device=dev)
        scene.rgb = torch.as_tensor(np.asarray(a["rgb"]), device=dev)
        scene.frame = torch.as_tensor(np.asarray(a["frame"], np.int64), device=dev)
        scene.frames_present = frozenset(np.unique(a["frame"]).tolist())
    if "g_means" in a:
        A = np.asarray(a["object_to_world"], np.float64).reshape(-1, 4, 4)
        car = np.asarray(a["g_car"]) if "g_car" in a else np.zeros(len(a["g_means"]), np.int64)
        for c in range(len(A)):
            g = splats.Gaussians(means=a["g_means"][car == c], scales=a["g_scales"][car == c],
                                 quats=a["g_quats"][car == c], opacities=a["g_opacities"][car == c],
                                 sh=a["g_sh"][car == c])
            scene.assets.append(fr.make_asset(f"car{c}" if c else "car", g, {0: A[c]}, dev))
    entry = job_mod.Frame(frame=0, K=np.asarray(a["K"], np.float64),
                          world_to_camera=np.asarray(a["world_to_camera"], np.float64),
                          source_frames=[int(f) for f in a["source_frames"]])
    return scene, entry


def build(n_points: int, n_gaussians: int, width: int = 1024, height: int = 576, device="cpu", seed: int = 0,
          car_distance: float = 12.0):
    """The benchmark scene as the render command holds it, and one output frame entry (``scene_arrays``)."""
    return scene_from_arrays(scene_arrays(n_points, n_gaussians, width, height, seed, car_distance), device)


# -- the timing worker ------------------------------------------------------------------------------------------

class Passes:
    """The frame and its two passes as ``frames.render_frame`` runs them, for one scene and frame, written against
    the API both trees share (render_frame, points.render_points, gaussians.project_factors and pixel_boxes,
    tiles.rasterize)."""

    def __init__(self, scene, entry, width, height):
        import inspect

        import torch

        from backend.render import frames as fr
        from backend.render import gaussians as gs
        from backend.render import points as pts
        from backend.render import tiles

        self.torch, self.fr, self.gs, self.pts, self.tiles = torch, fr, gs, pts, tiles
        self.scene, self.entry, self.W, self.H = scene, entry, width, height
        self.K = np.asarray(entry.K, np.float64)
        self.w2c = pts.relative_camera(np.asarray(entry.world_to_camera, np.float64), scene.origin)
        # a tree whose render_frame still has a Gaussian cutoff: its reference at 4 σ is the render without one
        self.cutoff = {"cutoff": 4.0} if "cutoff" in inspect.signature(fr.render_frame).parameters else {}
        self.depth = self.points()[1]  # the Gaussian pass stops at the points, as in a frame

    def frame(self):
        return self.fr.render_frame(self.scene, self.entry, self.W, self.H, to_numpy=False)

    def reference_frame(self):
        return self.fr.render_frame(self.scene, self.entry, self.W, self.H, reference=True, **self.cutoff)

    def points(self):
        return self.pts.render_points(self.scene.xyz, self.scene.rgb, self.K, self.w2c, self.W, self.H)

    def projection(self):
        """Every asset's Gaussians projected together, as render_frame does; with ``asset_id`` where the tree has
        an instance pass (``gaussians.asset_ids``)."""
        torch = self.torch
        means, factors, ids = [], [], []
        for i, a in enumerate(self.scene.assets):
            A = np.array(a.object_to_world[self.entry.frame], np.float64)
            A[:3, 3] -= self.scene.origin
            At = torch.as_tensor(A, dtype=torch.float64, device=self.scene.device)
            means.append(a.means @ At[:3, :3].T + At[:3, 3])
            factors.append(At[:3, :3] @ a.factors)
            ids.append(torch.full((len(a.means),), i + 1, dtype=torch.int64))
        assets = self.scene.assets
        proj = self.gs.project_factors(torch.cat(means), torch.cat(factors), torch.cat([a.opacities for a in assets]),
                                       torch.cat([a.sh for a in assets]), self.K, self.w2c, self.W, self.H)
        if hasattr(self.gs, "asset_ids"):
            proj["asset_id"] = torch.cat(ids)[proj["index"]]
        return proj

    def amodal(self):
        """``frames.amodal_pixels`` (trees that have it; else None) as ``render`` runs it: on the frame's own
        projection (made once, outside the timing: the frame paid for it)."""
        if not hasattr(self.fr, "amodal_pixels"):
            return None
        if not hasattr(self, "_frame_projection"):
            self._frame_projection = self.projection()
        return self.fr.amodal_pixels(self.scene, self.entry, self.W, self.H, projection=self._frame_projection)

    def gaussians(self):
        return self.tiles.rasterize(self.projection(), self.W, self.H, background_depth=self.depth)

    def pairs(self):
        """Pixel–Gaussian pairs: the pixels in each projected Gaussian's box, summed."""
        b = self.gs.pixel_boxes(self.projection(), self.W, self.H)
        return int(((b[:, 1] - b[:, 0] + 1).clamp_min(0) * (b[:, 3] - b[:, 2] + 1).clamp_min(0)).sum()), len(b)


def timed_ms(fn, repeat, warmup):
    """Wall time of fn() in ms, each of ``repeat`` calls after ``warmup`` untimed ones (CPU: nothing to sync)."""
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(1e3 * (time.perf_counter() - t))
    return out


def worker_request(passes: Passes, req: dict) -> dict:
    """One request: {"cmd": "time", "task": "frame" | "points" | "gaussians" | "amodal", "repeat", "warmup"} ->
    {"ms": [...]} ("amodal": ``frames.amodal_pixels``, [] in a tree without it);
    {"cmd": "pairs"} -> {"pairs", "gaussians"}; {"cmd": "dump", "path", "reference": bool} writes the frame's
    layers (``layer_<name>``), the point pass (``points_rgb``, ``points_depth``, ``points_winner``) and with
    ``reference`` the float64 pair rasterizer's frame (``reference_<name>``) to an .npz -> {"path"}."""
    cmd = req["cmd"]
    if cmd == "time":
        if req["task"] == "amodal" and passes.amodal() is None:
            return {"ms": []}
        fn = {"frame": passes.frame, "points": passes.points, "gaussians": passes.gaussians,
              "amodal": passes.amodal}[req["task"]]
        return {"ms": timed_ms(fn, int(req.get("repeat", 3)), int(req.get("warmup", 1)))}
    if cmd == "pairs":
        pairs, g = passes.pairs()
        return {"pairs": pairs, "gaussians": g}
    if cmd == "dump":
        out = {f"layer_{k}": v.cpu().numpy() for k, v in passes.frame().items()}
        out.update(zip(("points_rgb", "points_depth", "points_winner"), (t.cpu().numpy() for t in passes.points())))
        if req.get("reference"):
            out.update({f"reference_{k}": v for k, v in passes.reference_frame().items()})
        np.savez(req["path"], **out)
        return {"path": req["path"]}
    raise ValueError(f"unknown request {cmd!r}")


def load_passes(path) -> Passes:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    scene, entry = scene_from_arrays(arrays)
    return Passes(scene, entry, int(arrays["size"][0]), int(arrays["size"][1]))


def worker_main(argv) -> int:
    import argparse

    p = argparse.ArgumentParser()
    p.add_argument("--worker", action="store_true")
    p.add_argument("--tree", required=True)
    p.add_argument("--data", required=True)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--unset-wait-policy", action="store_true")
    args = p.parse_args(argv)
    # standard output is the reply channel: anything else printed (by Python or C code) goes to standard error
    reply = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    here = os.path.dirname(os.path.abspath(__file__))
    sys.path[:] = [os.path.abspath(args.tree)] + [q for q in sys.path if os.path.abspath(q or ".") != here]
    import backend  # noqa: F401  (the tree's own package first, as python -m backend imports it)

    if args.unset_wait_policy:
        os.environ.pop("OMP_WAIT_POLICY", None)
    policy = os.environ.get("OMP_WAIT_POLICY")  # read before torch and numba load their OpenMP runtimes
    import numba
    import torch

    torch.set_num_threads(args.threads)
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    passes = load_passes(args.data)
    hello = {"ready": True, "tree": os.path.abspath(backend.__file__), "wait_policy": policy,
             "threading_layer": numba.threading_layer(), "torch_threads": torch.get_num_threads()}
    reply.write(json.dumps(hello) + "\n")
    reply.flush()
    for line in sys.stdin:
        req = json.loads(line)
        if req.get("cmd") == "quit":
            break
        if req.get("cmd") == "load":  # another scene in place of this one
            passes = None
            passes = load_passes(req["data"])
            answer = {"loaded": req["data"]}
        else:
            answer = worker_request(passes, req)
        reply.write(json.dumps(answer) + "\n")
        reply.flush()
    return 0


if __name__ == "__main__":
    sys.exit(worker_main(sys.argv[1:]))
