"""core.vggt: VGGT's file layout in all its variants, its unprojection and confidence semantics, bad files."""

import os
import zipfile

import numpy as np
import pytest

from scpainter_blender.core import cameras as C
from scpainter_blender.core import vggt as V
from tests_support import synthetic_predictions as make_arrays


def save(tmp_path, arrays, name="predictions.npz", **extra):
    p = tmp_path / name
    np.savez(p, **arrays, **extra)
    return str(p)


def vggt_reference_unproject(depth, extrinsic, intrinsic):
    """VGGT's own formula (vggt/utils/geometry.py), written out: integer pixel coordinates, closed-form inverse."""
    S, H, W = depth.shape
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    out = np.zeros((S, H, W, 3))
    for i in range(S):
        fx, fy, cx, cy = intrinsic[i, 0, 0], intrinsic[i, 1, 1], intrinsic[i, 0, 2], intrinsic[i, 1, 2]
        d = depth[i].astype(np.float64)
        cam = np.stack([(u - cx) * d / fx, (v - cy) * d / fy, d], -1)
        R, t = extrinsic[i, :, :3].astype(np.float64), extrinsic[i, :, 3].astype(np.float64)
        out[i] = (cam - t) @ R  # R^T (x - t)
    return out


def test_unprojection_equals_vggt_formula(tmp_path):
    arrays = make_arrays()
    pred = V.load_predictions(save(tmp_path, arrays))
    pts = V.point_cloud(pred, confidence_percentile=0.0)
    ref = vggt_reference_unproject(arrays["depth"][..., 0], arrays["extrinsic"], arrays["intrinsic"])
    assert len(pts) == ref[..., 0].size
    assert np.abs(pts.positions - ref.reshape(-1, 3)).max() < 1e-9
    assert np.array_equal(pts.frame, np.repeat(np.arange(3), 14 * 21))
    assert np.allclose(pts.colors, np.moveaxis(arrays["images"], 1, -1).reshape(-1, 3))
    # our K is VGGT's with the principal point moved half a pixel
    assert np.allclose(pred.K[:, :2, 2], arrays["intrinsic"][:, :2, 2] + 0.5)


@pytest.mark.parametrize("variant", ["batch", "ext44", "hwc", "uint8", "depth3d", "all"])
def test_layout_variants_load_identically(tmp_path, variant):
    arrays = make_arrays()
    base = V.load_predictions(save(tmp_path, arrays, "base.npz"))
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
    pred = V.load_predictions(save(tmp_path, a))
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
    pred = V.load_predictions(p)
    assert pred.num_frames == 3


def test_confidence_semantics_match_vggt_demo(tmp_path):
    arrays = make_arrays(S=4)
    arrays["depth_conf"][0, 0, :5] = 0.0  # below 1e-5: always dropped
    pred = V.load_predictions(save(tmp_path, arrays))
    for p in (0.0, 10.0, 50.0, 90.0):
        conf = arrays["depth_conf"].reshape(-1)
        thr = np.percentile(conf, p)
        expected = (conf >= thr) & (conf > 1e-5)  # the demo: percentile over the whole clip
        pts = V.point_cloud(pred, confidence_percentile=p)
        assert len(pts) == expected.sum()
        per_frame = expected.reshape(4, -1).sum(1)
        assert np.array_equal(np.diff(pts.offsets), per_frame)
    with pytest.raises(ValueError):
        V.point_cloud(pred, confidence_percentile=101)


def test_world_points_source(tmp_path):
    arrays = make_arrays()
    pred = V.load_predictions(save(tmp_path, arrays))
    pts = V.point_cloud(pred, confidence_percentile=50.0, source="world_points")
    conf = arrays["world_points_conf"]
    keep = conf >= np.percentile(conf, 50)
    assert np.allclose(pts.positions, arrays["world_points"][keep].astype(np.float64))
    no_wp = {k: v for k, v in arrays.items() if not k.startswith("world_points")}
    pred2 = V.load_predictions(save(tmp_path, no_wp, "b.npz"))
    with pytest.raises(V.PredictionsError, match="world_points"):
        V.point_cloud(pred2, source="world_points")


def test_world_from_vggt_applied_in_float64(tmp_path):
    arrays = make_arrays()
    pred = V.load_predictions(save(tmp_path, arrays))
    M = C.similarity_matrix(12.5, V.BLENDER_FROM_OPENCV_AXES, [1e5, -1e5, 3.0])
    a = V.point_cloud(pred, 0.0)
    b = V.point_cloud(pred, 0.0, world_from_vggt=M)
    assert np.abs(b.positions - (12.5 * a.positions @ V.BLENDER_FROM_OPENCV_AXES.T + M[:3, 3])).max() < 1e-9


def test_points_behind_camera_dropped(tmp_path):
    arrays = make_arrays()
    arrays["depth"][1, 3, 4, 0] = -1.0
    arrays["depth"][1, 3, 5, 0] = 0.0
    pred = V.load_predictions(save(tmp_path, arrays))
    assert len(V.point_cloud(pred, 0.0)) == 3 * 14 * 21 - 2


# -- bad files ---------------------------------------------------------------------------------------------------

def test_truncated_file(tmp_path):
    p = save(tmp_path, make_arrays())
    data = open(p, "rb").read()
    t = tmp_path / "truncated.npz"
    t.write_bytes(data[: len(data) // 2])
    with pytest.raises(V.PredictionsError, match="truncated.npz"):
        V.load_predictions(t)


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
    with pytest.raises(V.PredictionsError, match="'depth'"):
        V.load_predictions(p)


def test_not_a_file_and_not_an_npz(tmp_path):
    with pytest.raises(V.PredictionsError, match="not found"):
        V.load_predictions(tmp_path / "missing.npz")
    bad = tmp_path / "text.npz"
    bad.write_text("hello")
    with pytest.raises(V.PredictionsError, match="text.npz"):
        V.load_predictions(bad)


@pytest.mark.parametrize("key", V.REQUIRED_KEYS)
def test_missing_key(tmp_path, key):
    arrays = make_arrays()
    del arrays[key]
    with pytest.raises(V.PredictionsError, match=f"'{key}'.*missing"):
        V.load_predictions(save(tmp_path, arrays))


@pytest.mark.parametrize("key,shape", [
    ("depth", (3, 14, 20, 1)), ("depth_conf", (2, 14, 21)), ("extrinsic", (3, 4, 3)), ("intrinsic", (3, 3)),
    ("images", (3, 4, 14, 21)), ("world_points", (3, 14, 21, 2)),
])
def test_wrong_shapes(tmp_path, key, shape):
    arrays = make_arrays()
    arrays[key] = np.ones(shape, np.float32)
    with pytest.raises(V.PredictionsError, match=f"'{key}'") as e:
        V.load_predictions(save(tmp_path, arrays))
    assert "predictions.npz" in str(e.value)


@pytest.mark.parametrize("key", ["depth", "depth_conf", "extrinsic", "intrinsic", "images", "world_points"])
def test_nan_values(tmp_path, key):
    arrays = make_arrays()
    a = arrays[key]
    a.reshape(-1)[a.size // 2 + 1] = np.nan
    with pytest.raises(V.PredictionsError, match=f"'{key}'.*NaN"):
        V.load_predictions(save(tmp_path, arrays))


def test_not_a_rotation(tmp_path):
    arrays = make_arrays()
    arrays["extrinsic"][2, :, :3] *= 2.0
    with pytest.raises(V.PredictionsError, match="frame 2 is not a rotation"):
        V.load_predictions(save(tmp_path, arrays))


def test_images_out_of_range(tmp_path):
    arrays = make_arrays()
    arrays["images"] = arrays["images"] * 255.0
    with pytest.raises(V.PredictionsError, match="'images'.*\\[0, 1\\]"):
        V.load_predictions(save(tmp_path, arrays))


def test_object_array_in_required_key(tmp_path):
    arrays = make_arrays()
    arrays["intrinsic"] = np.array([None, None], dtype=object)
    with pytest.raises(V.PredictionsError, match="'intrinsic'.*numeric"):
        V.load_predictions(save(tmp_path, arrays))


def test_save_round_trip(tmp_path):
    arrays = make_arrays()
    pred = V.load_predictions(save(tmp_path, arrays))
    out = tmp_path / "saved.npz"
    V.save_predictions(out, pred.images, pred.depth, pred.depth_conf, pred.world_to_camera, pred.intrinsic_vggt,
                       pred.world_points, pred.world_points_conf)
    with np.load(out) as z:
        assert z["depth"].shape == (3, 14, 21, 1) and z["extrinsic"].shape == (3, 3, 4)
        assert z["images"].shape == (3, 3, 14, 21) and z["images"].dtype == np.float32
    again = V.load_predictions(out)
    assert np.array_equal(again.depth, pred.depth)
    assert not [f for f in os.listdir(tmp_path) if ".tmp" in f]


# -- metric scale ------------------------------------------------------------------------------------------------

def test_scale_factor():
    fit = V.world_from_vggt_by_factor(4.0)
    assert np.allclose(fit.world_from_vggt[:3, :3], 4.0 * V.BLENDER_FROM_OPENCV_AXES)
    with pytest.raises(ValueError):
        V.world_from_vggt_by_factor(-1.0)


def test_trajectory_files(tmp_path):
    rng = np.random.default_rng(0)
    S = 6
    T = np.tile(np.eye(4), (S, 1, 1))
    T[:, :3, 3] = rng.normal(0, 3, (S, 3))
    centres = C.camera_centers(T)
    np.savez(tmp_path / "t.npz", world_to_camera=T)
    np.savetxt(tmp_path / "xyz.txt", centres)
    np.savetxt(tmp_path / "xyz.csv", centres, delimiter=",")
    tum = np.concatenate([np.arange(S)[:, None], centres, np.tile([0, 0, 0, 1.0], (S, 1))], 1)
    np.savetxt(tmp_path / "tum.txt", tum, header="timestamp tx ty tz qx qy qz qw")
    w, c = V.load_metric_trajectory(tmp_path / "t.npz", S)
    assert np.allclose(w, T) and np.allclose(c, centres)
    for name in ("xyz.txt", "xyz.csv"):
        w, c = V.load_metric_trajectory(tmp_path / name, S)
        assert w is None and np.allclose(c, centres)
    w, c = V.load_metric_trajectory(tmp_path / "tum.txt", S)
    assert np.allclose(w, T) and np.allclose(c, centres)
    with pytest.raises(V.PredictionsError, match="6 poses but the clip has 7"):
        V.load_metric_trajectory(tmp_path / "t.npz", 7)
    (tmp_path / "bad.txt").write_text("1 2\n3 4\n")
    with pytest.raises(V.PredictionsError, match="bad.txt"):
        V.load_metric_trajectory(tmp_path / "bad.txt")


def test_camera_height_fit_levels_the_world():
    """Ground plane y = 1 in a camera frame pitched down 10°: scale and levelling are exact."""
    pitch = np.radians(10)
    R = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
    S = 5
    T = np.tile(np.eye(4), (S, 1, 1))
    centres = np.stack([np.zeros(S), np.zeros(S), np.arange(S) * 0.5], 1)  # moving forward, 0.8 units high
    T[:, :3, :3] = R
    T[:, :3, 3] = -centres @ R.T
    plane = np.array([0.0, 1.0, 0.0, -0.8])  # y = 0.8 below the cameras (OpenCV y is down)
    fit = V.world_from_vggt_by_camera_height(plane, T, camera_height=1.6)
    assert fit.scale == pytest.approx(2.0)
    assert fit.residual_m < 1e-12
    w = C.transform_world_to_camera(T, fit.world_from_vggt)
    c = C.camera_centers(w)
    assert np.allclose(c[:, 2], 1.6) and np.allclose(c[0, :2], 0.0)
    assert np.allclose(np.diff(c[:, 0]), 0.0) and np.all(np.diff(c[:, 1]) > 0)  # drives along +Y
    on_plane = np.array([3.0, 0.8, 7.0])  # any point with y = 0.8 lies on the ground
    assert abs((fit.world_from_vggt @ [*on_plane, 1.0])[2]) < 1e-12
