"""A rig job's LiDAR sweeps written by ``render`` (``backend/render/lidar_sweeps.py``, docs/design.md §17): one
``.pcd.bin`` per frame with its ``.json`` (key, pose, returns per source) after the cameras, the inserted car among
the returns, nothing cast again by a second render, cast again when the LiDAR's mount changes; the surround
pictures beside them."""

import os

import numpy as np
import pytest

from backend.lidar import sweep as sweep_mod
from scpainter_blender.core import files, rig as R
from scpainter_blender.core import job as J
from scpainter_blender.core.output_layout import OutputLayout
from tests_support import run_backend_here as backend, small_job

#: OpenCV camera axes into the ego frame (x forward, y left, z up): looking forward
FORWARD = np.array([[0.0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
#: the LiDAR's sensor frame (x right, y forward, z up) into the ego frame, at the camera
LIDAR_AT_CAMERA = np.array([[0.0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])


@pytest.fixture(scope="module")
def rigged(tmp_path_factory):
    """small_job's scene (a car 6 m ahead) as a one-camera rig job with nuScenes' 32-beam LiDAR at the camera."""
    tmp = tmp_path_factory.mktemp("lidar")
    base = small_job(tmp / "drive", fps=10.0)
    K = np.array([[12.0, 0, 8], [0, 12.0, 6], [0, 0, 1]])
    rig = R.Rig("custom", [R.RigCamera("CAM_FRONT", (16, 12), K, FORWARD)],
                R.RigLidar("LIDAR_TOP", "nuscenes-32", LIDAR_AT_CAMERA))
    R.save(tmp / "rig.json", rig)
    code, ev, err = backend("rig", base, "--preset", tmp / "rig.json", "--out", tmp / "surround" / "job.json")
    assert code == 0, err
    return tmp, str(tmp / "surround" / "job.json")


def _render(job_path, tmp, *more):
    return backend("render", job_path, "--device", "cpu", "--data-root", tmp / "drive", *more)


def test_render_casts_each_frames_sweep_with_the_car_among_its_returns(rigged):
    tmp, job_path = rigged
    code, ev, err = _render(job_path, tmp)
    assert code == 0, err
    done = ev[-1]
    assert done["lidar"] == {"sweeps": 2, "cast": 2, "skipped": 0, "stopped": False}
    layout = OutputLayout(tmp / "surround")
    job = J.load(job_path)
    for e in job.frames:
        rows = sweep_mod.read_pcd_bin(layout.lidar_sweep(e.frame))
        info = files.read_json(layout.lidar_sweep_info(e.frame))
        assert rows.shape[1] == 5 and len(rows) == info["returns"] > 0
        assert set(np.unique(rows[:, 4])) <= set(range(32))                  # ring indices
        assert info["returns_per_source"]["car"] > 0                         # the inserted car returns points
        expected = np.asarray(e.ego_to_world) @ LIDAR_AT_CAMERA
        assert np.abs(np.asarray(info["lidar_to_world"]) - expected).max() < 1e-12
        # every return lies at its range from the sensor, within its range limits
        r = np.linalg.norm(rows[:, :3], axis=1)
        assert r.min() >= 1.0 - 1e-3 and r.max() <= 70.0 + 1e-3
        assert os.path.getsize(layout.surround(e.frame)) > 1000              # cameras beside the sweep from above
    lidar_events = [x for x in ev if x["event"] == "progress" and x["stage"] == "lidar"]
    assert [x["frame"] for x in lidar_events] == [1, 2] and all(x["camera"] == "LIDAR_TOP" for x in lidar_events)
    assert [x["kind"] for x in ev if x["event"] == "artifact" and x["path"].endswith(".pcd.bin")] == ["lidar"] * 2


def _calib(path) -> dict:
    """A KITTI calib file as OpenPCDet's ``get_calib_from_file`` reads it: ``key[:] v1 v2 ...`` per line."""
    out = {}
    for line in open(path, encoding="utf-8"):
        key, *values = line.split()
        out[key.rstrip(":")] = np.array([float(v) for v in values])
    return out


def _in_world_box(points, box) -> np.ndarray:
    """Which world ``points`` (R, 3) lie strictly inside a labels ``box_world`` (centre, size l w h, quaternion)."""
    from scpainter_blender.core.geometry import cameras

    R_ = cameras.quaternion_to_rotation(np.asarray(box["quaternion"], np.float64)).reshape(3, 3)
    local = (points - np.asarray(box["center"], np.float64)) @ R_
    return np.all(np.abs(local) < np.asarray(box["size"], np.float64) / 2, axis=1)


def _in_kitti_box(rect, h, w, l, loc, ry) -> np.ndarray:
    """Which rectified-camera points (R, 3) lie strictly inside a KITTI label's box (the devkit's
    ``computeBox3D``: from the bottom centre ``loc`` up along −y, length along x turned by ``ry`` about y)."""
    d = rect - loc
    c, s = np.cos(ry), np.sin(ry)
    along, across = c * d[:, 0] - s * d[:, 2], s * d[:, 0] + c * d[:, 2]
    return (np.abs(along) < l / 2) & (np.abs(across) < w / 2) & (d[:, 1] < 0) & (d[:, 1] > -h)


def test_kitti_export_of_the_rig_camera_carries_its_lidar(rigged):
    """KITTI's velodyne/ and Tr_velo_to_cam, read as OpenPCDet's ``calibration_kitti`` does (``lidar_to_rect``),
    projected by P2: the returns inside the car's label box are the sweep's returns in its world box, and they land
    on the label's 2D box; KITTI tracking carries the same points and one Tr_velo_cam."""
    tmp, job_path = rigged
    out = tmp / "kitti"
    code, ev, err = backend("export", job_path, "--format", "kitti", "--out", out, "--device", "cpu",
                            "--data-root", tmp / "drive")
    assert code == 0, err
    assert ev[-1]["lidar"]["sweeps"] == 2
    layout, job = OutputLayout(tmp / "surround"), J.load(job_path)
    cam = out / "CAM_FRONT"
    for i, e in enumerate(job.frames):
        rows = sweep_mod.read_pcd_bin(layout.lidar_sweep(e.frame))
        info = files.read_json(layout.lidar_sweep_info(e.frame))
        velo = np.fromfile(cam / "velodyne" / f"{i:06d}.bin", "<f4").reshape(-1, 4)
        assert len(velo) == len(rows) and np.allclose(velo[:, 3], rows[:, 3] / 255.0)
        # a camera looking forward: KITTI's velodyne axes are the sensor's (x forward = its y, y left = its -x)
        assert np.allclose(velo[:, :3], np.column_stack([rows[:, 1], -rows[:, 0], rows[:, 2]]), atol=1e-5)
        calib = _calib(cam / "calib" / f"{i:06d}.txt")
        V2C, R0, P2 = calib["Tr_velo_to_cam"].reshape(3, 4), calib["R0_rect"].reshape(3, 3), calib["P2"].reshape(3, 4)
        hom = np.hstack([velo[:, :3].astype(np.float64), np.ones((len(velo), 1))])
        rect = hom @ (V2C.T @ R0.T)                                                      # lidar_to_rect
        # P2 · X, divided by its third row (the devkit's projectToImage); OpenPCDet's rect_to_img divides by the
        # rect z, the same for a level camera (P2's third row 0 0 1 0: test_kitti), but this camera looks up
        uvw = np.hstack([rect, np.ones((len(rect), 1))]) @ P2.T
        img = uvw[:, :2] / uvw[:, 2:3]
        line = next(x.split() for x in open(cam / "label_2" / f"{i:06d}.txt") if x.startswith("Car "))
        box2d = np.array(line[4:8], float)
        h, w, l, x, y, z, ry = (float(v) for v in line[8:15])
        inside = _in_kitti_box(rect, h, w, l, np.array([x, y, z]), ry)
        # the same returns counted in the world, from the .pcd.bin and the sweep's pose, in the labels' box
        lab = files.read_json(layout.camera("CAM_FRONT").frame_labels(e.frame))
        car = next(o for o in lab["objects"] if o["class"] == "car" and o["synthetic"])
        T = np.asarray(info["lidar_to_world"])
        world = rows[:, :3].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        assert inside.sum() == _in_world_box(world, car["box_world"]).sum() > 0
        assert inside.sum() <= info["returns_per_source"]["car"] + info["returns_per_source"]["points"]
        u, v = img[inside].T
        assert (u >= box2d[0] - 0.5).all() and (u <= box2d[2] + 0.5).all()          # on the car's 2D box
        assert (v >= box2d[1] - 0.5).all() and (v <= box2d[3] + 0.5).all()
    # KITTI tracking: velodyne/0000/NNNNNN.bin, the sequence's one Tr_velo_cam (the rig holds the LiDAR fixed)
    code, ev, err = backend("export", job_path, "--format", "kitti-tracking", "--out", tmp / "tracking",
                            "--device", "cpu", "--data-root", tmp / "drive")
    assert code == 0, err
    seq = tmp / "tracking" / "CAM_FRONT"
    tr = _calib(seq / "calib" / "0000.txt")["Tr_velo_cam"]
    assert np.allclose(tr, _calib(cam / "calib" / "000000.txt")["Tr_velo_to_cam"], atol=1e-9)
    for i in range(len(job.frames)):
        assert np.array_equal(np.fromfile(seq / "velodyne" / "0000" / f"{i:06d}.bin", "<f4"),
                              np.fromfile(cam / "velodyne" / f"{i:06d}.bin", "<f4"))


def test_a_second_render_casts_nothing_and_a_moved_lidar_casts_again(rigged):
    tmp, job_path = rigged
    code, ev, err = _render(job_path, tmp)
    assert code == 0, err
    assert ev[-1]["lidar"]["cast"] == 0 and ev[-1]["rendered"] == 0
    job = J.load(job_path)
    moved = LIDAR_AT_CAMERA.copy()
    moved[2, 3] = 0.5                                                         # the LiDAR mounted 0.5 m higher
    job.rig.lidar.lidar_to_ego = moved
    J.save(job_path, job)
    code, ev, err = _render(job_path, tmp)
    assert code == 0, err
    assert ev[-1]["lidar"]["cast"] == 2 and ev[-1]["rendered"] == 0         # the cameras' layers are kept


def test_a_first_sweep_without_cached_kernels_says_it_compiles_them(rigged, monkeypatch):
    from backend.lidar import cast_cpu

    tmp, job_path = rigged
    monkeypatch.setattr(cast_cpu, "kernels_cached", lambda: False)   # as on a new install
    code, ev, err = _render(job_path, tmp, "--force")
    assert code == 0, err
    compile_ = [e for e in ev if e["event"] == "progress" and e["stage"] == "compile" and "LiDAR" in e["message"]]
    assert [(e["done"], e["total"]) for e in compile_] == [(0, 1), (1, 1)]
