"""A small labelled job for the exporters' tests, no renderer needed: two inserted cars, one recorded van and one
recorded car seen but not labelled (``ignore``: an ignore region in every export) seen by a level camera (or any
camera: ``job(world_to_camera=...)``), their labels made by ``core.labels.frame_labels`` from known boxes and
instance masks drawn from the projected boxes (the nearer car drawn last, so it hides part of the farther one)."""

import numpy as np

from backend.export import common
from scpainter_blender.core import job as job_mod
from scpainter_blender.core import labels
from scpainter_blender.core.geometry import boxes

W, H = 96, 64
K = np.array([[60.0, 0.0, 48.0], [0.0, 60.0, 32.0], [0.0, 0.0, 1.0]])
CAR = (np.eye(4), np.array([1.8, 4.2, 1.5]))     # box_to_file (centre at the origin), size w l h
CAR[0][2, 3] = 0.75                              # the file's origin on the ground, under the box


def world_to_camera(x: float = 0.0) -> np.ndarray:
    """A level camera 1.5 m above the ground at (x, 0), looking along world +y (x right, z up)."""
    T = np.eye(4)
    T[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]
    T[:3, 3] = -T[:3, :3] @ [x, 0.0, 1.5]
    return T


def tilted_camera(x: float = 0.0, pitch_deg: float = 8.0, roll_deg: float = 5.0) -> np.ndarray:
    """``world_to_camera(x)`` pitched down by ``pitch_deg`` (about the camera's x axis) and rolled by ``roll_deg``
    (about its optical axis)."""
    p, r = np.radians(pitch_deg), np.radians(roll_deg)
    pitch = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(p), -np.sin(p)], [0.0, np.sin(p), np.cos(p)]])
    roll = np.array([[np.cos(r), np.sin(r), 0.0], [-np.sin(r), np.cos(r), 0.0], [0.0, 0.0, 1.0]])
    T = world_to_camera(x)
    turn = np.eye(4)
    turn[:3, :3] = roll @ pitch
    return turn @ T


def placed(x: float, y: float, yaw_deg: float) -> np.ndarray:
    """object_to_world: the file frame turned by yaw about z and moved to (x, y, 0)."""
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    M = np.eye(4)
    M[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    M[:3, 3] = [x, y, 0.0]
    return M


FRAMES = (4, 5)
ASSETS = {"car_a": [placed(-1.5, 10.0, 30.0), placed(-1.4, 10.5, 30.0)],
          "car_b": [placed(1.5, 14.0, -60.0), placed(1.6, 14.2, -60.0)]}


def job(cameras=None) -> job_mod.Job:
    """The job; ``cameras`` one world_to_camera per frame (default: the level camera moving 0.1 m a frame)."""
    cameras = cameras or [world_to_camera(0.1 * i) for i in range(len(FRAMES))]
    frames = [job_mod.Frame(f, K.copy(), c) for f, c in zip(FRAMES, cameras)]
    assets = [job_mod.Asset(name, "car.ply", {f: m for f, m in zip(FRAMES, ms)},
                            box=job_mod.AssetBox(*CAR)) for name, ms in ASSETS.items()]
    van = job_mod.RecordedObject("rec_7", np.array([2.0, 5.0, 2.2]),
                                 {f: placed(0.5, 24.0, 90.0 + 5 * i) @ _lift(1.1) for i, f in enumerate(FRAMES)},
                                 "van")
    # seen but not labelled: left of the van at its depth (its depth test finds pixels: a bbox_visible)
    unlabelled = job_mod.RecordedObject("rec_8", np.array([1.8, 4.2, 1.5]),
                                        {f: placed(-9.0, 24.0, 0.0) @ _lift(0.75) for f in FRAMES}, "car",
                                        ignore=True)
    scene = job_mod.Scene("predictions.npz", np.eye(4), recorded_objects=[van, unlabelled])
    return job_mod.Job((W, H), frames, "out", scene, assets, fps=10.0)


def _lift(h: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = h
    return T


def layers(j: job_mod.Job, index: int) -> dict:
    """instance (ids; the nearer car last), hole (none), depth (each car's box centre depth on its pixels, the
    van's elsewhere) and each asset's amodal pixel count."""
    entry = j.frames[index]
    instance = np.zeros((H, W), np.float32)
    depth = np.full((H, W), 24.0, np.float32)
    amodal = []
    placed_boxes = [labels.asset_box_to_world(a, CAR, entry.frame) for a in j.assets]
    depths = [float((entry.world_to_camera @ bw)[2, 3]) for bw, _ in placed_boxes]
    masks = {}
    for a, (bw, size) in enumerate(placed_boxes):
        proj = boxes.project_box(bw, size, entry.K, entry.world_to_camera, W, H)
        masks[a] = boxes.polygon_mask(proj["polygon"], W, H)
        amodal.append(int(masks[a].sum()))
    for a in sorted(range(len(j.assets)), key=lambda a: -depths[a]):   # the farthest first
        instance[masks[a]] = a + 1
        depth[masks[a]] = depths[a]
    return {"instance": instance, "hole": np.zeros((H, W), np.float32), "depth": depth, "amodal_pixels": amodal}


def frame_labels(j: job_mod.Job, index: int) -> tuple:
    """(labels dict, instance layer) of output frame ``index``."""
    lay = layers(j, index)
    lab = labels.frame_labels(j, index, instance=lay["instance"], hole=lay["hole"], depth=lay["depth"],
                              amodal_pixels=lay["amodal_pixels"], asset_boxes=[(*CAR, "job")] * len(j.assets),
                              asset_hashes=["0" * 64] * len(j.assets), key="test")
    return lab, lay["instance"]


def write_png(path, seed: int = 0) -> str:
    from backend import png

    png.write_png(path, np.random.default_rng(seed).integers(0, 255, (H, W, 3)).astype(np.uint8))
    return str(path)


def export_frames(tmp_path, cameras=None) -> list:
    """``common.ExportFrame`` of every frame of ``job(cameras)``, with a PNG each."""
    j = job(cameras)
    out = []
    for i in range(len(j.frames)):
        lab, inst = frame_labels(j, i)
        out.append(common.ExportFrame(lab, write_png(tmp_path / f"img_{i}.png", i), inst))
    return out


def write_dataset(tmp_path_factory, fmt_module, name: str):
    """(out folder, frames, counts) of ``fmt_module.write`` on ``export_frames`` in a fresh temporary folder."""
    tmp = tmp_path_factory.mktemp(name)
    frames = export_frames(tmp)
    out = tmp / "dataset"
    out.mkdir()
    return out, frames, fmt_module.write(str(out), frames)
