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
