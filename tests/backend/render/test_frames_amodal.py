"""frames: each asset's amodal pixels counted in the frame's own kernel walk (``render_frame(keep=...)`` on the CPU,
``frame_amodal``) equal ``amodal_pixels``' render of each asset alone, exactly, on frames where things hide the
cars: a car behind another, points in front of a car, a car partly out of the image, one behind the camera and one
across the near plane; and the layers are the same bits with or without the counting."""

import numpy as np
import pytest
import torch

from backend.render import frames as fr
from scpainter_blender.core import job as job_mod
from scpainter_blender.core import shapes

W, H = 64, 48
K = np.array([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]])
#: car axes (Z up, front +Y) into the camera's (y down, z forward): up is -y, the front points away
UPRIGHT = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])


def _car(where, seed):
    A = np.eye(4)
    A[:3, :3] = UPRIGHT
    A[:3, 3] = where
    return fr.make_asset(f"car{seed}", shapes.procedural_car_gaussians(count=300, seed=seed), {0: A}, "cpu")


def _points(scene, xyz):
    xyz = np.asarray(xyz, np.float32)
    frame = np.zeros(len(xyz), np.int64)
    rng = np.random.default_rng(1)
    scene.xyz, scene.rgb = torch.as_tensor(xyz), torch.as_tensor(rng.uniform(0, 1, xyz.shape).astype(np.float32))
    scene.frame, scene.frames_present = torch.as_tensor(frame), frozenset({0})
    scene.frame_slices, scene.frame_boxes = fr.frame_index(frame, xyz)


def _scene(cars, wall=True):
    scene = fr.Scene(origin=np.zeros(3), device=torch.device("cpu"))
    scene.assets = [_car(w, s) for w, s in cars]
    if wall:  # a wall of points in front of the first car's left half, and a far background
        u, v = np.meshgrid(np.linspace(-1.2, 0.1, 40), np.linspace(-0.2, 1.1, 40))
        near = np.stack([u.ravel(), v.ravel(), np.full(u.size, 5.0)], 1)
        u, v = np.meshgrid(np.linspace(-25, 25, 80), np.linspace(-15, 15, 60))
        far = np.stack([u.ravel(), v.ravel(), np.full(u.size, 40.0)], 1)
        _points(scene, np.concatenate([near, far]))
    return scene


CASES = {
    # in front; behind it and partly hidden; half out of the image; behind the camera; across the near plane
    "five": [((0.0, 1.0, 8.0), 1), ((1.8, 1.0, 14.0), 2), ((7.5, 1.0, 9.0), 3), ((0.0, 1.0, -6.0), 4),
             ((-3.0, 1.0, 0.4), 5)],
    "behind": [((0.0, 1.0, 8.0), 6), ((1.6, 0.9, 12.0), 7)],
    "one": [((0.0, 1.0, 8.0), 8)],
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_kernels_counts_equal_a_render_of_each_asset_alone(case):
    scene = _scene(CASES[case])
    entry = job_mod.Frame(0, K, np.eye(4), [0])
    kept = {}
    layers = fr.render_frame(scene, entry, W, H, keep=kept)
    assert kept["amodal"] is not None  # counted in the walk, not by a second render
    alone = fr.amodal_pixels(scene, entry, W, H)  # each asset projected and rendered alone
    assert kept["amodal"].dtype == np.int64 and np.array_equal(kept["amodal"], alone), (kept["amodal"], alone)
    assert np.array_equal(fr.frame_amodal(scene, entry, W, H, kept), alone)
    assert np.array_equal(fr.amodal_pixels(scene, entry, W, H, projection=kept["projection"]), alone)
    # the counting changes no layer
    plain = fr.render_frame(scene, entry, W, H)
    assert all(np.array_equal(layers[k], plain[k], equal_nan=True) for k in layers)
    visible = fr.visible_pixels(layers["instance"], len(scene.assets))
    assert np.all(alone >= visible)
    if case != "one":
        assert alone[1] > visible[1] > 0  # the car behind is partly hidden, and counted whole
    assert alone[0] > visible[0]  # the wall of points hides part of the first car
    if case == "five":
        assert alone[2] > 0 and alone[3] == 0 and alone[4] > 0  # half out; behind the camera; across near


def test_paths_without_the_kernels_counts_fall_back_to_the_render_per_asset():
    scene = _scene(CASES["behind"])
    entry = job_mod.Frame(0, K, np.eye(4), [0])
    kept = {}
    fr.render_frame(scene, entry, W, H, reference=True, keep=kept)  # the torch pair rasterizer counts nothing
    assert kept["amodal"] is None
    assert np.array_equal(fr.frame_amodal(scene, entry, W, H, kept), fr.amodal_pixels(scene, entry, W, H))
    away = job_mod.Frame(0, K, np.diag([-1.0, 1.0, -1.0, 1.0]), [0])  # looking the other way: no Gaussian pass
    kept = {}
    fr.render_frame(scene, away, W, H, keep=kept)
    assert kept["projection"] is None and kept["amodal"] is None
    assert np.array_equal(fr.frame_amodal(scene, away, W, H, kept), np.zeros(2, np.int64))
