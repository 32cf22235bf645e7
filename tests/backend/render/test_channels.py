"""backend.render.channels in the render and generate commands: the named channels written by ``render``, read back
by ``generate``; folders rendered by the earlier writer (flat names, the mask once called ``asset``) kept and
read; the half-float option through ``render``/``batch`` and the resume key."""

import numpy as np
import OpenEXR
import pytest

from backend.generate import command as gen
from backend.render import channels
from backend.render import command as render_cmd
from scpainter_blender.core import errors
from scpainter_blender.core import job as J
from scpainter_blender.core import shapes


def raw(path) -> dict:
    """{file channel name: array} as OpenEXR reads the file."""
    return {n: c.pixels for n, c in OpenEXR.File(str(path), separate_channels=True).channels().items()}


def save_raw(path, named: dict) -> None:
    """What this project's former hand-made writer made: flat FLOAT channels, uncompressed scanlines."""
    OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION}, {n: np.asarray(v, np.float32) for n, v in named.items()}
                 ).write(str(path))


@pytest.fixture
def car_job(tmp_path):
    """Two frames of a Gaussian car, no scene (assets only), rendered on the CPU: (job path, job, EXR paths)."""
    ply = tmp_path / "car.ply"
    shapes.save_as_amodal3r(str(ply), shapes.procedural_car_gaussians(count=2000, seed=3))
    frames, object_to_world = [], {}
    for f, back in ((1, 8.0), (2, 6.0)):
        w2c = np.eye(4)
        w2c[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]            # looking along +Y from `back` metres
        w2c[:3, 3] = -w2c[:3, :3] @ np.array([0.0, -back, 0.3])
        frames.append({"frame": f, "K": [[40, 0, 24], [0, 40, 16], [0, 0, 1]], "world_to_camera": w2c.tolist()})
        object_to_world[str(f)] = (np.diag([4.5] * 3 + [1.0]) @ np.array(
            [[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1.0]])).tolist()
    J.save(tmp_path / "job.json", {"schema": J.SCHEMA, "resolution": [48, 32], "frames": frames,
                                   "assets": [{"name": "car", "ply": "car.ply", "object_to_world": object_to_world}],
                                   "output_dir": "out"})
    path = str(tmp_path / "job.json")
    job = J.load(path)
    r = render_cmd.render_job(path, job, "cpu")
    assert r["rendered"] == 2
    return path, job, [render_cmd.frame_paths(path, job, f)[0] for f in (1, 2)]


def test_written_channels_are_the_named_ones(car_job):
    _, _, paths = car_job
    for p in paths:
        f = OpenEXR.File(p, separate_channels=True)
        assert sorted(f.channels()) == sorted(channels.FILE_NAMES.values()) == [
            "asset_mask.Y", "depth.Z", "hole.Y", "image.B", "image.G", "image.R", "instance.Y"]
        assert f.channels()["instance.Y"].type() == OpenEXR.FLOAT
        assert f.header()["compression"] == OpenEXR.ZIP_COMPRESSION
        layers = channels.read(p)
        assert sorted(layers) == sorted(channels.CHANNELS)
        assert 0.05 < (layers["asset_mask"] > 0.5).mean() < 0.95                   # the car is in view
        # one asset, no points: its instance region is where M_a > 0.5 (a tie at exactly 0.5 has measure zero)
        assert np.array_equal(layers["instance"], (layers["asset_mask"] > 0.5).astype(np.float32))
        for c in channels.CHANNELS:
            assert np.array_equal(layers[c], f.channels()[channels.FILE_NAMES[c]].pixels), c


def test_conditions_written_before_the_rename_still_load(car_job):
    """An output folder rendered by the former writer (flat names, uncompressed) when the mask was called
    ``asset``: the render keeps its frames (same job, same key) and generate's loader gives exactly the tensors of
    the current files."""
    path, job, paths = car_job
    image, asset_mask, valid = gen.load_conditions(path, job)
    assert asset_mask.shape == (2, 1, 32, 48) and float(asset_mask.max()) > 0.5
    for p in paths:
        layers = channels.read(p)
        layers["asset"] = layers.pop("asset_mask")
        save_raw(p, layers)
        assert "asset" in raw(p) and "image.R" not in raw(p)
    r = render_cmd.render_job(path, job, "cpu")
    assert r["rendered"] == 0 and r["skipped"] == 2                           # kept, not rendered again
    assert "asset" in raw(paths[0])
    again = gen.load_conditions(path, job)
    for a, b in zip((image, asset_mask, valid), again):
        assert a.shape == b.shape and bool((a == b).all())
    layers = channels.read(paths[1])
    assert "asset" not in layers and np.array_equal(layers["asset_mask"], asset_mask[1, 0].numpy())


def test_missing_channel_names_file_and_channel(car_job):
    path, job, paths = car_job
    named = raw(paths[1])
    del named["asset_mask.Y"]
    save_raw(paths[1], named)
    with pytest.raises(channels.ConditionsError) as e:
        gen.load_conditions(path, job)
    assert isinstance(e.value, errors.InputError) and e.value.field == "channels"
    assert "frame_000002.exr" in str(e.value) and "asset_mask" in e.value.message and "render" in e.value.hint
    # Z is not needed to generate, but a reader asking for every channel is told it is missing
    named = raw(paths[0])
    del named["depth.Z"]
    save_raw(paths[0], named)
    with pytest.raises(channels.ConditionsError, match="'Z'"):
        channels.read(paths[0])


def test_half_float_is_part_of_the_resume_key(car_job):
    """``half``: I, M, M_a stored as HALF; another precision renders every frame again; ``half=None`` (generate,
    evaluate) keeps what the folder has; the job key of a float32 render is the one of earlier versions."""
    path, job, paths = car_job
    float_layers = channels.read(paths[0])
    assert render_cmd.job_key(path, job, 0) == render_cmd.job_key(path, job, 0, half=False)
    assert render_cmd.job_key(path, job, 0, half=True) != render_cmd.job_key(path, job, 0)
    r = render_cmd.render_job(path, job, "cpu", half=True)
    assert r["rendered"] == 2                                                 # another precision: rendered again
    f = OpenEXR.File(paths[0], separate_channels=True)
    assert f.channels()["image.R"].type() == OpenEXR.HALF and f.channels()["depth.Z"].type() == OpenEXR.FLOAT
    half_layers = channels.read(paths[0])
    for c in channels.HALF_LAYERS:
        assert np.array_equal(half_layers[c], float_layers[c].astype(np.float16).astype(np.float32)), c
    assert np.array_equal(half_layers["Z"], float_layers["Z"])
    assert f.channels()["instance.Y"].type() == OpenEXR.FLOAT                 # ids stay exact
    assert np.array_equal(half_layers["instance"], float_layers["instance"]) and half_layers["instance"].max() == 1
    assert render_cmd.render_job(path, job, "cpu")["skipped"] == 2            # generate's call keeps them
    gen.load_conditions(path, job)
    assert render_cmd.render_job(path, job, "cpu", half=False)["rendered"] == 2
    assert OpenEXR.File(paths[0], separate_channels=True).channels()["image.R"].type() == OpenEXR.FLOAT


def test_half_float_options_of_render_and_batch(car_job, capsys):
    """``--half-float`` of ``render`` and ``batch`` (the command line parsed and run in this process: the
    subprocess start-up, torch's import, is what makes ``python -m backend`` slow)."""
    import json

    from backend.__main__ import main

    path, job, paths = car_job

    def run(*argv):
        capsys.readouterr()
        code = main([str(a) for a in argv])
        return code, [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.strip()]

    def stored():
        return OpenEXR.File(paths[1], separate_channels=True).channels()["hole.Y"].type()

    code, ev = run("render", path, "--device", "cpu", "--half-float")
    assert code == 0 and ev[-1]["event"] == "done" and ev[-1]["rendered"] == 2 and stored() == OpenEXR.HALF
    code, ev = run("batch", path, "--device", "cpu")                       # float32 again: rendered again
    assert code == 0 and ev[-1]["items"][0]["status"] == "ok" and stored() == OpenEXR.FLOAT
    code, ev = run("batch", path, "--device", "cpu", "--half-float")
    assert code == 0 and stored() == OpenEXR.HALF
    code, ev = run("batch", path, "--command", "generate", "--half-float")
    assert code == 2 and ev[-1]["field"] == "--half-float" and "render" in ev[-1]["message"]
