"""core.geometry.point_cloud and core.geometry.unproject: VGGT's unprojection and confidence semantics, exactly."""

import numpy as np
import pytest

from scpainter_blender.core.geometry import metric_scale, point_cloud, similarity
from scpainter_blender.core.vggt import predictions as vggt, npz as vggt_io
from tests_support import synthetic_predictions as make_arrays
from tests.core.vggt.vggt_fixtures import save


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
    pred = vggt_io.load_predictions(save(tmp_path, arrays))
    pts = point_cloud.point_cloud(pred, confidence_percentile=0.0)
    ref = vggt_reference_unproject(arrays["depth"][..., 0], arrays["extrinsic"], arrays["intrinsic"])
    assert len(pts) == ref[..., 0].size
    assert np.abs(pts.positions - ref.reshape(-1, 3)).max() < 1e-9
    assert np.array_equal(pts.frame, np.repeat(np.arange(3), 14 * 21))
    assert np.allclose(pts.colors, np.moveaxis(arrays["images"], 1, -1).reshape(-1, 3))
    # our K is VGGT's with the principal point moved half a pixel
    assert np.allclose(pred.K[:, :2, 2], arrays["intrinsic"][:, :2, 2] + 0.5)


def test_confidence_semantics_match_vggt_demo(tmp_path):
    arrays = make_arrays(S=4)
    arrays["depth_conf"][0, 0, :5] = 0.0  # below 1e-5: always dropped
    pred = vggt_io.load_predictions(save(tmp_path, arrays))
    for p in (0.0, 10.0, 50.0, 90.0):
        conf = arrays["depth_conf"].reshape(-1)
        thr = np.percentile(conf, p)
        expected = (conf >= thr) & (conf > 1e-5)  # the demo: percentile over the whole clip
        pts = point_cloud.point_cloud(pred, confidence_percentile=p)
        assert len(pts) == expected.sum()
        per_frame = expected.reshape(4, -1).sum(1)
        assert np.array_equal(np.diff(pts.offsets), per_frame)
    with pytest.raises(ValueError):
        point_cloud.point_cloud(pred, confidence_percentile=101)


def test_world_points_source(tmp_path):
    arrays = make_arrays()
    pred = vggt_io.load_predictions(save(tmp_path, arrays))
    pts = point_cloud.point_cloud(pred, confidence_percentile=50.0, source="world_points")
    conf = arrays["world_points_conf"]
    keep = conf >= np.percentile(conf, 50)
    assert np.allclose(pts.positions, arrays["world_points"][keep].astype(np.float64))
    no_wp = {k: v for k, v in arrays.items() if not k.startswith("world_points")}
    pred2 = vggt_io.load_predictions(save(tmp_path, no_wp, "b.npz"))
    with pytest.raises(vggt.PredictionsError, match="world_points"):
        point_cloud.point_cloud(pred2, source="world_points")


def test_vggt_to_world_applied_in_float64(tmp_path):
    arrays = make_arrays()
    pred = vggt_io.load_predictions(save(tmp_path, arrays))
    M = similarity.similarity_matrix(12.5, metric_scale.OPENCV_TO_BLENDER_AXES, [1e5, -1e5, 3.0])
    a = point_cloud.point_cloud(pred, 0.0)
    b = point_cloud.point_cloud(pred, 0.0, vggt_to_world=M)
    assert np.abs(b.positions - (12.5 * a.positions @ metric_scale.OPENCV_TO_BLENDER_AXES.T + M[:3, 3])).max() < 1e-9


def test_points_behind_camera_dropped(tmp_path):
    arrays = make_arrays()
    arrays["depth"][1, 3, 4, 0] = -1.0
    arrays["depth"][1, 3, 5, 0] = 0.0
    pred = vggt_io.load_predictions(save(tmp_path, arrays))
    assert len(point_cloud.point_cloud(pred, 0.0)) == 3 * 14 * 21 - 2
