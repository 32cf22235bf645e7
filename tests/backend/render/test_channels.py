"""backend.render.channels: the condition EXR's channel names, written once and read back by ``generate``,
including condition folders rendered before the asset mask was named ``asset_mask`` (channel ``asset``)."""

import numpy as np
import pytest

from backend import generate as gen
from backend.render import channels, exr
from backend.render import command as render_cmd
from scpainter_blender.core import files
from scpainter_blender.core import job as J
from scpainter_blender.core import shapes


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
        raw = exr.read(p)
        assert sorted(raw) == sorted(["R", "G", "B", "hole", "asset_mask", "Z"]) == sorted(channels.CHANNELS)
        assert 0.05 < (raw["asset_mask"] > 0.5).mean() < 0.95                   # the car is in view
        assert channels.read(p).keys() == raw.keys()


def test_conditions_written_before_the_rename_still_load(car_job):
    """An output folder rendered when the channel was called ``asset``: the render keeps its frames (same job) and
    generate's loader gives exactly the tensors of the current files."""
    path, job, paths = car_job
    image, asset_mask, valid = gen.load_conditions(path, job)
    assert asset_mask.shape == (2, 1, 32, 48) and float(asset_mask.max()) > 0.5
    for p in paths:  # what the earlier writer made: the same exr.write, the mask under its former name
        old = exr.read(p)
        old["asset"] = old.pop("asset_mask")
        exr.write(p, old)
        assert "asset" in exr.read(p) and "asset_mask" not in exr.read(p)
    r = render_cmd.render_job(path, job, "cpu")
    assert r["rendered"] == 0 and r["skipped"] == 2                           # kept, not rendered again
    assert "asset" in exr.read(paths[0])
    again = gen.load_conditions(path, job)
    for a, b in zip((image, asset_mask, valid), again):
        assert torch_equal(a, b)
    layers = channels.read(paths[1])
    assert "asset" not in layers and np.array_equal(layers["asset_mask"], asset_mask[1, 0].numpy())


def test_missing_channel_names_file_and_channel(car_job):
    path, job, paths = car_job
    raw = exr.read(paths[1])
    del raw["asset_mask"]
    exr.write(paths[1], raw)
    with pytest.raises(channels.ConditionsError) as e:
        gen.load_conditions(path, job)
    assert isinstance(e.value, files.InputError) and e.value.field == "channels"
    assert "frame_000002.exr" in str(e.value) and "asset_mask" in e.value.message and "render" in e.value.hint
    # Z is not needed to generate, but a reader asking for every channel is told it is missing
    raw = exr.read(paths[0])
    del raw["Z"]
    exr.write(paths[0], raw)
    with pytest.raises(channels.ConditionsError, match="'Z'"):
        channels.read(paths[0])


def test_writer_takes_exactly_the_channels(tmp_path):
    z = np.zeros((2, 3), np.float32)
    layers = {c: z for c in channels.CHANNELS}
    channels.write(tmp_path / "ok.exr", layers)
    assert sorted(exr.read(tmp_path / "ok.exr")) == sorted(channels.CHANNELS)
    for bad in ({**{c: z for c in channels.CHANNELS if c != "asset_mask"}, "asset": z}, {**layers, "extra": z}):
        with pytest.raises(ValueError, match="condition layers"):
            channels.write(tmp_path / "bad.exr", bad)
    assert not (tmp_path / "bad.exr").exists()


def torch_equal(a, b) -> bool:
    return a.shape == b.shape and bool((a == b).all())
