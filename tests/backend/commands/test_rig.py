"""``python -m backend rig``: a single-camera job made a rig job; bad input exits 2 naming the file and field."""

import json

import numpy as np

from scpainter_blender.core import job as J, rig as R
from tests_support import run_backend_here as backend, small_job


def test_rig_writes_the_rig_job(tmp_path):
    base = small_job(tmp_path)
    code, ev, err = backend("rig", base, "--preset", "nuscenes", "--scale", "0.02", "--lidar", "velodyne-64",
                            "--follow", "CAM_BACK", "--out", tmp_path / "rig.json")
    assert code == 0, err
    done = ev[-1]
    assert done["command"] == "rig" and done["cameras"] == list(R.NUSCENES_CAMERAS) and done["lidar"] == "LIDAR_TOP"
    assert done["follow"] == "CAM_BACK" and done["frames"] == 2 and done["data_roots"] == []
    assert done["resolutions"]["CAM_FRONT"] == [32, 18]
    job = J.load(tmp_path / "rig.json")
    assert job.rig.lidar.model == "velodyne-64" and job.output_dir == "."
    back = dict((c.name, j) for c, j in job.camera_jobs())["CAM_BACK"]
    np.testing.assert_allclose(back.frames[0].world_to_camera, J.load(base).frames[0].world_to_camera, atol=1e-9)


def test_bad_input_exits_2_naming_the_file_and_field(tmp_path):
    base = small_job(tmp_path)
    out = tmp_path / "rig.json"
    code, ev, _ = backend("rig", base, "--preset", "surround9", "--out", out)
    assert code == 2 and ev[-1]["field"] == "--preset" and "'front', 'nuscenes'" in ev[-1]["message"]
    twice = {"schema": R.RIG_SCHEMA, **R.preset("nuscenes", scale=0.02).to_dict()}
    twice["cameras"][3]["name"] = "CAM_FRONT"
    (tmp_path / "twice.json").write_text(json.dumps(twice))
    code, ev, _ = backend("rig", base, "--preset", tmp_path / "twice.json", "--out", out)
    assert code == 2 and ev[-1]["file"] == str(tmp_path / "twice.json") and ev[-1]["field"] == "cameras[3].name"
    assert "two sensors with one name" in ev[-1]["message"]
    code, ev, _ = backend("rig", base, "--preset", "front", "--lidar", "hdl-9000", "--out", out)
    assert code == 2 and ev[-1]["field"] == "--lidar"
    code, ev, _ = backend("rig", base, "--preset", "front", "--lidar", "NUSCENES-32", "--out", out)   # names exact
    assert code == 2 and ev[-1]["field"] == "--lidar" and "did you mean 'nuscenes-32'?" in ev[-1]["message"]
    code, ev, _ = backend("rig", base, "--preset", "front", "--follow", "CAM_BACK", "--out", out)
    assert code == 2 and ev[-1]["field"] == "--follow"
    assert not out.exists()


def test_an_existing_out_is_never_overwritten(tmp_path):
    """A rendered six-camera job is not silently replaced by a one-camera one (its outputs left behind): an existing
    ``--out`` exits 2 naming it, unless it holds exactly the job that would be written (a no-op)."""
    base = small_job(tmp_path)
    out = tmp_path / "surround" / "job.json"
    args = ("rig", base, "--preset", "nuscenes", "--scale", "0.02", "--out", out)
    code, ev, err = backend(*args)
    assert code == 0, err
    before = out.read_bytes()
    code, ev, err = backend(*args)          # the same job again: nothing to do
    assert code == 0, err
    assert out.read_bytes() == before
    code, ev, _ = backend("rig", base, "--preset", "front", "--scale", "0.02", "--out", out)
    assert code == 2 and ev[-1]["field"] == "--out" and str(out) in ev[-1]["message"]
    assert "delete the old job" in ev[-1]["hint"]
    assert out.read_bytes() == before
