"""core.geometry.metric_scale: vggt_to_world by factor, trajectory and camera height; metric trajectory files."""

import os

import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core.geometry import metric_scale, similarity
from scpainter_blender.core.vggt import predictions as vggt


def test_scale_factor():
    fit = metric_scale.vggt_to_world_by_factor(4.0)
    assert np.allclose(fit.vggt_to_world[:3, :3], 4.0 * metric_scale.OPENCV_TO_BLENDER_AXES)
    with pytest.raises(ValueError):
        metric_scale.vggt_to_world_by_factor(-1.0)


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
    w, c = metric_scale.load_metric_trajectory(tmp_path / "t.npz", S)
    assert np.allclose(w, T) and np.allclose(c, centres)
    for name in ("xyz.txt", "xyz.csv"):
        w, c = metric_scale.load_metric_trajectory(tmp_path / name, S)
        assert w is None and np.allclose(c, centres)
    w, c = metric_scale.load_metric_trajectory(tmp_path / "tum.txt", S)
    assert np.allclose(w, T) and np.allclose(c, centres)
    with pytest.raises(vggt.PredictionsError, match="6 poses but the clip has 7"):
        metric_scale.load_metric_trajectory(tmp_path / "t.npz", 7)
    (tmp_path / "bad.txt").write_text("1 2\n3 4\n")
    with pytest.raises(vggt.PredictionsError, match="bad.txt"):
        metric_scale.load_metric_trajectory(tmp_path / "bad.txt")


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
        with pytest.raises(vggt.PredictionsError, match=f"{name}: {expected[name]}"):
            metric_scale.load_metric_trajectory(tmp_path / name)
    (tmp_path / "empty.txt").write_text("# nothing but a comment\n")
    (tmp_path / "latin1.txt").write_bytes(b"1 2 3\n4 5 \xe9\n")
    (tmp_path / "zeroq.txt").write_text("0 1 2 3 0 0 0 0\n")
    with open(tmp_path / "huge.txt", "wb") as f:  # sparse: its size alone is refused, nothing is read
        f.truncate(metric_scale.MAX_TRAJECTORY_TEXT_BYTES + 1)
    for name, message in (("empty.txt", "holds no poses"), ("latin1.txt", "not a numeric table"),
                          ("huge.txt", "is larger than 256 MB"),
                          ("zeroq.txt", "'quaternion': quaternion of zero length")):
        with pytest.raises(vggt.PredictionsError, match=f"{name}: {message}"):
            metric_scale.load_metric_trajectory(tmp_path / name)


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
    fit = metric_scale.vggt_to_world_by_camera_height(plane, T, camera_height=1.6)
    assert fit.scale == pytest.approx(2.0)
    assert fit.residual_m < 1e-12
    w = similarity.transform_world_to_camera(T, fit.vggt_to_world)
    c = C.camera_centers(w)
    assert np.allclose(c[:, 2], 1.6) and np.allclose(c[0, :2], 0.0)
    assert np.allclose(np.diff(c[:, 0]), 0.0) and np.all(np.diff(c[:, 1]) > 0)  # drives along +Y
    on_plane = np.array([3.0, 0.8, 7.0])  # any point with y = 0.8 lies on the ground
    assert abs((fit.vggt_to_world @ [*on_plane, 1.0])[2]) < 1e-12


def test_fits_the_data_cannot_give_name_the_file():
    """A straight path given as centres alone cannot fix the roll; cameras on the plane or looking straight down
    give no height or heading: PredictionsErrors naming the file and key, not bare ValueErrors."""
    S = 6
    vggt_w2c = np.tile(np.eye(4), (S, 1, 1))
    vggt_w2c[:, 2, 3] = -np.arange(S) * 0.1
    straight = np.stack([np.zeros(S), np.arange(S) * 2.0, np.full(S, 1.6)], 1)
    with pytest.raises(vggt.PredictionsError, match=r"drive\.txt: 'camera_centers': cannot give the metric scale: "
                                                    "points are .*collinear") as e:
        metric_scale.vggt_to_world_by_trajectory(vggt_w2c, metric_centers=straight, path="drive.txt")
    assert e.value.field == "camera_centers"
    # with orientations the same straight drive fits (test_cameras' fit_similarity_to_cameras), backwards it cannot
    metric_w2c = similarity.transform_world_to_camera(vggt_w2c, similarity.similarity_matrix(2.0, np.eye(3), [0] * 3))
    assert metric_scale.vggt_to_world_by_trajectory(vggt_w2c, metric_w2c).scale == pytest.approx(2.0)
    backwards = metric_w2c[::-1].copy()
    with pytest.raises(vggt.PredictionsError, match="'world_to_camera': cannot give the metric scale: .*opposite"):
        metric_scale.vggt_to_world_by_trajectory(vggt_w2c, backwards, path="drive.npz")
    on_plane = np.array([0.0, 1.0, 0.0, 0.0])  # y = 0 through every camera centre
    with pytest.raises(vggt.PredictionsError, match=r"p\.npz: the cameras lie on the ground plane"):
        metric_scale.vggt_to_world_by_camera_height(on_plane, vggt_w2c, 1.6, path="p.npz")
    down = np.tile(np.eye(4), (S, 1, 1))
    down[:, :3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # camera +z along world -y: straight at the plane y = -2
    with pytest.raises(vggt.PredictionsError, match=r"'extrinsic': frame 0 looks straight down"):
        metric_scale.vggt_to_world_by_camera_height([0.0, 1.0, 0.0, 2.0], down, 1.6, path="p.npz")
    with pytest.raises(ValueError, match="camera height must be a positive number"):
        metric_scale.vggt_to_world_by_camera_height(on_plane, vggt_w2c, -1.0)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_trajectory_fifo_refused_at_once(tmp_path):
    import time

    for name in ("pipe.npz", "pipe.txt", "pipe.csv"):
        os.mkfifo(tmp_path / name)
    t = time.perf_counter()
    for name in ("pipe.npz", "pipe.txt", "pipe.csv"):
        with pytest.raises(vggt.PredictionsError, match=rf"{name.replace('.', '[.]')}: is a FIFO"):
            metric_scale.load_metric_trajectory(tmp_path / name)
    assert time.perf_counter() - t < 1.0
    with pytest.raises(vggt.PredictionsError, match="trajectory file not found"):
        metric_scale.load_metric_trajectory(tmp_path / "none.txt")


def _road(S=4, H=40, W=60, height=0.8, seed=0):
    """Predictions of cameras ``height`` VGGT units over a flat road (OpenCV y = height in every camera frame,
    driving along +z): the lower rows see the road, the upper ones a far wall."""
    from scpainter_blender.core.geometry import unproject
    from scpainter_blender.core.vggt import npz

    rng = np.random.default_rng(seed)
    w2c = np.tile(np.eye(4), (S, 1, 1))
    w2c[:, 2, 3] = -0.5 * np.arange(S)
    intr = np.tile(np.array([[30.0, 0, W / 2 - 0.5], [0, 30.0, H / 2 - 0.5], [0, 0, 1]]), (S, 1, 1))  # VGGT's K
    ray_y = unproject.unproject_depth(np.ones((S, H, W)), vggt.vggt_K_to_ours(intr), np.tile(np.eye(4), (S, 1, 1)))
    ray_y = ray_y[..., 1]
    depth = np.where(ray_y > 0.05, height / np.maximum(ray_y, 0.05), 20.0).astype(np.float32)
    arrays = {"images": rng.random((S, H, W, 3), dtype=np.float32), "depth": depth,
              "depth_conf": (1.0 + rng.exponential(2.0, (S, H, W))).astype(np.float32),
              "extrinsic": w2c[:, :3].astype(np.float32), "intrinsic": intr.astype(np.float32)}
    return npz.predictions_from_arrays(arrays, "road.npz")


def test_camera_height_fit_finds_the_road_in_predictions():
    """Candidates → RANSAC plane → scale: cameras 0.8 units over the road at 1.6 m give 2 m per unit, the road
    z = 0; seeded, so the same matrix every time; its details carry the plane fit's figures."""
    pred = _road()
    fit = metric_scale.camera_height_fit(pred, 1.6)
    assert fit.method == "camera_height" and fit.scale == pytest.approx(2.0, rel=1e-4)
    assert fit.residual_m < 1e-4
    c = C.camera_centers(similarity.transform_world_to_camera(pred.world_to_camera, fit.vggt_to_world))
    assert np.allclose(c[:, 2], 1.6, atol=1e-4)
    d = fit.details
    assert d["candidates"] > 100 and d["inliers"] > 0.9 * d["candidates"] and d["nonfinite_candidates"] == 0
    assert {"inlier_rms_vggt", "tilt_deg", "threshold_vggt", "plane_inlier_rms_m"} <= set(d)
    again = metric_scale.camera_height_fit(pred, 1.6)
    assert np.array_equal(fit.vggt_to_world, again.vggt_to_world) and fit.details == again.details


def test_camera_height_fit_refusals_name_the_file_and_field():
    """No road, too few points, a height that is not a positive number: GroundPlaneError (a PredictionsError)
    naming the predictions file and the field, with a hint."""
    from scpainter_blender.core.vggt import npz
    from tests_support import synthetic_predictions

    arrays = synthetic_predictions(S=1, H=40, W=60)
    arrays["depth"][:] = 2.0  # a wall 2 units in front of the camera fills the image: nothing level
    wall = npz.predictions_from_arrays(arrays, "wall.npz")
    few = npz.predictions_from_arrays(synthetic_predictions(S=1, H=14, W=21), "few.npz")  # under 100 points
    for pred, field, confidence in ((wall, "(camera height)", 0.0), (few, "depth", 50.0)):
        with pytest.raises(metric_scale.GroundPlaneError) as e:
            metric_scale.camera_height_fit(pred, 1.6, confidence)
        assert e.value.path == pred.path and e.value.field == field
        assert "factor or a metric trajectory" in e.value.hint
        assert isinstance(e.value, vggt.PredictionsError)
    for height in (-1.0, 0.0, float("nan")):
        with pytest.raises(metric_scale.GroundPlaneError, match="positive number of metres") as e:
            metric_scale.camera_height_fit(_road(), height)
        assert e.value.field == "(camera height)" and e.value.hint


def test_saved_trajectory_reads_back(tmp_path):
    """``save_metric_trajectory`` writes what ``load_metric_trajectory`` reads (``sensors --trajectory-out``)."""
    T = np.tile(np.eye(4), (3, 1, 1))
    T[:, :3, 3] = [[400.0, 1100.0, -1.5], [404.0, 1100.5, -1.5], [408.0, 1101.0, -1.5]]
    metric_scale.save_metric_trajectory(tmp_path / "m.npz", T)
    w2c, centres = metric_scale.load_metric_trajectory(str(tmp_path / "m.npz"), 3)
    np.testing.assert_allclose(w2c, T, atol=1e-12)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]   # no temporary left
