"""``python -m backend splat-asset`` (backend/splat_asset.py) and SOG in jobs: a SOG rewritten as an INRIA PLY with
the values core reads, bad input exit 2 naming the entry, and a job whose asset is a .sog rendering as the same job
with splat-transform's own decode of it."""

import glob
import os

import numpy as np

import sog_fixtures as S
import splat_transform
from scpainter_blender.core import job as J
from scpainter_blender.core.splats import reader as splats_io, sog
from tests_support import run_backend_here, small_job


def test_splat_asset_writes_the_values_read(tmp_path):
    meta, images = S.tiny(n=12, bands=3)
    bundle = S.write_bundle(tmp_path / "car.sog", meta, images)
    out = tmp_path / "assets" / "car.ply"
    code, events, err = run_backend_here("splat-asset", bundle, "--out", out)
    assert code == 0, err
    assert events[0] == {"event": "artifact", "path": str(out), "kind": "gaussians"}
    done = events[-1]
    assert done["command"] == "splat-asset"
    assert done["result"] == {"ply": str(out), "source": bundle, "format": "sog", "count": 12, "sh_degree": 3,
                              "dropped": {}}
    got, want = splats_io.read(out), sog.read(bundle)
    assert got.format == "inria"
    for k in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot"):
        assert np.array_equal(getattr(got, k), getattr(want, k)), k
    folder = S.write_folder(tmp_path / "unbundled", meta, images)
    code, events, err = run_backend_here("splat-asset", folder, "--out", tmp_path / "u.ply")
    assert code == 0 and np.array_equal(splats_io.read(tmp_path / "u.ply").rot, want.rot), err


def test_splat_asset_bad_input_names_the_entry(tmp_path):
    meta, images = S.tiny(n=12)
    bundle = S.write_bundle(tmp_path / "car.sog", meta, images, leave_out=["sh0.webp"])
    code, events, err = run_backend_here("splat-asset", bundle, "--out", tmp_path / "o.ply")
    assert code == 2 and "Traceback" not in err
    assert events[-1]["event"] == "error" and events[-1]["field"] == "sh0.webp" and events[-1]["file"] == bundle
    assert "no entry 'sh0.webp'" in events[-1]["message"] and not (tmp_path / "o.ply").exists()


def _conditions(job_path):
    out = os.path.join(os.path.dirname(job_path), "out")
    files = sorted(glob.glob(os.path.join(out, "**", "*.exr"), recursive=True))
    assert files
    return [open(f, "rb").read() for f in files]


def test_a_job_whose_asset_is_a_sog_renders_as_its_decode(tmp_path):
    """render --check and render of a job naming car.sog (splat-transform's bundle of the job's car) give the frames
    of the same job naming splat-transform's own decode of that bundle (a PLY)."""
    jobs = {}
    for name in ("sog", "ply"):
        job = small_job(tmp_path / name)
        folder = os.path.dirname(job)
        splat_transform.convert(os.path.join(folder, "car.ply"), os.path.join(tmp_path, "car.sog"))
        d = J.load(job).to_dict()
        if name == "sog":
            os.replace(tmp_path / "car.sog", os.path.join(folder, "car.sog"))
            d["assets"][0]["ply"] = "car.sog"
        else:
            splat_transform.convert(os.path.join(tmp_path, "car.sog"), os.path.join(folder, "decoded.ply"))
            d["assets"][0]["ply"] = "decoded.ply"
        os.remove(os.path.join(folder, "car.ply"))
        J.save(job, d)
        jobs[name] = job
    # two conversions of the same car.ply (small_job's, SH 0: no k-means palette, so the writer is deterministic)
    code, events, err = run_backend_here("render", jobs["sog"], "--check", "--device", "cpu")
    assert code == 0 and events[-1]["check"] is True, err
    for job in jobs.values():
        code, events, err = run_backend_here("render", job, "--device", "cpu")
        assert code == 0, err
    assert _conditions(jobs["sog"]) == _conditions(jobs["ply"])
