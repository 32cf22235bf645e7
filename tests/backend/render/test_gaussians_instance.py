"""The instance pass (backend.render.gaussians.rasterize's rule, in every rasterizer; frames.render_frame's
``instance`` layer, frames.visible_pixels and frames.amodal_pixels) on overlapping cars and random scenes.

Rule: per pixel w_a = Σ α·T over the composited Gaussians of asset a, T_rest the transmittance left; instance =
argmax_a w_a (ties to the lower id) where max_a w_a > T_rest, else 0. The CPU tile kernel (float64 accumulators)
must equal the torch reference exactly; a difference could only come from a pixel where max_a w_a and T_rest (or
two assets' weights) agree to rounding, which these continuous scenes do not produce (checked: 0 pixels).
"""

import numpy as np
import pytest
import torch

from backend.render import frames as fr
from backend.render import gaussians as GS
from backend.render import tiles as TL
from scpainter_blender.core import job as job_mod
from scpainter_blender.core import shapes

from tests.backend.render.test_gaussians import EYE, K, random_scene, reference_gaussians

W, H = 96, 64
KC = np.array([[60.0, 0, W / 2], [0, 60.0, H / 2], [0, 0, 1]])


def camera(height=1.0) -> np.ndarray:
    """world_to_camera at (0, 0, height) looking along +Y (OpenCV axes: x right, y down)."""
    w2c = np.eye(4)
    w2c[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    w2c[:3, 3] = -w2c[:3, :3] @ np.array([0.0, 0.0, height])
    return w2c


#: Three cars seen from behind: 1 near the middle, 2 further back and half hidden by 1, 3 cut by the left border.
CARS = ((0.6, 9.0), (-1.2, 14.0), (-6.8, 9.0))


def car_scene(cars=CARS, count=1500, wall=False) -> tuple:
    """(Scene, Frame) of procedural cars at (x, y) on the road (no points; with ``wall`` a wall of points across
    the view left of x = -1.6 m at y = 12 m, between car 1 and car 2: it hides part of car 2)."""
    scene = fr.Scene(origin=np.zeros(3), device=torch.device("cpu"))
    for i, (x, y) in enumerate(cars):
        A = np.eye(4)
        A[:3, 3] = (x, y, 0.0)
        scene.assets.append(fr.make_asset(f"car{i + 1}", shapes.procedural_car_gaussians(count=count, seed=i),
                                          {0: A}, scene.device))
    if wall:
        gx, gz = np.meshgrid(np.arange(-12.0, -1.6, 0.05), np.arange(0.0, 4.0, 0.05))
        xyz = np.stack([gx.ravel(), np.full(gx.size, 12.0), gz.ravel()], 1)
        scene.xyz = torch.as_tensor(xyz, dtype=torch.float32)
        scene.rgb = torch.full((len(xyz), 3), 0.5)
        scene.frame = torch.zeros(len(xyz), dtype=torch.int64)
        scene.frames_present = frozenset({0})
    return scene, job_mod.Frame(frame=0, K=KC, world_to_camera=camera(), source_frames=[0] if wall else [])


def wall_depth(depth=12.0):
    bg = torch.full((H, W), float("inf"), dtype=torch.float64)
    bg[:, : W // 2] = depth
    return bg


@pytest.mark.parametrize("bg", [None, 12.0], ids=["no-points", "wall"])
def test_tile_kernel_instance_equals_the_reference_on_overlapping_cars(bg):
    scene, entry = car_scene()
    proj = fr.project_assets(scene, range(3), 0, KC, camera(), W, H)
    background = None if bg is None else wall_depth(bg)
    ref = GS.rasterize(proj, W, H, background)
    got = TL.rasterize(proj, W, H, background)
    assert ref[3].dtype == got[3].dtype == torch.int32
    assert int((ref[3] != got[3]).sum()) == 0
    counts = np.bincount(ref[3].numpy().ravel(), minlength=4)
    assert counts.min() > 0  # every car and the scene win pixels
    for s in (4, 16):  # the tile size changes nothing
        assert torch.equal(TL.rasterize(proj, W, H, background, tile=s)[3], got[3])
    if bg is None:
        # one asset: its instance region is where its M_a > 0.5
        alone = fr.project_assets(scene, [0], 0, KC, camera(), W, H)
        r = TL.rasterize(alone, W, H)
        assert torch.equal(r[3] > 0, r[1] > 0.5) and int(r[3].max()) == 1


@pytest.mark.parametrize("seed,n_assets,wall", [(40, 2, False), (41, 3, False), (42, 3, True), (43, 5, True)])
def test_instance_equals_the_numpy_brute_force(seed, n_assets, wall):
    """Random overlapping Gaussians with random asset ids against the float64 numpy renderer (every Gaussian at
    every pixel), in the pair reference and the CPU tile kernel (float64 projection)."""
    scene = random_scene(90, seed, 1)
    ids = np.random.default_rng(seed).integers(1, n_assets + 1, len(scene[0]))
    bg = np.full((48, 64), np.inf)
    if wall:
        bg[:, :32] = 5.0
    _, _, want = reference_gaussians(*scene, K, EYE, 64, 48, bg_depth=bg if wall else None, asset_id=ids)
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float64)  # noqa: E731
    for rasterize, fast in ((GS.rasterize, False), (TL.rasterize, True)):
        proj = GS.project(*(t(a) for a in scene), K, EYE, 64, 48, fast=fast)
        proj["asset_id"] = torch.as_tensor(ids)[proj["index"]]
        got = rasterize(proj, 64, 48, t(bg) if wall else None)[3].numpy()
        assert np.array_equal(got, want), (rasterize.__module__, int((got != want).sum()))
    assert len(np.unique(want)) >= 3  # the rule picks different assets and the background on this scene


def test_identical_gaussians_of_two_assets():
    """Two identical Gaussians (same depth, same footprint) in two assets: the depth tie goes to the lower index,
    which composites first and takes α, the other α(1 − α); so the first row's asset wins, whichever id it has.
    (An exact tie of two assets' sums is not constructible across the implementations: the reference's
    transmittance is a float64 log-space product. Each implementation keeps the first maximum: torch.argmax,
    np.argmax and the kernels' strict >.)"""
    proj = {"index": torch.tensor([0, 1]), "mean2d": torch.tensor([[8.0, 8.0], [8.0, 8.0]], dtype=torch.float64),
            "conic": torch.tensor([[0.1, 0.0, 0.1]] * 2, dtype=torch.float64),
            "radius": torch.tensor([[6.0, 6.0]] * 2, dtype=torch.float64),
            "depth": torch.tensor([2.0, 2.0], dtype=torch.float64),
            "opacity": torch.tensor([0.5, 0.5], dtype=torch.float64), "color": torch.ones(2, 3, dtype=torch.float64)}
    for ids, winner in (([1, 2], 1), ([2, 1], 2)):
        proj["asset_id"] = torch.tensor(ids)
        ref, got = GS.rasterize(proj, 16, 16)[3], TL.rasterize(proj, 16, 16)[3]
        assert torch.equal(ref, got) and int(ref[7, 7].item()) == winner  # pixel centre (7.5, 7.5): near the mean
        assert int((ref > 0).sum()) > 0 and set(torch.unique(ref).tolist()) == {0, winner}


def test_render_frame_instance_layer():
    scene, entry = car_scene(wall=True)
    layers = fr.render_frame(scene, entry, W, H)
    ref = fr.render_frame(scene, entry, W, H, reference=True)
    inst = layers["instance"]
    assert inst.dtype == np.float32 and inst.shape == (H, W)
    assert np.array_equal(inst, ref["instance"])
    assert set(np.unique(inst).tolist()) == {0.0, 1.0, 2.0, 3.0}
    assert not inst[layers["asset_mask"] < 1e-3].any()  # no asset there: 0
    # the wall hides car 2 (behind it) on the left half, car 3 stands in front of it
    wall_only = car_scene(wall=True)[0]
    wall_only.assets = []
    assert not fr.render_frame(wall_only, entry, W, H)["instance"].any()  # no assets: no instance pass, 0
    # a single car: its instance region is where its M_a > 0.5
    one = car_scene(cars=CARS[:1])
    single = fr.render_frame(*one, W, H)
    assert np.array_equal(single["instance"], (single["asset_mask"] > 0.5).astype(np.float32))
    # every asset out of view (behind the camera): the Gaussian pass is skipped, the layer is 0
    behind = car_scene(cars=((0.0, -10.0),))
    assert not fr.render_frame(*behind, W, H)["instance"].any()


def test_visible_and_amodal_pixels():
    scene, entry = car_scene(cars=(*CARS, (0.0, -10.0)), wall=True)  # car 4 behind the camera
    layers = fr.render_frame(scene, entry, W, H)
    visible = fr.visible_pixels(layers["instance"], 4)
    assert visible.dtype == np.int64 and visible.shape == (4,)
    assert visible.sum() == int((layers["instance"] > 0).sum())
    assert np.array_equal(visible, [int((layers["instance"] == a).sum()) for a in (1, 2, 3, 4)])
    amodal = fr.amodal_pixels(scene, entry, W, H)
    assert amodal.dtype == np.int64 and amodal.shape == (4,)
    assert amodal[3] == visible[3] == 0                # out of view: no pass
    assert visible[2] == amodal[2] > 0                 # car 3: cut by the border, nothing in front or behind it
    assert 0 < visible[1] < amodal[1]                  # car 2: half hidden by car 1 and by the wall
    assert visible[0] > 0 and amodal[0] > 0
    # without the wall and car 2, car 1 is unoccluded too: visible == amodal exactly
    alone = car_scene(cars=(CARS[0], CARS[2]))
    lay = fr.render_frame(*alone, W, H)
    assert np.array_equal(fr.visible_pixels(lay["instance"], 2), fr.amodal_pixels(*alone, W, H))
    # from the frame's own projection (render_frame(keep=...)): the same counts as projecting each asset alone
    kept = {}
    fr.render_frame(scene, entry, W, H, keep=kept)
    assert np.array_equal(fr.amodal_pixels(scene, entry, W, H, projection=kept["projection"]), amodal)
    kept = {}
    fr.render_frame(*car_scene(cars=((0.0, -10.0),)), W, H, keep=kept)
    assert kept["projection"] is None
    assert not fr.amodal_pixels(*car_scene(cars=((0.0, -10.0),)), W, H, projection=None).any()
    # tensors are counted too (render_frame(..., to_numpy=False))
    assert np.array_equal(fr.visible_pixels(torch.as_tensor(lay["instance"]), 2), fr.visible_pixels(lay["instance"], 2))
