"""Clip folders: the street exported as a clip, and the errors bad clips give."""

import os

import numpy as np
import pytest

from backend.train import clip as clip_mod
from scpainter_blender.core import errors
from scpainter_blender.core.job import JobError  # ClipError is one; the shared validators raise it
from tests_support import copy_clip, refusal_beside_fifo


def test_street_clip_loads_with_metric_poses_cars_and_views(street, street_clip_path):
    c = clip_mod.load(os.path.dirname(street_clip_path))
    m = street.metric()
    assert c.metric and c.num_frames == street.params.num_frames
    assert c.image_size == (street.params.width, street.params.height)
    np.testing.assert_allclose(c.world_to_camera, m["world_to_camera"])
    np.testing.assert_allclose(c.K_for(259, 147)[0, :2], m["K"][0, :2] / 2)
    assert len(c.cars) == len(street.info["cars"]) and all(car.asset for car in c.cars)
    assert sorted(c.views) == sorted(street.params.shifts_m)
    assert os.path.samefile(c.views[2.0][5], street.frame_path("left_2m", 5))


_copy = copy_clip  # tests_support: a copy of the street clip with clip.json edited


@pytest.mark.parametrize("edit, field", [
    (lambda d, f: d.update(schema="nope"), "schema"),
    (lambda d, f: d.update(predictions="missing.npz"), "predictions"),
    (lambda d, f: d.update(frames=["frames/frame_000000.png"]), "frames"),
    (lambda d, f: os.remove(f / "frames" / "frame_000015.png"), "frames[15]"),
    (lambda d, f: d["cars"][0]["boxes"].update({"99": np.eye(4).tolist()}), "cars[0].boxes.99"),
    (lambda d, f: d["cars"][1].update(size=[1, -2, 1]), "cars[1].size"),
    (lambda d, f: d["cars"][0]["boxes"].update({"0": (2 * np.eye(4)).tolist()}), "cars[0].boxes.0"),
    (lambda d, f: d["cars"][0].update(asset="assets/none.ply"), "cars[0].asset"),
    (lambda d, f: np.savez(f / "poses.npz", K=np.zeros((16, 3, 3))), "world_to_camera"),
    # wrong JSON types and odd values: each named, never a TypeError from deeper down (issue 14)
    (lambda d, f: d.update(cars={"a": 1}), "cars"),
    (lambda d, f: d.update(cars=5), "cars"),
    (lambda d, f: d["cars"][0].update(size=["a", 1, 2]), "cars[0].size"),
    (lambda d, f: d["cars"][0].update(size=[[1], [2], [3]]), "cars[0].size"),
    (lambda d, f: d["cars"][0].update(size=[1, 2, 0]), "cars[0].size"),
    (lambda d, f: d["cars"][0].update(id={"x": 1}), "cars[0].id"),
    (lambda d, f: d["cars"][0].update(boxes=[np.eye(4).tolist()]), "cars[0].boxes"),
    (lambda d, f: d.update(frames="frames/frame_{0.__class__}.png"), "frames"),
    (lambda d, f: d.update(frames="frames/frame_{:999999999}.png"), "frames"),
    (lambda d, f: d.update(frames="frames/frame_{}{}.png"), "frames"),     # two indices (issue 30's fuzzer)
    (lambda d, f: d.update(frames="frames/frame_{}_{0}.png"), "frames"),   # automatic and manual numbering
    (lambda d, f: d.update(frames={"0": "frames/frame_000000.png"}), "frames"),
    (lambda d, f: d.update(views={"nan": "views/left_2m/frame_{:06d}.png"}), "views.nan"),
    (lambda d, f: d.update(views=["views"]), "views"),
    (lambda d, f: d.update(fps="10"), "fps"),
    (lambda d, f: d.update(predictions=["predictions.npz"]), "predictions"),
    (lambda d, f: _edit_poses(f, world_to_camera=lambda a: a * 0), "world_to_camera"),
    (lambda d, f: _edit_poses(f, K=lambda a: a > 0), "K"),
    (lambda d, f: _edit_poses(f, K=lambda a: -a), "K"),
    (lambda d, f: _edit_poses(f, vggt_to_world=lambda a: a[:3]), "vggt_to_world"),
    (lambda d, f: _edit_poses(f, vggt_to_world=lambda a: np.diag([1.0, 2.0, 3.0, 1.0])), "vggt_to_world"),
    (lambda d, f: _edit_poses(f, world_to_camera=lambda a: np.array([None] * len(a), object)), "world_to_camera"),
])
def test_bad_clips_name_the_field(street_clip_path, tmp_path, edit, field):
    folder = _copy(street_clip_path, tmp_path, edit)
    with pytest.raises(JobError, match=f"{field.replace('[', '.').replace(']', '.')}"):
        clip_mod.load(folder)


def _edit_poses(folder, **change):
    """Rewrite the clip's poses.npz with ``change[key](array)`` applied."""
    with np.load(folder / "poses.npz") as z:
        arrays = {k: z[k] for k in z.files}
    for k, fn in change.items():
        arrays[k] = fn(arrays[k])
    np.savez(folder / "poses.npz", **arrays)


def _set_K(t, row, col, value):
    def change(a):
        a = np.array(a, np.float64)
        a[t, row, col] = value
        return a
    return change


@pytest.mark.parametrize("row, col, value", [
    (0, 0, 1e12),        # a focal length beyond any camera (and beyond a job's bound once resized)
    (1, 1, -5.0),
    (0, 0, 1e-30),       # positive, but a field of view of 180° (found by issue 30's fuzzer)
    (1, 1, 1e-3),
    (0, 0, 1e6),         # within a job's 1e8, but 1,000 image widths: resized for training it would pass it
    (0, 2, 1e7),         # a principal point far outside the image
    (1, 2, -1e4),
    (1, 0, 3.0),         # not our intrinsics' shape: a job refuses it, so a clip does
    (2, 0, 1.0),
])
def test_a_poses_K_out_of_bounds_is_refused_naming_poses_npz_and_the_frame(street_clip_path, tmp_path, row, col,
                                                                            value):
    """Issue 30: a poses.npz K was unbounded, and the job made from the clip then named the job. Now the clip is
    refused at load, naming poses.npz and K[t], with the job's own bounds (``core.job.intrinsics_problem``)."""
    folder = _copy(street_clip_path, tmp_path, lambda d, f: _edit_poses(f, K=_set_K(3, row, col, value)))
    with pytest.raises(clip_mod.ClipError) as e:
        clip_mod.load(folder)
    assert e.value.path == str(folder / "poses.npz") and e.value.field == "K[3]", str(e.value)
    assert "fx" in e.value.message and e.value.hint


def test_a_clips_K_passes_the_jobs_bound_at_any_training_size(street_clip_path, tmp_path):
    """The largest K a clip accepts stays within a job's bound (``MAX_K``) resized to the largest training size:
    both the job's own bound (``MAX_FOCAL_RATIO`` image sizes) and, tighter, the agreement with VGGT's estimate."""
    from scpainter_blender.core import job as J

    c = clip_mod.load(os.path.dirname(street_clip_path))
    W, H = c.image_size
    fx_vggt = (np.diag([W / c.predictions.width, H / c.predictions.height, 1.0]) @ c.predictions.K)[0, 0, 0]
    fx = min(np.nextafter(J.MAX_FOCAL_RATIO, 0) * W, np.nextafter(clip_mod.POSES_K_FOCAL_AGREEMENT, 0) * fx_vggt)
    folder = _copy(street_clip_path, tmp_path, lambda d, f: _edit_poses(f, K=_set_K(0, 0, 0, fx)))
    big = clip_mod.load(folder)
    assert J.intrinsics_problem(big.K_for(16384, 16384)[0]) is None


def test_a_poses_K_for_another_image_size_is_refused(street_clip_path, tmp_path):
    """Frames resized to 1036 x 588 with poses.npz's K left for the 518 x 294 frames (found by a fresh tester: loaded,
    and training projected with fx half the frames' and the principal point in the top-left quarter)."""
    from PIL import Image

    def edit(d, folder):
        for p in sorted((folder / "frames").iterdir()):
            im = Image.open(p).convert("RGB").resize((1036, 588), Image.LANCZOS)
            p.unlink()  # the copy's own file, never one it might share with the cached street
            im.save(p, compress_level=1)  # the same pixels, written fast (zlib's default level was most of the test)

    folder = _copy(street_clip_path, tmp_path, edit)
    with pytest.raises(clip_mod.ClipError) as e:
        clip_mod.load(folder)
    assert e.value.path == str(folder / "poses.npz") and e.value.field == "K[0]", str(e.value)
    assert "for frames of 1036 x 588 px" in e.value.message and "about 518 x 294 px" in e.value.message, str(e.value)
    # the same K scaled to the frames' size, as the hint says: accepted
    _edit_poses(folder, K=lambda K: np.diag([2.0, 2.0, 1.0]) @ K)
    assert clip_mod.load(folder).image_size == (1036, 588)


@pytest.mark.parametrize("key, value, field, words", [
    ("distortion_model", "fisheye", "distortion_model", "stated without distortion coefficients"),
    ("distortion", ["0.1", "0", "0", "0"], "distortion", "a list of 4 holding str"),
])
def test_distortion_fields_that_say_nothing_are_refused(street_clip_path, tmp_path, key, value, field, words):
    def edit(d, folder):
        d[key] = value
        if key == "distortion":
            d["distortion_model"] = "fisheye"
    folder = _copy(street_clip_path, tmp_path, edit)
    with pytest.raises(clip_mod.ClipError) as e:
        clip_mod.load(folder)
    assert e.value.field == field and words in e.value.message, str(e.value)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
@pytest.mark.parametrize("name, field", [("clip.json", "(file)"), ("predictions.npz", "predictions"),
                                         ("poses.npz", "(file)"), ("frames/frame_000000.png", "frames[0]"),
                                         ("views/left_2m/frame_000000.png", "views.2")])
def test_fifos_named_by_a_clip_are_refused_at_once(street_clip_path, tmp_path, name, field):
    """A FIFO in place of any file a clip names once blocked the loader for ever; now it is refused at once."""

    folder = _copy(street_clip_path, tmp_path, lambda d, f: None)
    os.remove(folder / name)  # after _copy, which writes clip.json (a write would block on a FIFO too)
    os.mkfifo(folder / name)
    e = refusal_beside_fifo(lambda: clip_mod.load(folder), folder / name, JobError, f"loading the clip's {name}")
    assert "is a FIFO (named pipe)" in str(e) and e.field == field, str(e)
    assert isinstance(e, errors.InputError)


def test_clip_without_poses_uses_vggt_cameras_scaled_to_the_frames(street_clip_path, tmp_path):
    folder = _copy(street_clip_path, tmp_path, lambda d, f: [d.pop("poses"), d.pop("views")])
    c = clip_mod.load(folder)
    assert not c.metric
    np.testing.assert_allclose(c.vggt_to_world, np.eye(4))
    np.testing.assert_allclose(c.K, c.predictions.K, atol=1e-4)  # the street's frames are VGGT's size
    np.testing.assert_allclose(c.world_to_camera[0], np.eye(4), atol=1e-6)
