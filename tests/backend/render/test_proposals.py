"""``--proposals accept|ignore|off`` (backend/render/proposals.py): the labels of a tiny job whose reconstruction
shows a road and one box on it that nothing labels, made by ``python -m backend render``."""

import json
import os

import numpy as np

from scpainter_blender.core import job as J
from scpainter_blender.core.output_layout import OutputLayout
from scpainter_blender.core.vggt import npz as vggt_io

W, H, F = 128, 96, 7
FOCAL = 80.0
CAMERA_HEIGHT = 1.6
#: the box in VGGT's frame (OpenCV axes of the first camera: x right, y down, z forward), metres: 2 m wide,
#: 4.5 m long, 1.5 m tall, standing on the ground (y = CAMERA_HEIGHT) 2 m to the left, 9–13.5 m ahead
BOX_LO, BOX_HI = np.array([-3.0, CAMERA_HEIGHT - 1.5, 9.0]), np.array([-1.0, CAMERA_HEIGHT, 13.5])
#: vggt_to_world of a metric reconstruction: OpenCV axes to Blender's (x right, y forward, z up), the first camera at
#: the origin (``metric_scale.vggt_to_world_by_factor(1)``'s axes)
VGGT_TO_WORLD = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, -1.0, 0, 0], [0, 0, 0, 1.0]])


def ray_cast(z_cam):
    """Depth (H, W) seen from a camera at (0, 0, ``z_cam``) of VGGT's frame looking along +z: the ground plane and
    the box (slabs), VGGT's pixel convention (x = (u - cx) d / fx)."""
    f, cx, cy = FOCAL, W / 2, H / 2
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    d = np.stack([(u - cx) / f, (v - cy) / f, np.ones_like(u)], -1)          # z = 1: t is the depth
    o = np.array([0.0, 0.0, z_cam])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(d[..., 1] > 1e-6, CAMERA_HEIGHT / d[..., 1], np.inf)
        t1, t2 = (BOX_LO - o) / d, (BOX_HI - o) / d
        near, far = np.nanmax(np.minimum(t1, t2), -1), np.nanmin(np.maximum(t1, t2), -1)
    t_box = np.where((near <= far) & (far > 0), near, np.inf)
    depth = np.minimum(t_ground, t_box)
    return np.where(np.isfinite(depth), depth, 200.0), f


def road_job(folder, **scene):
    """A job in ``folder``: F frames driving 2 m each along the road, past the box (predictions ray-cast as above), the scene's
    ``scene`` fields added; returns its path."""
    folder = str(folder)
    os.makedirs(folder, exist_ok=True)
    depth, ext, intr = [], [], []
    for i in range(F):
        d, f = ray_cast(2.0 * i)
        depth.append(d)
        e = np.eye(3, 4)
        e[2, 3] = -2.0 * i                                                     # world_to_camera: the camera at z = 2i
        ext.append(e)
        intr.append([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]])
    rng = np.random.default_rng(0)
    vggt_io.save_predictions(os.path.join(folder, "predictions.npz"), images=rng.random((F, H, W, 3)),
                             depth=np.array(depth), depth_conf=np.ones((F, H, W)), extrinsic=np.array(ext),
                             intrinsic_vggt=np.array(intr))
    K = [[FOCAL, 0, W / 2 + 0.5], [0, FOCAL, H / 2 + 0.5], [0, 0, 1]]
    frames = []
    for i in range(F):
        w2c = np.eye(4)
        w2c[:3, :4] = ext[i]
        frames.append({"frame": i + 1, "K": K, "world_to_camera": (w2c @ np.linalg.inv(VGGT_TO_WORLD)).tolist(),
                       "source_frames": list(range(F))})
    job = {"schema": J.SCHEMA, "resolution": [W, H], "output_dir": "out", "frames": frames,
           "scene": {"predictions": "predictions.npz", "vggt_to_world": VGGT_TO_WORLD.tolist(),
                     # every point kept: the box's side, seen at a grazing angle, is all depth edges at this size
                     "confidence_percentile": 0, "point_cleaning": {"depth_edge_ratio": None, "outliers": None},
                     **scene}}
    path = os.path.join(folder, "job.json")
    J.save(path, job)
    return path


def labels(job_path, frame=1):
    with open(OutputLayout(os.path.join(os.path.dirname(job_path), "out")).frame_labels(frame)) as f:
        return json.load(f)


def recorded(lab):
    return [o for o in lab["objects"] if not o["synthetic"]]


def test_the_three_modes(tmp_path, capsys):
    """ignore (the default): an ignore region and a warning naming it; accept: a label; off: nothing; each a
    label-only change (the layers kept, the labels made again). The command line parsed and run in this process
    (the subprocess start-up, torch's import, is what makes ``python -m backend`` slow)."""
    from backend.__main__ import main

    path = road_job(tmp_path)

    def run(*mode):
        capsys.readouterr()
        assert main(["render", path, "--device", "cpu", *mode]) == 0
        ev = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.strip()]
        return [e for e in ev if e["event"] == "warning"], ev[-1], labels(path)

    warnings, done, lab = run()
    proposed = [w for w in warnings if w["code"] == "unlabelled_object"]
    assert [w["object"] for w in proposed] == ["proposal_01"] and "proposal_01: a car" in proposed[0]["message"]
    # and each frame that shows it says how much of the image is left unlabelled (core.labels.UNLABELLED_FLAG)
    shown = [w for w in warnings if w["code"] != "unlabelled_object"]
    assert shown and {w["code"] for w in shown} == {"unlabelled_objects"} and len(shown) + 1 == len(warnings)
    assert done["warnings"] == len(warnings) and done["rendered"] == F
    (obj,) = recorded(lab)
    assert obj["class"] == "car" and obj["track_id"] and obj["visible_pixels"] > 0 and obj["ignore"]
    assert 0 < lab["unlabelled_fraction"] < 1
    # the box of BOX_LO..BOX_HI, in world (x right, y forward, z up), as the points show it
    centre = VGGT_TO_WORLD[:3, :3] @ ((BOX_LO + BOX_HI) / 2)
    assert np.allclose(obj["box_world"]["center"], centre, atol=0.05)

    warnings, done, accepted = run("--proposals", "accept")
    assert warnings == [] and done["rendered"] == 0 and done["relabelled"] == F   # label-only: the layers kept
    (obj,) = recorded(accepted)
    assert obj["class"] == "car" and obj["box_world"] == recorded(lab)[0]["box_world"] and not obj["ignore"]
    assert accepted["layers_key"] == lab["layers_key"]

    warnings, done, off = run("--proposals", "off")
    assert warnings == [] and done["rendered"] == 0 and recorded(off) == []


def test_a_recorded_object_over_it_leaves_nothing_to_propose(tmp_path):
    from backend.render import proposals

    centre = VGGT_TO_WORLD[:3, :3] @ ((BOX_LO + BOX_HI) / 2)
    T = np.eye(4)
    T[:3, 3] = centre
    box = {"id": "car_a", "size": [2.0, 4.5, 1.5], "boxes": {str(f): T.tolist() for f in range(1, F + 1)}}
    path = road_job(tmp_path, recorded_objects=[box])
    job = J.load(path)
    assert proposals.apply(path, job, "ignore", allow_outside=False) == (job, 0)
    path = road_job(tmp_path / "bare")
    job, warned = proposals.apply(path, J.load(path), "accept")
    assert warned == 0 and [(o.id, o.ignore) for o in job.scene.recorded_objects] == [("proposal_01", False)]
    job, warned = proposals.apply(path, J.load(path), "ignore")
    assert warned == 1 and [(o.id, o.ignore) for o in job.scene.recorded_objects] == [("proposal_01", True)]
    assert sorted(job.scene.recorded_objects[0].boxes) == list(range(1, F + 1))


def test_batch_labels_as_render_does_so_an_export_has_nothing_to_make_again(tmp_path, capsys):
    """``batch`` adds the proposals as ``render`` does (its default mode): the labels it writes hold the ignored
    proposal, and an export after it neither renders nor relabels a frame."""
    from backend.__main__ import main

    path = road_job(tmp_path)
    assert main(["batch", path, "--command", "render", "--device", "cpu"]) == 0
    (obj,) = recorded(labels(path))
    assert obj["name"] == "proposal_01" and obj["ignore"]
    layout = OutputLayout(os.path.join(os.path.dirname(path), "out"))
    written = [os.stat(layout.frame_labels(f)).st_mtime_ns for f in range(1, F + 1)]
    capsys.readouterr()
    assert main(["export", path, "--format", "kitti", "--device", "cpu"]) == 0
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.strip()]
    assert events[-1]["rendered"] == 0 and events[-1]["ignore_regions"] > 0
    assert [os.stat(layout.frame_labels(f)).st_mtime_ns for f in range(1, F + 1)] == written   # not made again
