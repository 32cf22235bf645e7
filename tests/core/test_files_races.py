"""Inputs checked once and read later (issue 42): an asset swapped for a link after the job's paths were checked
was read (4 of 4 trials). Reads inside ``files.confined_reads`` check the file as opened, not the path: the swap is
made deterministic by doing it at the point between the check and the read (``job_inputs.job_paths`` returning)."""

import os

import pytest

from scpainter_blender.core import files, job as J, job_inputs
from scpainter_blender.core.errors import InputError
from scpainter_blender.core.splats import reader
from tests_support import small_job


def test_an_asset_swapped_for_a_link_after_the_check_is_not_read(tmp_path, monkeypatch):
    job = small_job(tmp_path / "job")
    secret = tmp_path / "secret"
    secret.mkdir()
    car = os.path.join(os.path.dirname(job), "car.ply")
    os.rename(car, secret / "car.ply")                      # a readable Gaussian file, outside the job's folder
    with open(car, "wb") as f:                               # the job's own car, as the check sees it
        f.write(open(secret / "car.ply", "rb").read())
    checked = job_inputs.job_paths

    def check_then_swap(*args, **kwargs):
        paths = checked(*args, **kwargs)                     # the paths pass confinement ...
        os.remove(car)                                       # ... then the asset becomes a link leading out
        os.symlink(secret / "car.ply", car)
        return paths

    monkeypatch.setattr(job_inputs, "job_paths", check_then_swap)
    with pytest.raises(InputError) as e:
        job_inputs.check_inputs(job, J.load(job))
    assert e.value.path == car and "outside" in e.value.message and str(secret / "car.ply") in e.value.message


def test_confined_reads_check_the_opened_file(tmp_path):
    inside, outside = tmp_path / "in", tmp_path / "out"
    inside.mkdir()
    outside.mkdir()
    (outside / "a.json").write_text("{}")
    (inside / "b.json").write_text("{}")
    os.symlink(outside / "a.json", inside / "a.json")
    os.symlink(inside / "b.json", inside / "c.json")         # a link that stays inside is fine
    with files.confined_reads([inside]):
        assert files.read_json(inside / "b.json") == {} and files.read_json(inside / "c.json") == {}
        with pytest.raises(InputError):
            files.read_json(inside / "a.json")
        with pytest.raises(Exception):                        # every reader opens through open_regular
            reader.read(inside / "a.json")
        with files.confined_reads(None):                      # --allow-outside: no limit
            assert files.read_json(inside / "a.json") == {}
    assert files.read_json(inside / "a.json") == {}
