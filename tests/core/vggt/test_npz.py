"""core.vggt.npz: VGGT's file layout in all its variants, NaN/inf pixels, and bad files refused naming file and key."""

import os
import zipfile

import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core import errors
from scpainter_blender.core.geometry import point_cloud
from scpainter_blender.core.vggt import predictions as vggt, npz as vggt_io
from tests_support import synthetic_predictions as make_arrays
from vggt_cases import drive, write
from tests.core.vggt.vggt_fixtures import save


@pytest.mark.parametrize("variant", ["batch", "ext44", "hwc", "uint8", "depth3d", "all"])
def test_layout_variants_load_identically(tmp_path, variant):
    arrays = make_arrays()
    base = vggt_io.load_predictions(save(tmp_path, arrays, "base.npz"))
    a = dict(arrays)
    if variant in ("batch", "all"):
        a = {k: v[None] for k, v in a.items()}
    if variant in ("ext44", "all"):
        e = C.as_matrix4(arrays["extrinsic"]).astype(np.float32)
        a["extrinsic"] = e[None] if variant == "all" else e
    if variant in ("hwc", "all"):
        im = np.moveaxis(arrays["images"], 1, -1)
        a["images"] = im[None] if variant == "all" else im
    if variant == "uint8":
        a["images"] = np.round(arrays["images"] * 255).astype(np.uint8)
    if variant == "depth3d":
        a["depth"] = arrays["depth"][..., 0]
    pred = vggt_io.load_predictions(save(tmp_path, a))
    assert np.array_equal(pred.depth, base.depth)
    assert np.array_equal(pred.world_to_camera, base.world_to_camera)
    assert np.array_equal(pred.intrinsic_vggt, base.intrinsic_vggt)
    tol = 0.5 / 255 + 1e-7 if variant == "uint8" else 0.0
    assert np.abs(pred.images - base.images).max() <= tol
    assert pred.images.shape == (3, 14, 21, 3)


def test_pickled_extra_key_is_ignored(tmp_path):
    """Newer demo files hold pose_enc_list = None (an object array): it must not stop the load."""
    arrays = make_arrays()
    p = save(tmp_path, arrays, pose_enc_list=np.array(None, dtype=object))
    pred = vggt_io.load_predictions(p)
    assert pred.num_frames == 3


def test_squeezed_one_frame_file(tmp_path):
    arrays, _, _ = drive(S=1)
    base = vggt_io.load_predictions(write(tmp_path, arrays, "base.npz"))
    H, W = 24, 32
    for layout in ("chw", "hwc"):
        sq = {"images": np.moveaxis(arrays["images"][0], -1, 0) if layout == "chw" else arrays["images"][0],
              "depth": arrays["depth"][0], "depth_conf": arrays["depth_conf"][0],
              "extrinsic": arrays["extrinsic"][0, :3].astype(np.float32),
              "intrinsic": arrays["intrinsic_vggt"][0].astype(np.float32),
              "world_points": arrays["world_points"][0], "world_points_conf": arrays["world_points_conf"][0]}
        assert sq["depth"].shape == (H, W) and sq["extrinsic"].shape == (3, 4) and sq["intrinsic"].shape == (3, 3)
        pred = vggt_io.load_predictions(save(tmp_path, sq, f"{layout}.npz"), extrinsic_convention="auto")
        assert pred.num_frames == 1 and pred.images.shape == (1, H, W, 3)
        assert pred.world_points.shape == (1, H, W, 3) and pred.world_points_conf.shape == (1, H, W)
        for name in ("images", "depth", "depth_conf", "world_to_camera", "intrinsic_vggt", "world_points"):
            assert np.array_equal(getattr(pred, name), getattr(base, name)), name


def test_save_round_trip(tmp_path):
    arrays = make_arrays()
    pred = vggt_io.load_predictions(save(tmp_path, arrays))
    out = tmp_path / "saved.npz"
    vggt_io.save_predictions(out, pred.images, pred.depth, pred.depth_conf, pred.world_to_camera,
                             pred.intrinsic_vggt, pred.world_points, pred.world_points_conf)
    with np.load(out) as z:
        assert z["depth"].shape == (3, 14, 21, 1) and z["extrinsic"].shape == (3, 3, 4)
        assert z["images"].shape == (3, 3, 14, 21) and z["images"].dtype == np.float32
    again = vggt_io.load_predictions(out)
    assert np.array_equal(again.depth, pred.depth)
    assert not [f for f in os.listdir(tmp_path) if ".tmp" in f]


def test_nonfinite_pixels_dropped_and_counted(tmp_path):
    arrays, _, _ = drive()
    arrays["depth"][1, 2, 3:6] = np.nan
    arrays["depth_conf"][2, 5, 7] = np.inf
    arrays["depth_conf"][2, 6, 7] = -np.inf
    arrays["world_points"][0, 4, 4, 1] = np.nan
    path = write(tmp_path, arrays)
    pred = vggt_io.load_predictions(path, extrinsic_convention="auto")  # the check skips the bad pixels too
    rep = pred.report
    assert rep.nonfinite == {"depth": [0, 3, 0, 0], "depth_conf": [0, 0, 2, 0], "world_points": [1, 0, 0, 0]}
    assert rep.dropped_pixels == [0, 3, 2, 0] and rep.convention_checked
    assert "dropped 5 pixels with NaN/inf depth or confidence (frame 1: 3, frame 2: 2)" in rep.warnings
    assert np.all(np.isfinite(pred.depth)) and np.all(np.isfinite(pred.depth_conf))
    bad = ~np.isfinite(arrays["depth"]) | ~np.isfinite(arrays["depth_conf"])
    assert np.array_equal(pred.valid, ~bad)
    # the points: the clean pixels, filtered by the percentile of the clean confidences
    conf = arrays["depth_conf"]
    for p in (0.0, 50.0):
        keep = ~bad & (conf >= np.percentile(conf[~bad], p))
        pts = point_cloud.point_cloud(pred, p)
        assert np.array_equal(np.diff(pts.offsets), keep.reshape(4, -1).sum(1))
        assert np.all(np.isfinite(pts.positions))
    wp = point_cloud.point_cloud(pred, 0.0, source="world_points")  # its own bad pixel, and (depth <= 0) the depth
    assert len(wp) == 4 * 24 * 32 - 1 - 5 and np.all(np.isfinite(wp.positions))
    g = point_cloud.ground_candidates(pred, 0.0)
    assert len(g) == 4 * 10 * 32 - 0 and np.all(np.isfinite(g))  # bad pixels are in the upper rows
    # a frame without a single finite pixel is refused, naming it; so is a frame of NaN world points
    for key, value in (("depth", np.nan), ("depth_conf", np.inf), ("world_points", np.nan)):
        a = {k: np.array(v) for k, v in arrays.items()}
        a[key][2] = value
        with pytest.raises(vggt.PredictionsError, match=f"'{key}': frame 2 has no pixel with a finite") as e:
            vggt_io.load_predictions(write(tmp_path, a, "bad.npz"))
        assert "remove frame 2" in str(e.value) and "bad.npz" in str(e.value)
    # ... but a point map is not read when it is not used
    a = {k: np.array(v) for k, v in arrays.items()}
    a["world_points"][2] = np.nan
    assert vggt_io.load_predictions(write(tmp_path, a, "wp.npz"), world_points=False).num_frames == 4


# -- bad files -------------------------------------------------------------------------------------------------------


def test_truncated_file(tmp_path):
    p = save(tmp_path, make_arrays())
    data = open(p, "rb").read()
    t = tmp_path / "truncated.npz"
    t.write_bytes(data[: len(data) // 2])
    with pytest.raises(vggt.PredictionsError, match="truncated.npz"):
        vggt_io.load_predictions(t)


def test_corrupt_member(tmp_path):
    """A zip whose directory is fine but one array's bytes are cut."""
    p = tmp_path / "cut.npz"
    arrays = make_arrays()
    with zipfile.ZipFile(p, "w") as z:
        for k, v in arrays.items():
            path = tmp_path / f"{k}.npy"
            np.save(path, v)
            data = path.read_bytes()
            z.writestr(f"{k}.npy", data[:200] if k == "depth" else data)
    with pytest.raises(vggt.PredictionsError, match="'depth'"):
        vggt_io.load_predictions(p)


def test_not_a_file_and_not_an_npz(tmp_path):
    with pytest.raises(vggt.PredictionsError, match="not found"):
        vggt_io.load_predictions(tmp_path / "missing.npz")
    bad = tmp_path / "text.npz"
    bad.write_text("hello")
    with pytest.raises(vggt.PredictionsError, match="text.npz"):
        vggt_io.load_predictions(bad)


@pytest.mark.parametrize("key", vggt.REQUIRED_KEYS)
def test_missing_key(tmp_path, key):
    arrays = make_arrays()
    del arrays[key]
    with pytest.raises(vggt.PredictionsError, match=f"'{key}'.*missing"):
        vggt_io.load_predictions(save(tmp_path, arrays))


@pytest.mark.parametrize("key,shape", [
    ("depth", (3, 14, 20, 1)), ("depth_conf", (2, 14, 21)), ("extrinsic", (3, 4, 3)), ("intrinsic", (3, 3)),
    ("images", (3, 4, 14, 21)), ("world_points", (3, 14, 21, 2)),
])
def test_wrong_shapes(tmp_path, key, shape):
    arrays = make_arrays()
    arrays[key] = np.ones(shape, np.float32)
    with pytest.raises(vggt.PredictionsError, match=f"'{key}'") as e:
        vggt_io.load_predictions(save(tmp_path, arrays))
    assert "predictions.npz" in str(e.value)


@pytest.mark.parametrize("key", ["extrinsic", "intrinsic", "images"])
def test_nan_values(tmp_path, key):
    """Non-finite poses, intrinsics or colours stay refusals, naming the frame and what to do."""
    arrays = make_arrays()
    a = arrays[key]
    a.reshape(-1)[a.size // 2 + 1] = np.nan
    with pytest.raises(vggt.PredictionsError, match=f"'{key}'.*NaN") as e:
        vggt_io.load_predictions(save(tmp_path, arrays))
    if key != "images":
        assert "frame 1" in str(e.value) and "re-run VGGT" in str(e.value)


def test_not_a_rotation(tmp_path):
    arrays = make_arrays()
    arrays["extrinsic"][2, :, :3] *= 2.0
    with pytest.raises(vggt.PredictionsError, match="frame 2 is not a rotation"):
        vggt_io.load_predictions(save(tmp_path, arrays))


def test_skewed_or_projective_intrinsic_refused(tmp_path):
    """Unprojection and Blender cameras assume [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]: anything else is refused
    naming the frame, never placed with the skew silently ignored."""
    for row, col, value in ((0, 1, 0.5), (1, 0, 0.2), (2, 0, 1e-3), (2, 2, 2.0)):
        arrays = make_arrays()
        arrays["intrinsic"][1, row, col] = value
        with pytest.raises(vggt.PredictionsError, match=r"'intrinsic': frame 1 is not \[\[fx, 0, cx\]") as e:
            vggt_io.load_predictions(save(tmp_path, arrays))
        assert e.value.field == "intrinsic" and "no skew" in str(e.value)


def test_images_out_of_range(tmp_path):
    arrays = make_arrays()
    arrays["images"] = arrays["images"] * 255.0
    with pytest.raises(vggt.PredictionsError, match="'images'.*\\[0, 1\\]"):
        vggt_io.load_predictions(save(tmp_path, arrays))


def test_object_array_in_required_key(tmp_path):
    arrays = make_arrays()
    arrays["intrinsic"] = np.array([None, None], dtype=object)
    with pytest.raises(vggt.PredictionsError, match="'intrinsic'.*numeric"):
        vggt_io.load_predictions(save(tmp_path, arrays))


# -- readers that cannot be made to traceback or hang (issue 14) -----------------------------------------------------


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_fifo_and_directory_refused_at_once(tmp_path):
    import time

    os.mkfifo(tmp_path / "pipe.npz")
    t = time.perf_counter()
    with pytest.raises(vggt.PredictionsError, match=r"pipe\.npz: is a FIFO \(named pipe\), not a regular file") as e:
        vggt_io.load_predictions(tmp_path / "pipe.npz")
    assert isinstance(e.value, errors.InputError) and e.value.field == "(file)" and e.value.key is None
    assert time.perf_counter() - t < 1.0
    with pytest.raises(vggt.PredictionsError, match="is a directory"):
        vggt_io.load_predictions(tmp_path)


@pytest.mark.parametrize("key, array, message", [
    ("images", np.zeros((0, 3, 14, 21), np.float32), "holds no frames"),
    ("images", np.zeros((3, 3, 0, 21), np.float32), "has images of 21 x 0 pixels"),
    ("images", np.zeros((3, 3, 14, 0), np.float32), "has images of 0 x 14 pixels"),
    ("images", np.zeros(5, np.float32), r"expected \(S, 3, H, W\)"),
    ("images", np.zeros((3, 3, 14, 21), bool), "is not an array of numbers"),
    ("depth", np.zeros((0, 14, 21, 1), np.float32), r"expected shape .* got \(0, 14, 21, 1\)"),
    ("depth", np.ones((3, 14, 21, 1), np.uint16), "holds integers .* millimetres"),
    ("depth_conf", np.ones((3, 14, 21), bool), "is not an array of numbers"),
    ("extrinsic", np.ones(3, np.float32), r"expected \(3, 3, 4\) or \(3, 4, 4\), got \(3,\)"),
    ("extrinsic", np.zeros((3, 3, 4), np.float32), "frame 0 is not a rotation"),
    ("intrinsic", np.float32(1.0), r"expected \(3, 3, 3\), got \(\)"),
    ("world_points", np.ones((3, 14, 21, 3), np.int32), "holds integers"),
    ("world_points_conf", np.ones((3, 14, 21, 0), np.float32), "expected shape"),
])
def test_odd_shapes_and_dtypes_name_the_key(tmp_path, key, array, message):
    """Zero frames, empty or 1-D arrays, integers and booleans where VGGT writes floats: a PredictionsError naming
    the key, never a numpy traceback from a later step."""
    arrays = make_arrays()
    arrays[key] = array
    for convention in ("world_to_camera", "auto"):
        with pytest.raises(vggt.PredictionsError, match=f"'{key}': {message}") as e:
            vggt_io.load_predictions(save(tmp_path, arrays), extrinsic_convention=convention, crop="auto")
        assert e.value.field == key and e.value.path.endswith("predictions.npz")


def test_zero_frame_file_refused(tmp_path):
    arrays = {k: np.zeros((0,) + v.shape[1:], v.dtype) for k, v in make_arrays().items()}
    with pytest.raises(vggt.PredictionsError, match="'images': holds no frames"):
        vggt_io.load_predictions(save(tmp_path, arrays))


def test_damaged_npz_members_name_file_and_key(tmp_path):
    arrays = make_arrays()
    # a member stored without the .npy suffix
    p = tmp_path / "nosuffix.npz"
    with zipfile.ZipFile(p, "w") as z:
        for k, v in arrays.items():
            buf = __import__("io").BytesIO()
            np.save(buf, v)
            z.writestr(k if k == "depth" else f"{k}.npy", buf.getvalue())
    with pytest.raises(vggt.PredictionsError, match=r"nosuffix\.npz: 'depth': is stored without the \.npy suffix"):
        vggt_io.load_predictions(p)
    # a corrupt deflate stream in one member (savez_compressed, bytes flipped mid-member)
    q = tmp_path / "deflate.npz"
    np.savez_compressed(q, **arrays)
    data = bytearray(q.read_bytes())
    with zipfile.ZipFile(q) as z:
        info = z.getinfo("depth.npy")
    mid = info.header_offset + 30 + len("depth.npy") + info.compress_size // 2
    data[mid:mid + 8] = bytes(b ^ 0xA5 for b in data[mid:mid + 8])
    q.write_bytes(bytes(data))
    with pytest.raises(vggt.PredictionsError, match=r"deflate\.npz: 'depth': ") as e:
        vggt_io.load_predictions(q)
    assert e.value.field == "depth"
    # a header claiming more elements than the member holds (same length, valid CRC)
    with zipfile.ZipFile(save(tmp_path, arrays, "plain.npz")) as z:
        members = {n: z.read(n) for n in z.namelist()}
    members["intrinsic.npy"] = members["intrinsic.npy"].replace(b"(3, 3, 3)", b"(9, 3, 3)")
    r = tmp_path / "claims.npz"
    with zipfile.ZipFile(r, "w") as z:
        for n, b in members.items():
            z.writestr(n, b)
    with pytest.raises(vggt.PredictionsError, match=r"claims\.npz: 'intrinsic': its header claims shape \(9, 3, 3\)"):
        vggt_io.load_predictions(r)
    # a broken header
    members["intrinsic.npy"] = members["intrinsic.npy"].replace(b"'descr'", b"'dexcr'")
    with zipfile.ZipFile(r, "w") as z:
        for n, b in members.items():
            z.writestr(n, b)
    with pytest.raises(vggt.PredictionsError, match=r"'intrinsic': is not a readable \.npy array \(broken header"):
        vggt_io.load_predictions(r)
