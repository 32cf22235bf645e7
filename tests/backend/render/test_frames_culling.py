"""frames: what a frame cannot see is left out (assets' Gaussian pass, source frames' points), with the same layers.

The skip tests are conservative bounds of what the projections cull; each is checked two ways: as a property
(whenever it says "unseen", the real projection keeps nothing), and on whole frames (layers identical with and
without ``Scene.skip_unseen``) for assets inside, partly inside, just outside, behind and across the near plane.
"""

import numpy as np
import pytest
import torch

from backend.render import frames as fr
from backend.render import gaussians as gs
from backend.render import points as pts
from scpainter_blender.core import job as job_mod
from scpainter_blender.core.geometry import visibility
from scpainter_blender.core.splats import gaussians as splats

W, H = 32, 24
K = np.array([[30.0, 0, 16], [0, 30.0, 12], [0, 0, 1]])


def _gaussians(rng, n=60, size=0.5, elongate=False):
    """``n`` Gaussians within ±``size`` of the origin; ``elongate``: needle-like, some along the viewing axis."""
    scales = rng.uniform(0.01, 0.08, (n, 3))
    if elongate:  # one long axis each, in a random direction (the rotation): some point along the view axis
        scales[np.arange(n), rng.integers(0, 3, n)] = rng.uniform(0.3, 1.5, n)
    q = rng.standard_normal((n, 4))
    return splats.Gaussians(means=rng.uniform(-size, size, (n, 3)).astype(np.float32),
                            scales=scales.astype(np.float32), quats=(q / np.linalg.norm(q, axis=1)[:, None]).astype(
                                np.float32), opacities=rng.uniform(0.2, 1.0, n).astype(np.float32),
                            sh=rng.uniform(-0.5, 0.5, (n, 1, 3)).astype(np.float32))


def _asset(g, where, frame=0, scale=1.0):
    A = np.diag([scale, scale, scale, 1.0])
    A[:3, 3] = where
    return fr.make_asset("car", g, {frame: A}, "cpu")


def _project(asset, frame, K, w2c, width, height):
    A = torch.as_tensor(asset.object_to_world[frame], dtype=torch.float64)
    means = asset.means @ A[:3, :3].T + A[:3, 3]
    return gs.project_factors(means, A[:3, :3] @ asset.factors, asset.opacities, asset.sh, K, w2c, width, height,
                              near=fr.GAUSSIAN_NEAR)


def test_an_unseen_asset_is_one_the_projection_culls_entirely():
    """Random assets (round and needle-like Gaussians, some long along the view axis) around the frustum's edges,
    behind the camera and across the near plane, random off-centre K: "unseen" implies nothing projected."""
    rng = np.random.default_rng(0)
    unseen = seen = 0
    for trial in range(300):
        Kt = K.copy()
        Kt[0, 2], Kt[1, 2] = rng.uniform(-10, W + 10), rng.uniform(-8, H + 8)   # principal point anywhere
        g = _gaussians(rng, n=40, size=rng.uniform(0.05, 1.0), elongate=trial % 2 == 1)
        z = rng.choice([rng.uniform(-3, 0.3), rng.uniform(0.3, 20)])
        # around the image's edges: x/z and y/z near the frustum's side planes, either side
        x = z * ((rng.choice([0, W]) - Kt[0, 2]) / Kt[0, 0] + rng.uniform(-0.6, 0.6))
        y = z * ((rng.choice([0, H]) - Kt[1, 2]) / Kt[1, 1] + rng.uniform(-0.6, 0.6))
        a = _asset(g, [x, y, z], scale=rng.uniform(0.5, 3.0))
        if fr.asset_unseen(a, 0, np.zeros(3), Kt, np.eye(4), W, H):
            unseen += 1
            assert len(_project(a, 0, Kt, np.eye(4), W, H)["index"]) == 0, trial
        else:
            seen += 1
    assert unseen > 60 and seen > 60, (unseen, seen)  # both answers happen: the property is not vacuous


def _scene(assets, xyz=None, frame=None):
    scene = fr.Scene(origin=np.array([100.0, -40.0, 2.0]), device=torch.device("cpu"))  # far from the world origin
    scene.assets = assets
    if xyz is not None:
        scene.xyz = torch.as_tensor(xyz, dtype=torch.float32)
        scene.rgb = torch.as_tensor(np.random.default_rng(1).random((len(xyz), 3)), dtype=torch.float32)
        scene.frame = torch.as_tensor(frame, dtype=torch.int64)
        scene.frames_present = frozenset(np.unique(frame).tolist())
        scene.frame_slices, scene.frame_boxes = fr.frame_index(frame, scene.xyz.numpy())
    return scene


def _entry(w2c_relative, origin, frame=0, sources=()):
    """A job frame whose camera is ``w2c_relative`` for positions relative to ``origin`` (as the scene has them)."""
    w2c = np.array(w2c_relative, np.float64)
    w2c[:3, 3] -= w2c[:3, :3] @ origin
    return job_mod.Frame(frame, K, w2c, list(sources))


def _both(scene, entry, **kw):
    scene.skip_unseen = True
    a = fr.render_frame(scene, entry, W, H, **kw)
    scene.skip_unseen = False
    b = fr.render_frame(scene, entry, W, H, **kw)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    return a


@pytest.mark.parametrize("case,where,skipped", [
    ("inside", [0.0, 0.0, 6.0], False),
    ("partly inside (right edge)", [3.2, 0.0, 6.0], False),
    ("partly inside (across the near plane)", [0.0, 0.0, 0.2], False),
    ("just outside, right", [5.0, 0.0, 6.0], None),       # within a few pixels of the edge: may or may not skip
    ("just outside, top", [0.0, -4.0, 6.0], None),
    ("outside, left", [-9.0, 0.0, 6.0], True),
    ("outside, below", [0.0, 9.0, 6.0], True),
    ("behind the camera", [0.0, 0.0, -3.0], True),
])
def test_layers_are_the_same_with_and_without_the_asset_skip(case, where, skipped):
    rng = np.random.default_rng(3)
    g = _gaussians(rng, n=150, size=0.6)
    scene = _scene([])
    origin = scene.origin
    a = _asset(g, np.asarray(where) + origin, frame=5)
    scene.assets = [a]
    entry = _entry(np.eye(4), origin, frame=5)
    unseen = fr.asset_unseen(a, 5, origin, K, pts.relative_camera(entry.world_to_camera, origin), W, H)
    if skipped is not None:
        assert unseen == skipped, case
    layers = _both(scene, entry)
    if skipped is False:
        assert layers["asset_mask"].max() > 0.1, case   # it does draw: the skip would have been wrong


def test_two_assets_one_seen_run_the_pass_for_both():
    rng = np.random.default_rng(4)
    scene = _scene([])
    o = scene.origin
    scene.assets = [_asset(_gaussians(rng), o + [0.0, 0.0, 5.0]), _asset(_gaussians(rng), o + [0.0, 0.0, -5.0])]
    layers = _both(scene, _entry(np.eye(4), o))
    assert layers["asset_mask"].max() > 0.1


def test_an_unseen_source_frame_is_one_whose_points_all_cull():
    """Random boxes of points around the frustum, tested in one batch: "unseen" implies the z-buffer lands none."""
    rng = np.random.default_rng(5)
    clouds = []
    for trial in range(300):
        z = rng.uniform(-3, 12)
        c = np.array([z * rng.uniform(-1.2, 1.2), z * rng.uniform(-1.0, 1.0), z])
        xyz = c + rng.uniform(-1, 1, (200, 3)) * rng.uniform(0.01, 2.0, 3)
        clouds.append(np.concatenate([xyz, visibility.box_corners(xyz.min(0), xyz.max(0))]).astype(np.float32))
    boxes = np.stack([np.stack([x.min(0), x.max(0)]) for x in clouds]).astype(np.float64)
    for r in (0, 2):
        unseen = fr.points_unseen(boxes, K, np.eye(4), W, H, radius_px=r)
        assert unseen.shape == (300,) and 60 < unseen.sum() < 240, unseen.sum()   # both answers happen
        for trial in np.flatnonzero(unseen):
            t = torch.as_tensor(clouds[trial])
            _, depth, _ = pts.render_points(t, torch.zeros_like(t), K, np.eye(4), W, H, radius_px=r)
            assert torch.isinf(depth).all(), trial
        # one box at a time answers the same as the batch
        assert [bool(fr.points_unseen(b, K, np.eye(4), W, H, radius_px=r)[0]) for b in boxes[:20]] == \
            unseen[:20].tolist()


def _frames_of_points(rng):
    """Six source frames' points: in view, behind the camera, off to the left, far above, in view, in view."""
    centres = [[0, 0, 5], [0, 0, -4], [-20, 0, 5], [0, -30, 5], [0.5, 0.2, 8], [-0.5, 0.4, 3]]
    xyz = np.concatenate([np.asarray(c) + rng.uniform(-1, 1, (300, 3)) for c in centres])
    frame = np.repeat(np.arange(6), 300)
    return xyz, frame


@pytest.mark.parametrize("sources", [range(6), [0, 1, 2, 3], [1, 2, 3], [0, 4], [4, 5, 1], [5, 0, 2, 3, 1]])
@pytest.mark.parametrize("radius", [0, 1])
def test_layers_are_the_same_with_and_without_the_source_frame_skip(sources, radius):
    rng = np.random.default_rng(6)
    xyz, frame = _frames_of_points(rng)
    scene = _scene([], xyz, frame)
    entry = _entry(np.eye(4), scene.origin, sources=sources)
    w2c = pts.relative_camera(entry.world_to_camera, scene.origin)
    visible = fr.visible_frames(scene, entry.source_frames, K, w2c, W, H, radius)
    assert set(visible) == set(sources) & {0, 4, 5}   # the three out of view are left out, the others not
    layers = _both(scene, entry, point_radius_px=radius)
    # and the same as the selection over every point, without the per-frame slices
    plain = _scene([], xyz, frame)
    plain.frame_slices = plain.frame_boxes = None
    other = fr.render_frame(plain, entry, W, H, point_radius_px=radius)
    assert all(np.array_equal(layers[k], other[k]) for k in layers)
    if set(sources) & {0, 4, 5}:
        assert (layers["hole"] == 0).any()


def test_selection_keeps_the_order_and_copies_only_when_it_must():
    rng = np.random.default_rng(7)
    xyz, frame = _frames_of_points(rng)
    scene = _scene([], xyz, frame)
    every, _ = fr.select_points(scene, list(range(6)))
    assert every.data_ptr() == scene.xyz.data_ptr()                       # every frame: the stored tensor
    run, _ = fr.select_points(scene, [2, 3, 4])
    assert run.data_ptr() == scene.xyz[600:].data_ptr() and len(run) == 900  # contiguous frames: one view
    picked, colours = fr.select_points(scene, [4, 1])
    sel = np.isin(frame, [1, 4])
    np.testing.assert_array_equal(picked.numpy(), scene.xyz.numpy()[sel])  # in the scene's order
    np.testing.assert_array_equal(colours.numpy(), scene.rgb.numpy()[sel])


def test_frames_out_of_order_are_not_sliced():
    slices, boxes = fr.frame_index(np.array([0, 0, 1, 0]), np.zeros((4, 3), np.float32))
    assert slices is None and boxes is None


def test_overflowing_transforms_never_raise_and_skip_only_what_the_projection_culls():
    """A scale of 1e200 or a camera 1e300 m away (the hostile-input fuzzing's cases) overflow the bounds: no
    OverflowError, and "unseen" still means the projection keeps nothing; bounds that overflow to inf are
    never skipped."""
    g = _gaussians(np.random.default_rng(9), n=10)
    far = np.eye(4)
    far[:3, 3] = [1e300, -1e300, 1e300]
    for scale, w2c in ((1e200, np.eye(4)), (1.0, far), (1e-300, np.eye(4)), (1e200, far)):
        a = _asset(g, [0.0, 0.0, 5.0], scale=scale)
        unseen = fr.asset_unseen(a, 0, np.zeros(3), K, w2c, W, H)
        assert isinstance(unseen, bool)
        if unseen:
            with np.errstate(all="ignore"):
                assert len(_project(a, 0, K, w2c, W, H)["depth"]) == 0, (scale, w2c[0, 3])
    boxes = np.array([[[-1e308, -1e308, 1.0], [1e308, 1e308, 1e308]], [[0.0, 0.0, 1.0], [1.0, 1.0, 2.0]]])
    rotated = np.eye(4)
    rotated[:3, :3] = [[0.6, 0.8, 0.0], [-0.8, 0.6, 0.0], [0.0, 0.0, 1.0]]
    rotated[:3, 3] = [1e308, 1e308, 0.0]  # the first box's corners overflow to inf: not skipped
    assert fr.points_unseen(boxes, K, rotated, W, H)[0] == False  # noqa: E712
