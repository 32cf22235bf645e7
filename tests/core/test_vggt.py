"""core.vggt: VGGT's file layout in all its variants, its unprojection and confidence semantics, bad files."""

import os
import zipfile

import numpy as np
import pytest

from scpainter_blender.core import cameras as C
from scpainter_blender.core import vggt as V
from tests_support import synthetic_predictions as make_arrays
from vggt_cases import drive, pad, write


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


@pytest.mark.parametrize("key", ["extrinsic", "intrinsic", "images"])
def test_nan_values(tmp_path, key):
    """Non-finite poses, intrinsics or colours stay refusals, naming the frame and what to do."""
    arrays = make_arrays()
    a = arrays[key]
    a.reshape(-1)[a.size // 2 + 1] = np.nan
    with pytest.raises(V.PredictionsError, match=f"'{key}'.*NaN") as e:
        V.load_predictions(save(tmp_path, arrays))
    if key != "images":
        assert "frame 1" in str(e.value) and "re-run VGGT" in str(e.value)


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


# -- files as other tools write them: pose convention, NaN pixels, squeezed axes, padding ----------------------

def test_world_to_camera_file_passes_the_check(tmp_path):
    arrays, w2c, _ = drive()
    pred = V.load_predictions(write(tmp_path, arrays), extrinsic_convention="auto")
    rep = pred.report
    assert rep.extrinsic_convention == "world_to_camera" and rep.convention_checked
    assert np.abs(pred.world_to_camera - w2c).max() < 1e-6
    chk = rep.check
    assert list(chk.frames) == [0, 1, 2, 3] and chk.agrees("world_to_camera") and not chk.agrees("camera_to_world")
    assert chk.relative["world_to_camera"].max() < 0.06   # the 2 % point-head noise, not more
    assert "world-to-camera agrees" in rep.info[0] and not rep.warnings
    # the default (and the backend's reading) does not check, and needs no world_points
    plain = V.load_predictions(write(tmp_path, arrays), world_points=False)
    assert plain.report.check is None and np.array_equal(plain.world_to_camera, pred.world_to_camera)


def test_camera_to_world_file_refused_then_imported_as_such(tmp_path):
    arrays, w2c, _ = drive()
    arrays["extrinsic"] = C.rigid_inverse(w2c)  # what some tools write under 'extrinsic'
    path = write(tmp_path, arrays)
    for world_points in (True, False):  # the check reads world_points even when the caller will not use them
        with pytest.raises(V.PredictionsError) as e:
            V.load_predictions(path, world_points=world_points, extrinsic_convention="auto")
        msg = str(e.value)
        assert msg.startswith("predictions.npz: 'extrinsic': holds camera-to-world poses") and path in msg
        assert "VGGT units" in msg and "inverted poses agree" in msg
        assert "--extrinsic-convention on the command line): camera_to_world (" in msg
    # with a known scale the disagreement is in metres: the median distance of the worst frame, scaled
    with pytest.raises(V.PredictionsError) as e:
        V.load_predictions(path, extrinsic_convention="auto", metres_per_unit=2.0)
    chk = V.check_extrinsic_convention(V.load_predictions(path))
    k = chk.worst("world_to_camera")
    assert f"frame {chk.frames[k]} lands {2.0 * chk.distance['world_to_camera'][k]:.3g} m" in str(e.value)
    pred = V.load_predictions(path, extrinsic_convention="camera_to_world")
    assert pred.report.extrinsic_convention == "camera_to_world" and not pred.report.convention_checked
    assert np.abs(pred.world_to_camera - w2c).max() < 1e-6
    good = V.load_predictions(write(tmp_path, drive()[0], "good.npz"))
    assert np.abs(V.point_cloud(pred, 0.0).positions - V.point_cloud(good, 0.0).positions).max() < 1e-5


def test_camera_to_world_file_of_a_slow_drive_refused(tmp_path):
    """A slow drive: read the wrong way, its frames miss by less than the tolerance that VGGT's point-head noise
    needs, but the inverse fits them decisively better: still refused."""
    arrays, w2c, _ = drive(S=3)
    for i in range(3):  # 0.1 units forward per frame and a 1° turn: metres in a real clip
        yaw = np.radians(1.0 * i)
        R = np.array([[np.cos(yaw), 0, -np.sin(yaw)], [0, 1, 0], [np.sin(yaw), 0, np.cos(yaw)]])
        w2c[i, :3, :3], w2c[i, :3, 3] = R, -R @ np.array([0.0, 0.0, 0.1 * i])
    wp = V.unproject_depth(arrays["depth"], V.vggt_K_to_ours(arrays["intrinsic_vggt"]), w2c)
    wp += np.random.default_rng(1).normal(0.0, 0.01, wp.shape) * arrays["depth"][..., None]  # point-head noise
    arrays["world_points"] = wp.astype(np.float32)
    arrays["extrinsic"] = C.rigid_inverse(w2c)
    path = write(tmp_path, arrays)
    chk = V.check_extrinsic_convention(V.load_predictions(path))
    assert chk.relative["world_to_camera"].max() < V.CONVENTION_TOLERANCE  # inside the tolerance alone
    assert not chk.agrees("world_to_camera") and chk.agrees("camera_to_world")
    with pytest.raises(V.PredictionsError, match="holds camera-to-world poses"):
        V.load_predictions(path, extrinsic_convention="auto")
    arrays["extrinsic"] = w2c  # and the right file of the same drive passes
    assert V.load_predictions(write(tmp_path, arrays, "ok.npz"), extrinsic_convention="auto").report.convention_checked


def test_neither_convention_fits(tmp_path):
    arrays, w2c, _ = drive()
    arrays["world_points"] = drive(seed=1)[0]["world_points"][:, ::-1]  # another depth, mirrored: unrelated
    path = write(tmp_path, arrays)
    with pytest.raises(V.PredictionsError) as e:
        V.load_predictions(path, extrinsic_convention="auto")
    msg = str(e.value)
    assert "'extrinsic': neither reading of the poses fits the file's world_points: in frame" in msg
    assert "VGGT units" in msg and "world_to_camera or camera_to_world (no check)" in msg
    with pytest.raises(V.PredictionsError, match=r"in frame \d the depth lands [\d.]+ m from them"):
        V.load_predictions(path, extrinsic_convention="auto", metres_per_unit=3.0)
    # an explicit convention imports it anyway
    assert V.load_predictions(path, extrinsic_convention="world_to_camera").num_frames == 4


def test_convention_not_checkable_without_world_points(tmp_path):
    arrays, _, _ = drive()
    del arrays["world_points"], arrays["world_points_conf"]
    pred = V.load_predictions(write(tmp_path, arrays), extrinsic_convention="auto")
    rep = pred.report
    assert rep.extrinsic_convention == "world_to_camera" and not rep.convention_checked
    assert "not checked (the file has no world_points)" in rep.warnings[0]
    assert rep.to_json()["extrinsic_convention_checked"] is False
    with pytest.raises(ValueError, match="extrinsic_convention"):
        V.load_predictions(write(tmp_path, arrays), extrinsic_convention="c2w")


def test_nonfinite_pixels_dropped_and_counted(tmp_path):
    arrays, _, _ = drive()
    arrays["depth"][1, 2, 3:6] = np.nan
    arrays["depth_conf"][2, 5, 7] = np.inf
    arrays["depth_conf"][2, 6, 7] = -np.inf
    arrays["world_points"][0, 4, 4, 1] = np.nan
    path = write(tmp_path, arrays)
    pred = V.load_predictions(path, extrinsic_convention="auto")  # the check skips the bad pixels too
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
        pts = V.point_cloud(pred, p)
        assert np.array_equal(np.diff(pts.offsets), keep.reshape(4, -1).sum(1))
        assert np.all(np.isfinite(pts.positions))
    wp = V.point_cloud(pred, 0.0, source="world_points")  # its own bad pixel, and (depth <= 0) the depth ones
    assert len(wp) == 4 * 24 * 32 - 1 - 5 and np.all(np.isfinite(wp.positions))
    g = V.ground_candidates(pred, 0.0)
    assert len(g) == 4 * 10 * 32 - 0 and np.all(np.isfinite(g))  # bad pixels are in the upper rows
    # a frame without a single finite pixel is refused, naming it; so is a frame of NaN world points
    for key, value in (("depth", np.nan), ("depth_conf", np.inf), ("world_points", np.nan)):
        a = {k: np.array(v) for k, v in arrays.items()}
        a[key][2] = value
        with pytest.raises(V.PredictionsError, match=f"'{key}': frame 2 has no pixel with a finite") as e:
            V.load_predictions(write(tmp_path, a, "bad.npz"))
        assert "remove frame 2" in str(e.value) and "bad.npz" in str(e.value)
    # ... but a point map is not read when it is not used
    a = {k: np.array(v) for k, v in arrays.items()}
    a["world_points"][2] = np.nan
    assert V.load_predictions(write(tmp_path, a, "wp.npz"), world_points=False).num_frames == 4


def test_squeezed_one_frame_file(tmp_path):
    arrays, _, _ = drive(S=1)
    base = V.load_predictions(write(tmp_path, arrays, "base.npz"))
    H, W = 24, 32
    for layout in ("chw", "hwc"):
        sq = {"images": np.moveaxis(arrays["images"][0], -1, 0) if layout == "chw" else arrays["images"][0],
              "depth": arrays["depth"][0], "depth_conf": arrays["depth_conf"][0],
              "extrinsic": arrays["extrinsic"][0, :3].astype(np.float32),
              "intrinsic": arrays["intrinsic_vggt"][0].astype(np.float32),
              "world_points": arrays["world_points"][0], "world_points_conf": arrays["world_points_conf"][0]}
        assert sq["depth"].shape == (H, W) and sq["extrinsic"].shape == (3, 4) and sq["intrinsic"].shape == (3, 3)
        pred = V.load_predictions(save(tmp_path, sq, f"{layout}.npz"), extrinsic_convention="auto")
        assert pred.num_frames == 1 and pred.images.shape == (1, H, W, 3)
        assert pred.world_points.shape == (1, H, W, 3) and pred.world_points_conf.shape == (1, H, W)
        for name in ("images", "depth", "depth_conf", "world_to_camera", "intrinsic_vggt", "world_points"):
            assert np.array_equal(getattr(pred, name), getattr(base, name)), name


@pytest.mark.parametrize("top,bottom", [(4, 4), (3, 4)])
def test_padded_file_cropped_like_the_original(tmp_path, top, bottom):
    arrays, _, _ = drive(H=32 - top - bottom, W=32)
    orig = V.load_predictions(write(tmp_path, arrays, "orig.npz"))
    padded = write(tmp_path, pad(arrays, top, bottom))
    uncropped = V.load_predictions(padded)
    assert (uncropped.width, uncropped.height) == (32, 32)
    auto = V.load_predictions(padded, crop="auto", extrinsic_convention="auto")
    explicit = V.load_predictions(padded, crop=f"0 {top} 0 {bottom}")
    as_list = V.load_predictions(padded, crop=[0, top, 0, bottom])
    assert auto.report.crop == explicit.report.crop == (0, top, 0, bottom)
    assert auto.report.crop_requested == "auto" and explicit.report.crop_requested == "explicit"
    assert f"cropped left 0, top {top}, right 0, bottom {bottom} px (VGGT's white padding detected): " \
           f"32 x 32 -> 32 x {32 - top - bottom}" in auto.report.info[0]
    assert auto.report.original_size == (32, 32)
    ref = V.point_cloud(orig, 50.0)
    for pred in (auto, explicit, as_list):
        assert (pred.width, pred.height) == (orig.width, orig.height)
        assert np.array_equal(pred.K, orig.K) and np.array_equal(pred.images, orig.images)
        pts = V.point_cloud(pred, 50.0)
        assert np.array_equal(pts.positions, ref.positions) and np.array_equal(pts.frame, ref.frame)
    # not padded: auto finds nothing
    assert V.load_predictions(write(tmp_path, arrays, "orig.npz"), crop="auto").report.crop == (0, 0, 0, 0)


def test_left_right_padding_and_white_sky_not_cropped(tmp_path):
    arrays, _, _ = drive(H=24, W=16)
    p = write(tmp_path, pad(arrays, 0, 0, left=4, right=4))
    assert V.load_predictions(p, crop="auto").report.crop == (4, 0, 4, 0)
    # a sky of pure white at the top of every frame: top band only, not cropped
    sky = dict(arrays)
    sky["images"] = arrays["images"].copy()
    sky["images"][:, :3] = 1.0
    pred = V.load_predictions(write(tmp_path, sky, "sky.npz"), crop="auto")
    assert pred.report.crop == (0, 0, 0, 0) and pred.height == 24
    assert "white borders (left 0, top 3, right 0, bottom 0 px)" in pred.report.info[0]
    # padding plus a white sky row: the bands are not symmetric, nothing is guessed
    both = pad(sky, 4, 4)
    assert V.load_predictions(write(tmp_path, both, "both.npz"), crop="auto").report.crop == (0, 0, 0, 0)
    # one frame with a non-white border pixel is enough: not padding
    one = pad(arrays, 4, 4)
    one["images"][2, 1, 5, 0] = 0.999
    assert V.load_predictions(write(tmp_path, one, "one.npz"), crop="auto").report.crop == (0, 0, 0, 0)
    white = dict(arrays, images=np.ones_like(arrays["images"]))
    assert V.load_predictions(write(tmp_path, white, "white.npz"), crop="auto").report.crop == (0, 0, 0, 0)


def test_bad_crops(tmp_path):
    arrays, _, _ = drive(H=10, W=12)
    p = write(tmp_path, arrays)
    with pytest.raises(V.PredictionsError, match="predictions.npz: crop left 6 top 0 right 6 bottom 0 leaves"):
        V.load_predictions(p, crop="6 0 6 0")
    for bad in ("1 2 3", "a b c d", "-1 0 0 0", "1.5 0 0 0", [1, 2]):
        with pytest.raises(V.PredictionsError, match="predictions.npz: crop .*'auto', 'none' or four"):
            V.load_predictions(p, crop=bad)
    assert V.parse_crop(None) == V.parse_crop("") == V.parse_crop(" None ") == "none"
    assert V.parse_crop("1,2, 3 4") == (1, 2, 3, 4)


# -- readers that cannot be made to traceback or hang (issue 14) ----------------------------------------------------

@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_fifo_and_directory_refused_at_once(tmp_path):
    import time

    for name in ("pipe.npz", "pipe.txt", "pipe.csv"):
        os.mkfifo(tmp_path / name)
    t = time.perf_counter()
    with pytest.raises(V.PredictionsError, match=r"pipe\.npz: is a FIFO \(named pipe\), not a regular file") as e:
        V.load_predictions(tmp_path / "pipe.npz")
    assert isinstance(e.value, V.files.InputError) and e.value.field == "(file)" and e.value.key is None
    for name in ("pipe.npz", "pipe.txt", "pipe.csv"):
        with pytest.raises(V.PredictionsError, match=rf"{name.replace('.', '[.]')}: is a FIFO"):
            V.load_metric_trajectory(tmp_path / name)
    assert time.perf_counter() - t < 1.0
    with pytest.raises(V.PredictionsError, match="is a directory"):
        V.load_predictions(tmp_path)
    with pytest.raises(V.PredictionsError, match="trajectory file not found"):
        V.load_metric_trajectory(tmp_path / "none.txt")


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
        with pytest.raises(V.PredictionsError, match=f"'{key}': {message}") as e:
            V.load_predictions(save(tmp_path, arrays), extrinsic_convention=convention, crop="auto")
        assert e.value.field == key and e.value.path.endswith("predictions.npz")


def test_zero_frame_file_refused(tmp_path):
    arrays = {k: np.zeros((0,) + v.shape[1:], v.dtype) for k, v in make_arrays().items()}
    with pytest.raises(V.PredictionsError, match="'images': holds no frames"):
        V.load_predictions(save(tmp_path, arrays))


def test_damaged_npz_members_name_file_and_key(tmp_path):
    arrays = make_arrays()
    # a member stored without the .npy suffix
    p = tmp_path / "nosuffix.npz"
    with zipfile.ZipFile(p, "w") as z:
        for k, v in arrays.items():
            buf = __import__("io").BytesIO()
            np.save(buf, v)
            z.writestr(k if k == "depth" else f"{k}.npy", buf.getvalue())
    with pytest.raises(V.PredictionsError, match=r"nosuffix\.npz: 'depth': is stored without the \.npy suffix"):
        V.load_predictions(p)
    # a corrupt deflate stream in one member (savez_compressed, bytes flipped mid-member)
    q = tmp_path / "deflate.npz"
    np.savez_compressed(q, **arrays)
    data = bytearray(q.read_bytes())
    with zipfile.ZipFile(q) as z:
        info = z.getinfo("depth.npy")
    mid = info.header_offset + 30 + len("depth.npy") + info.compress_size // 2
    data[mid:mid + 8] = bytes(b ^ 0xA5 for b in data[mid:mid + 8])
    q.write_bytes(bytes(data))
    with pytest.raises(V.PredictionsError, match=r"deflate\.npz: 'depth': ") as e:
        V.load_predictions(q)
    assert e.value.field == "depth"
    # a header claiming more elements than the member holds (same length, valid CRC)
    with zipfile.ZipFile(save(tmp_path, arrays, "plain.npz")) as z:
        members = {n: z.read(n) for n in z.namelist()}
    members["intrinsic.npy"] = members["intrinsic.npy"].replace(b"(3, 3, 3)", b"(9, 3, 3)")
    r = tmp_path / "claims.npz"
    with zipfile.ZipFile(r, "w") as z:
        for n, b in members.items():
            z.writestr(n, b)
    with pytest.raises(V.PredictionsError, match=r"claims\.npz: 'intrinsic': its header claims shape \(9, 3, 3\)"):
        V.load_predictions(r)
    # a broken header
    members["intrinsic.npy"] = members["intrinsic.npy"].replace(b"'descr'", b"'dexcr'")
    with zipfile.ZipFile(r, "w") as z:
        for n, b in members.items():
            z.writestr(n, b)
    with pytest.raises(V.PredictionsError, match=r"'intrinsic': is not a readable \.npy array \(broken header"):
        V.load_predictions(r)


def test_bad_trajectories_are_clean_errors(tmp_path):
    T = np.tile(np.eye(4), (3, 1, 1))
    cases = {
        "zero.npz": dict(world_to_camera=np.zeros((0, 4, 4))),
        "singular.npz": dict(world_to_camera=np.concatenate([T, np.zeros((1, 4, 4))])),
        "flat.npz": dict(world_to_camera=np.zeros(16)),
        "bool.npz": dict(camera_centers=np.ones((3, 3), bool)),
        "nocentres.npz": dict(camera_centers=np.zeros((0, 3))),
        "neither.npz": dict(other=np.zeros(3)),
        "pickle.npz": dict(world_to_camera=np.array([None], dtype=object)),
    }
    expected = {"zero.npz": "'world_to_camera': holds no poses", "singular.npz": "'world_to_camera': pose 3 is not a "
                "rotation", "flat.npz": r"'world_to_camera': expected \(N, 4, 4\)", "bool.npz": "'camera_centers': is "
                "not an array of numbers", "nocentres.npz": "'camera_centers': holds no poses", "neither.npz":
                r"'world_to_camera': missing.*\['other'\]", "pickle.npz": "'world_to_camera': holds Python objects"}
    for name, arrays in cases.items():
        np.savez(tmp_path / name, **arrays)
        with pytest.raises(V.PredictionsError, match=f"{name}: {expected[name]}"):
            V.load_metric_trajectory(tmp_path / name)
    (tmp_path / "empty.txt").write_text("# nothing but a comment\n")
    (tmp_path / "latin1.txt").write_bytes(b"1 2 3\n4 5 \xe9\n")
    (tmp_path / "zeroq.txt").write_text("0 1 2 3 0 0 0 0\n")
    with open(tmp_path / "huge.txt", "wb") as f:  # sparse: its size alone is refused, nothing is read
        f.truncate(V.MAX_TRAJECTORY_TEXT_BYTES + 1)
    for name, message in (("empty.txt", "holds no poses"), ("latin1.txt", "not a numeric table"),
                          ("huge.txt", "is larger than 256 MB"),
                          ("zeroq.txt", "'quaternion': quaternion of zero length")):
        with pytest.raises(V.PredictionsError, match=f"{name}: {message}"):
            V.load_metric_trajectory(tmp_path / name)
