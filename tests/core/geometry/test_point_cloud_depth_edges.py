"""core.geometry.point_cloud.depth_edges: the depth-edge ("flying pixel") rule, its reference, and point_cloud's use of it."""

import numpy as np
import pytest

from scpainter_blender.core.geometry import point_cloud
from scpainter_blender.core.vggt import predictions as vggt, npz as vggt_io


def test_fast_equals_the_rule_pixel_by_pixel():
    rng = np.random.default_rng(0)
    for trial in range(6):
        H, W = 9 + trial, 13
        # piecewise depth (blocks at different distances), a ramp, and pixels without depth of every kind
        depth = np.kron(rng.uniform(1, 30, (4, 5)), np.ones((4, 4)))[:H, :W] * (1 + 0.02 * rng.random((H, W)))
        depth[rng.random((H, W)) < 0.1] = 0.0
        depth[rng.random((H, W)) < 0.05] = np.nan
        depth[rng.random((H, W)) < 0.05] = np.inf
        depth[rng.random((H, W)) < 0.03] *= -1
        valid = rng.random((H, W)) > 0.1 if trial % 2 else None
        for ratio in (0.01, 0.05, 0.3, 2.0):
            fast = point_cloud.depth_edges(depth, ratio, valid)
            assert fast.dtype == bool and fast.shape == (H, W)
            np.testing.assert_array_equal(fast, point_cloud.depth_edges_reference(depth, ratio, valid))


def test_what_the_rule_drops():
    step = np.full((5, 8), 10.0)
    step[:, 4:] = 20.0                      # a discontinuity between columns 3 and 4
    edges = point_cloud.depth_edges(step, 0.3)
    assert edges[:, 3].all() and edges[:, 4].all() and edges.sum() == 10   # |Δ|/10 = 1, |Δ|/20 = 0.5 > 0.3
    edges = point_cloud.depth_edges(step, 0.6)
    assert edges[:, 3].all() and not edges[:, 4].any()                      # 0.5 < 0.6: the far side stays
    ramp = 10.0 + 0.1 * np.arange(40)[None, :].repeat(6, 0)                 # ≤ 1 % per pixel: a slanted wall
    assert not point_cloud.depth_edges(ramp, 0.02).any()
    assert not point_cloud.depth_edges(np.full((4, 4), 3.0), 1e-4).any()
    # a network's blur of the step: the pixels in between go (and the near plateau's last pixel, 2/10 > 0.1);
    # the far plateau's first stays (2/20 is not above 0.1)
    blurred = np.array([10, 10, 10, 12, 15, 18, 20, 20, 20.0])[None, :].repeat(3, 0)
    assert point_cloud.depth_edges(blurred, 0.1)[0].tolist() == [0, 0, 1, 1, 1, 1, 0, 0, 0]
    # a hole is not an edge: a pixel beside pixels without depth is kept, and so are they
    hole = np.full((3, 3), 5.0)
    hole[1, 1] = 0.0
    assert not point_cloud.depth_edges(hole, 0.01).any()
    lone = np.zeros((3, 3))
    lone[1, 1] = 5.0
    assert not point_cloud.depth_edges(lone, 0.01).any()


def _predictions(rng, S=3, H=12, W=16):
    depth = np.kron(rng.uniform(2, 20, (S, 3, 4)), np.ones((1, 4, 4)))
    depth[0, 0, 0] = np.nan                 # dropped on load (valid = False), never an edge nor compared
    K = np.array([[12.0, 0, W / 2], [0, 12.0, H / 2], [0, 0, 1]])
    ext = np.tile(np.eye(4)[:3], (S, 1, 1))
    ext[:, 0, 3] = np.arange(S) * 0.3
    return vggt_io.predictions_from_arrays({
        "images": rng.random((S, 3, H, W)).astype(np.float32), "depth": depth[..., None].astype(np.float32),
        "depth_conf": (1 + 5 * rng.random((S, H, W))).astype(np.float32), "extrinsic": ext.astype(np.float32),
        "intrinsic": np.tile(vggt.ours_K_to_vggt(K), (S, 1, 1)).astype(np.float32)})


@pytest.mark.parametrize("percentile", [0.0, 40.0])
def test_point_cloud_leaves_out_exactly_the_edge_pixels(percentile):
    pred = _predictions(np.random.default_rng(1))
    full = point_cloud.point_cloud(pred, percentile)
    clean = point_cloud.point_cloud(pred, percentile, depth_edge_ratio=0.2)
    assert clean.threshold == full.threshold          # the clip's confidence distribution, as without the test
    dropped = 0
    for i in range(pred.num_frames):
        edges = point_cloud.depth_edges(pred.depth[i], 0.2, pred.valid[i])
        kept = (pred.depth_conf[i] >= full.threshold) & pred.valid[i] & (pred.depth[i] > 0)
        a, b = full.positions[full.frame_slice(i)], clean.positions[clean.frame_slice(i)]
        np.testing.assert_array_equal(b, a[~edges[kept]])   # the same points, in the same order, minus edges
        dropped += int((edges & kept).sum())
    assert clean.depth_edge_points == dropped > 0 and len(full) - len(clean) == dropped
    assert full.depth_edge_points == 0
