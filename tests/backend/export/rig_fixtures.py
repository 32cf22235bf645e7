"""A small rendered rig job for the nuScenes export's tests, no renderer needed: nuScenes' six cameras and LIDAR_TOP
(``core.rig.preset("nuscenes")`` scaled to 1/20: 80 x 45 px) on an ego driving 5 m/s along a heading of 10°, six
frames at 10 fps (keyframes 0 and 5 at 2 Hz, sweeps between); two inserted cars (one driving 3 m/s ahead, one
parked front left), a recorded van following behind and a recorded car marked ignore.

The output folder is the contract's rig layout: ``<out>/<CAMERA>/conditions/labels_NNNNNN.json`` and previews per
camera (each camera's labels made by ``core.labels.frame_labels`` as a single-camera job with
``Job.camera_jobs()``, from layers ray-cast against the boxes: ``layers``), and
``<out>/LIDAR_TOP/sweep_NNNNNN.pcd.bin``. The sweeps here are lattices whose counts are known exactly
(``write_sweep``: a 4 x 4 x 4 lattice inside every box and a ground grid, in the sensor frame); the simulated sweeps
``render`` writes are read end to end by ``test_nuscenes.py``'s command-line test.
"""

import os

import numpy as np

from backend import png
from scpainter_blender.core import job as job_mod
from scpainter_blender.core import labels, outputs
from scpainter_blender.core import rig as rig_mod
from scpainter_blender.core.output_layout import OutputLayout

RIG = rig_mod.preset("nuscenes", scale=0.05)
FRAMES = tuple(range(10, 16))
FPS = 10.0
EGO_SPEED, HEADING = 5.0, np.radians(10.0)
CAR = (np.eye(4), np.array([1.8, 4.2, 1.5]))      # box_to_file (the file's origin under the box), size w l h
CAR[0][2, 3] = 0.75
LATTICE = 4                                       # points per box axis in the stand-in sweep: 64 per box


def _yaw(theta: float, x: float, y: float, z: float = 0.0) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    M = np.eye(4)
    M[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    M[:3, 3] = [x, y, z]
    return M


def ego_to_world(i: int) -> np.ndarray:
    d = EGO_SPEED * i / FPS
    return _yaw(HEADING, 3.0 + d * np.cos(HEADING), -2.0 + d * np.sin(HEADING))


def _in_ego0(x: float, y: float, i: int, speed: float) -> tuple:
    """World (x, y) of a point at ego-frame (x, y) of frame 0 moved ``speed`` m/s along the heading for i frames."""
    p = ego_to_world(0) @ [x + speed * i / FPS, y, 0.0, 1.0]
    return p[0], p[1]


def box_frame(x: float, y: float, heading: float, lift: float = 0.0) -> np.ndarray:
    """box_to_world (box frame: x across the width, y along the length, +y the front) of a box whose front points
    along ``heading``, at (x, y), its centre ``lift`` above the ground."""
    return _yaw(heading - np.pi / 2, x, y, lift)


#: name -> (ego-frame x, y at frame 0, speed m/s along the heading)
INSERTED = {"car_a": (12.0, -1.5, 3.0), "car_b": (7.0, 5.5, 0.0)}
VAN = (-9.0, 0.5, EGO_SPEED, np.array([2.0, 5.0, 2.2]))
IGNORED = (-4.0, -7.0, 0.0, np.array([1.8, 4.2, 1.5]))


def world_boxes(i: int) -> list:
    """(name, box_to_world, size w l h, asset index or None, ignore) of every object at frame i."""
    out = []
    for a, (name, (x, y, v)) in enumerate(INSERTED.items()):
        out.append((name, box_frame(*_in_ego0(x, y, i, v), HEADING, 0.75), CAR[1], a, False))
    for name, (x, y, v, size), ignore in (("rec_van", VAN, False), ("rec_ignored", IGNORED, True)):
        out.append((name, box_frame(*_in_ego0(x, y, i, v), HEADING, size[2] / 2), size, None, ignore))
    return out


def rig_job() -> job_mod.Job:
    """The rig job (``core.job``'s rig form: ``rig``, frames with ``ego_to_world``); its assets placed by their file
    frame, the recorded objects by their boxes."""
    frames = [job_mod.Frame(f, None, None, [], ego_to_world=ego_to_world(i)) for i, f in enumerate(FRAMES)]
    file_to_box = np.linalg.inv(CAR[0])
    assets = [job_mod.Asset(name, "car.ply", {f: world_boxes(i)[a][1] @ file_to_box for i, f in enumerate(FRAMES)},
                            box=job_mod.AssetBox(*CAR)) for a, name in enumerate(INSERTED)]
    recorded = [job_mod.RecordedObject(name, size, {f: world_boxes(i)[k][1] for i, f in enumerate(FRAMES)},
                                       "van" if name == "rec_van" else "car", ignore=ignore)
                for k, (name, _, size, a, ignore) in enumerate(world_boxes(0)) if a is None]
    scene = job_mod.Scene("predictions.npz", np.eye(4), recorded_objects=recorded)
    return job_mod.Job(None, frames, "out", scene, assets, fps=FPS, rig=RIG)


def layers(cam: rig_mod.RigCamera, i: int) -> dict:
    """The frame's layers as a renderer of solid boxes gives them: each pixel centre's ray against every box;
    ``depth`` the nearest hit's Z (inf: none), ``instance`` the asset id of the nearest hit (0: none or a recorded
    object), ``amodal_pixels`` per asset the pixels its box covers alone."""
    W, H = cam.resolution
    c2w = rig_mod.camera_to_world(ego_to_world(i), cam.camera_to_ego)
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    d_cam = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(cam.K).T           # (H, W, 3), z = 1
    depth = np.full((H, W), np.inf)
    instance = np.zeros((H, W), np.float32)
    amodal = [0] * len(INSERTED)
    for _, T, size, a, _ in world_boxes(i):
        C = np.linalg.inv(T) @ c2w
        o, d = C[:3, 3], d_cam @ C[:3, :3].T
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-size / 2 - o) / d, (size / 2 - o) / d
        entry = np.nanmax(np.minimum(t1, t2), axis=-1)
        leave = np.nanmin(np.maximum(t1, t2), axis=-1)
        hit = (leave >= np.maximum(entry, labels.NEAR))
        z = np.where(hit, np.maximum(entry, labels.NEAR), np.inf)
        if a is not None:
            amodal[a] = int(hit.sum())
        nearer = z < depth
        depth[nearer] = z[nearer]
        instance[nearer] = 0 if a is None else a + 1
    return {"instance": instance, "hole": np.zeros((H, W), np.float32), "depth": depth, "amodal_pixels": amodal}


def write_sweep(path: str, i: int) -> None:
    """The stand-in sweep of frame i (module docstring): rows x, y, z, intensity, ring (float32) in the sensor
    frame; a ``LATTICE``³ lattice inside every box (well inside: no point near a face) and a ground grid 2 cm below
    the ground (never in a box)."""
    pts = []
    f = (np.arange(LATTICE) + 0.5) / LATTICE - 0.5
    grid = np.stack(np.meshgrid(f, f, f, indexing="ij"), -1).reshape(-1, 3) * 0.9
    for _, T, size, _, _ in world_boxes(i):
        pts.append((grid * size) @ T[:3, :3].T + T[:3, 3])
    g = np.arange(-20.0, 20.5, 1.0)
    gx, gy = np.meshgrid(g, g)
    ground = ego_to_world(i) @ np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size), np.ones(gx.size)])
    pts.append(ground[:3].T - [0.0, 0.0, 0.02])
    world = np.concatenate(pts)
    to_sensor = np.linalg.inv(ego_to_world(i) @ RIG.lidar.lidar_to_ego)
    local = world @ to_sensor[:3, :3].T + to_sensor[:3, 3]
    rows = np.concatenate([local, np.full((len(local), 1), 10.0), np.zeros((len(local), 1))], 1).astype("<f4")
    with outputs.atomic_write(path) as fh:
        fh.write(rows.tobytes())


def build(root: str) -> str:
    """The rendered rig job's output folder at ``root`` (module docstring): each of ``rig_job().camera_jobs()``
    labelled as a single-camera job in its ``OutputLayout.camera`` folder; returns ``root``."""
    out = OutputLayout(root)
    for cam, j in rig_job().camera_jobs():
        layout = out.camera(cam.name)
        os.makedirs(layout.conditions, exist_ok=True)
        for i, e in enumerate(j.frames):
            lay = layers(cam, i)
            lab = labels.frame_labels(j, i, instance=lay["instance"], hole=lay["hole"], depth=lay["depth"],
                                      amodal_pixels=lay["amodal_pixels"], asset_boxes=[(*CAR, "job")] * 2,
                                      asset_hashes=["0" * 64] * 2, key="test")
            outputs.write_json(layout.frame_labels(e.frame), lab)
            shade = (lay["instance"][..., None] * 90 + 40).clip(0, 255).astype(np.uint8)
            png.write_png(layout.condition_preview(e.frame), np.repeat(shade, 3, axis=2))
    os.makedirs(out.lidar(RIG.lidar.name), exist_ok=True)
    for i, f in enumerate(FRAMES):
        write_sweep(out.lidar_sweep(f, RIG.lidar.name), i)
    return root


def clip(root: str, name: str = "scpainter-0000"):
    """``nuscenes.job_clip`` of ``rig_job()`` rendered by ``build`` at ``root``."""
    from backend.export import nuscenes

    return nuscenes.job_clip(rig_job(), root, name)[0]
