"""Assets whose Gaussians are invalid (issue 30): none valid is refused naming the job's ``assets[i].ply`` and the
file (``render``, ``render --check``, ``generate --check``); most of them invalid renders with a ``warning``."""

import os

import numpy as np
import pytest

from scpainter_blender.core import job as J
from scpainter_blender.core import job_inputs
from scpainter_blender.core.splats import gaussians as splats, inria, reader
from tests.core.splats import splat_fixtures as F
from tests_support import run_backend_here, small_job


def _car(job):
    """The small job's car, raw (300 Gaussians as Amodal3R saves them), and its path."""
    path = os.path.join(os.path.dirname(job), "car.ply")
    return reader.read(path), path


def _write_inria(path, ply, rows, **values):
    """``ply`` with ``values`` (xyz=..., rot=...) set on ``rows``, written as an INRIA PLY at ``path``."""
    arrays = {k: getattr(ply, k).copy() for k in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot")}
    for k, v in values.items():
        arrays[k][rows] = v
    inria.write_ply(path, splats.GaussianPly(**arrays))


def _nan_chunk_ranges(path, ply):
    """``ply`` as a SuperSplat compressed PLY whose chunk ranges are NaN: every Gaussian decodes to NaN."""
    F.write_compressed(path, ply)
    with open(path, "rb") as f:
        data = f.read()
    at = data.index(b"end_header\n") + len(b"end_header\n")
    chunks = -(-len(ply) // 256)
    table = np.frombuffer(data[at:at + chunks * 18 * 4], "<f4").copy()
    table[:] = np.nan
    with open(path, "wb") as f:
        f.write(data[:at] + table.tobytes() + data[at + chunks * 18 * 4:])


@pytest.mark.parametrize("make, why", [
    (lambda ply, path: _write_inria(path, ply, slice(None), rot=0.0), "300 with a zero quaternion"),
    (lambda ply, path: _write_inria(path, ply, slice(None), xyz=np.nan), "300 with NaN or infinite values"),
    (lambda ply, path: _nan_chunk_ranges(path, ply), "300 with NaN or infinite values"),
])
def test_an_asset_without_one_valid_gaussian_is_refused_naming_it(tmp_path, make, why):
    """It once rendered with no car, exit 0 and no word in the log. Refused where every command checks its inputs
    (``job_inputs.check_inputs``), naming the job's field and the file."""
    job = small_job(tmp_path, frames=(1, 2))
    ply, path = _car(job)
    make(ply, path)
    assert len(reader.read(path)) == 300 and len(reader.load(path)) == 0  # readable, nothing valid
    with pytest.raises(J.JobError) as e:
        job_inputs.check_inputs(job, J.load(job))
    assert e.value.path == job and e.value.field == "assets[0].ply" and e.value.hint
    assert path in e.value.message and "none of its 300 Gaussians is valid" in e.value.message
    assert why in e.value.message


def test_render_and_checks_refuse_an_asset_without_one_valid_gaussian(tmp_path):
    job = small_job(tmp_path, frames=(1, 2))
    ply, path = _car(job)
    _nan_chunk_ranges(path, ply)
    for args in (("render", "--check"), ("render",), ("generate", "--check"), ("generate",)):
        code, ev, err = run_backend_here(*args[:1], job, "--device", "cpu", *args[1:])
        assert code == 2 and ev[-1]["event"] == "error" and "Traceback" not in err, (args, err[-2000:])
        assert ev[-1]["file"] == job and ev[-1]["field"] == "assets[0].ply", args
        assert path in ev[-1]["message"] and "none of its 300 Gaussians is valid" in ev[-1]["message"]
    assert not os.path.exists(tmp_path / "out" / "conditions" / "frame_000001.exr")  # nothing rendered


def test_an_empty_asset_is_refused_naming_it(tmp_path):
    job = small_job(tmp_path, frames=(1,))
    ply, path = _car(job)
    inria.write_ply(path, splats.GaussianPly(**{k: getattr(ply, k)[:0] for k in ("xyz", "f_dc", "f_rest", "opacity",
                                                                              "scale", "rot")}))
    with pytest.raises(J.JobError) as e:
        job_inputs.check_inputs(job, J.load(job))
    assert e.value.field == "assets[0].ply" and "holds no Gaussians" in e.value.message


def test_an_asset_mostly_invalid_renders_with_a_warning(tmp_path):
    """More than ``MOSTLY_INVALID_SHARE`` dropped: rendered (what is left), with a warning naming the asset, the
    counts and the file, every run (also ``--check``); at most that share: no warning."""
    job = small_job(tmp_path, frames=(1, 2))
    ply, path = _car(job)
    _write_inria(path, ply, slice(0, 200), rot=0.0)                   # 200 of 300: two thirds
    for args in (("render", "--check"), ("render",), ("render",)):
        code, ev, err = run_backend_here(*args[:1], job, "--device", "cpu", *args[1:])
        assert code == 0, err[-2000:]
        warnings = [e for e in ev if e["event"] == "warning" and e["code"] == splats.INVALID_GAUSSIANS]
        assert len(warnings) == 1 and warnings[0]["object"] == "car", (args, warnings)
        assert "200 of its 300 Gaussians" in warnings[0]["message"] and path in warnings[0]["message"]
        assert "warning: " in err
    layers = J.read_json(tmp_path / "out" / "conditions" / "labels_000001.json")
    assert layers["objects"] and layers["objects"][0]["visible_pixels"] > 0   # the car that is left is drawn

    _write_inria(path, ply, slice(0, 150), rot=0.0)                   # half: accepted as is
    code, ev, err = run_backend_here("render", job, "--device", "cpu")
    assert code == 0 and not [e for e in ev if e["event"] == "warning" and e["code"] == splats.INVALID_GAUSSIANS]
    assert 0 < splats.MOSTLY_INVALID_SHARE < 1


def test_an_asset_whose_gaussians_are_all_below_the_drawn_opacity_is_refused_naming_it(tmp_path):
    """300 Gaussians of opacity logit -60 (valid numbers) once rendered with no car, exit 0, an asset mask of 0 in
    every frame and nothing said. The renderer skips every Gaussian below ``splats.ALPHA_MIN`` (1/255): refused
    like an asset without a valid Gaussian, with its own message, where every command checks its inputs."""
    job = small_job(tmp_path, frames=(1, 2))
    ply, path = _car(job)
    _write_inria(path, ply, slice(None), opacity=-60.0)
    assert len(reader.load(path)) == 300                                        # every Gaussian valid
    with pytest.raises(J.JobError) as e:
        job_inputs.check_inputs(job, J.load(job))
    assert e.value.path == job and e.value.field == "assets[0].ply" and "opacity" in e.value.hint
    assert path in e.value.message and "none of its 300 Gaussians would be drawn" in e.value.message
    assert "300 with an opacity below 1/255" in e.value.message
    for args in (("render", "--check"), ("render",), ("generate", "--check")):
        code, ev, err = run_backend_here(*args[:1], job, "--device", "cpu", *args[1:])
        assert code == 2 and ev[-1]["event"] == "error" and "Traceback" not in err, (args, err[-2000:])
        assert ev[-1]["field"] == "assets[0].ply" and "would be drawn" in ev[-1]["message"], args
    assert not os.path.exists(tmp_path / "out" / "conditions" / "frame_000001.exr")

    # invalid and transparent together, none drawn: refused, saying both
    _write_inria(path, reader.read(path), slice(0, 100), rot=0.0)     # the transparent car, 100 zero quaternions
    with pytest.raises(J.JobError) as e:
        job_inputs.check_inputs(job, J.load(job))
    assert "200 with an opacity below 1/255" in e.value.message and "100 with a zero quaternion" in e.value.message


def test_the_opacity_cut_is_the_renderers_own(tmp_path):
    """Just above ``ALPHA_MIN`` is drawn (accepted, the car visible), just below is not (refused): the check and the
    renderer share the constant and compare in the renderer's float32."""
    from backend.render import gaussians as render_gaussians

    assert render_gaussians.ALPHA_MIN is splats.ALPHA_MIN
    logit = float(np.log(splats.ALPHA_MIN / (1 - splats.ALPHA_MIN)))
    job = small_job(tmp_path, frames=(1,))
    ply, path = _car(job)
    _write_inria(path, ply, slice(None), opacity=logit - 1e-3)
    with pytest.raises(J.JobError):
        job_inputs.check_inputs(job, J.load(job))
    _write_inria(path, ply, slice(None), opacity=logit + 1e-3)
    assert not job_inputs.check_inputs(job, J.load(job))["asset_warnings"]


def test_an_asset_mostly_below_the_drawn_opacity_renders_with_a_warning(tmp_path):
    """More than ``MOSTLY_INVALID_SHARE`` of the Gaussians never drawn: rendered from the rest, with a ``warning``
    (code ``splats.TRANSPARENT_ASSET``, the asset's name) every run and ``--check``; at most that share: none."""
    job = small_job(tmp_path, frames=(1,))
    ply, path = _car(job)
    _write_inria(path, ply, slice(0, 200), opacity=-60.0)
    for args in (("render", "--check"), ("render",)):
        code, ev, err = run_backend_here(*args[:1], job, "--device", "cpu", *args[1:])
        assert code == 0, err[-2000:]
        warnings = [e for e in ev if e["event"] == "warning" and e["code"] == splats.TRANSPARENT_ASSET]
        assert len(warnings) == 1 and warnings[0]["object"] == "car", (args, warnings)
        assert "200 of its 300 Gaussians" in warnings[0]["message"] and path in warnings[0]["message"]
        assert not [e for e in ev if e["event"] == "warning" and e["code"] == splats.INVALID_GAUSSIANS]
    _write_inria(path, ply, slice(0, 150), opacity=-60.0)
    assert not job_inputs.check_inputs(job, J.load(job))["asset_warnings"]
