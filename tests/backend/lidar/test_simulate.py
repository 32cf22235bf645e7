"""backend/lidar/simulate.py: the accuracy on a scene of known geometry (a ground plane and a car-sized box, sampled
as points) against analytic ray casting, and the numerical extremes: an empty scene, points under the sensor, NaN
rows, a world 1e5 m from its origin, the range window, removal boxes, Gaussian cars, the renderer's scene."""

import numpy as np
import pytest
import torch

from backend.lidar import cast, simulate as sim
from backend.lidar.sweep import counts
from scpainter_blender.core import shapes
from scpainter_blender.core.lidar_model import MODELS

from tests.backend.lidar.lidar_scenes import PlaneBox, edge_clearance

NUSCENES = MODELS["nuscenes-32"]


@pytest.fixture(scope="module")
def plane_box():
    sc = PlaneBox()
    pts, rgb = sc.sample(2_000_000, 7000.0, seed=0)
    return sc, pts, rgb


def _analytic(sc, model, T, settings):
    d0, e1, e2 = cast.ray_bases(model)
    rng, surface = sc.cast(T[:3, 3], d0 @ T[:3, :3].T)
    clear = edge_clearance(sc, T[:3, 3], d0 @ T[:3, :3].T, e1 @ T[:3, :3].T, e2 @ T[:3, :3].T,
                           2 * np.deg2rad(settings.footprint_deg))
    return rng, surface, clear


def test_ranges_within_2_cm_and_the_box_count_within_5_percent(plane_box):
    sc, pts, rgb = plane_box
    T, st = sc.lidar_to_world(), cast.LidarSettings()
    sweep = sim.simulate(NUSCENES, T, pts, rgb, settings=st)
    rng, surface, clear = _analytic(sc, NUSCENES, T, st)
    col, row = sweep.column, NUSCENES.beams - 1 - sweep.ring
    err = np.abs(sweep.range_m - rng[col, row])
    both = np.isfinite(err)
    # every return whose analytic hit is at least 2 footprints from an edge: within 2 cm (here: under a mm)
    assert clear[col, row].sum() > 20_000 and err[clear[col, row]].max() < 0.02
    # all returns that have an analytic hit, edges included: the 99th percentile
    assert both.mean() > 0.99 and np.percentile(err[both], 99) < 0.02
    # rays clear of edges with an analytic hit all return; rays with none return only within 2 footprints of one
    returned = np.zeros(rng.shape, bool)
    returned[col, row] = True
    assert np.all(returned[clear & (surface >= 0)])
    assert not np.any(returned & clear & (surface < 0))
    # the box: its returns (the label box a little larger than the sampled one) against the rays that hit it
    analytic = int((surface == 1).sum())
    got = counts(sweep, [(sc.box_to_world, np.asarray(sc.box_size) + 0.1)])[0]
    assert analytic > 500 and abs(got - analytic) <= 0.05 * analytic
    # intensity away from edges: the grey ground's (0.4) and the box's (0.8) luminance
    grey = np.where(surface[col, row] == 1, 0.8, 0.4)
    assert np.allclose(sweep.intensity[clear[col, row]] / 255, grey[clear[col, row]], atol=1e-5)


def test_an_empty_scene_and_points_under_or_near_the_sensor_give_no_returns():
    T = np.eye(4)
    assert len(sim.simulate(NUSCENES, T, np.zeros((0, 3)))) == 0
    rng = np.random.default_rng(0)
    under = np.column_stack([rng.uniform(-0.3, 0.3, (5000, 2)), -rng.uniform(2, 5, 5000)])  # below the lowest beam
    near = rng.normal(size=(5000, 3))
    near *= (0.95 * rng.uniform(0, 1, (5000, 1)) ** (1 / 3)) / np.linalg.norm(near, axis=1, keepdims=True)  # < 1 m
    assert len(sim.simulate(NUSCENES, T, np.concatenate([under, near]))) == 0


def _wall(depth, n=60_000, seed=0, half=6.0):
    """A wall facing the sensor along +y at ``depth`` m (world), from z = -3 to 3."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-half, half, n), np.full(n, depth), rng.uniform(-3, 3, n)])


def test_nan_rows_are_dropped_and_a_far_world_loses_nothing():
    pts = _wall(10.0)
    T = np.eye(4)
    base = sim.simulate(NUSCENES, T, pts)
    assert len(base) > 200 and np.abs(base.points[:, 1] - 10.0).max() < 0.01
    with_nan = np.concatenate([pts[:100], np.full((50, 3), np.nan), pts[100:], [[np.inf, 0, 0]]])
    assert np.array_equal(sim.simulate(NUSCENES, T, with_nan).range_m, base.range_m)
    far = T.copy()
    far[:3, 3] = (1e5, -1e5, 1e5)
    moved = sim.simulate(NUSCENES, far, pts + far[:3, 3])
    assert np.array_equal(moved.column, base.column) and np.abs(moved.range_m - base.range_m).max() < 1e-5
    assert np.allclose(moved.world_points(), base.world_points() + far[:3, 3], atol=1e-4)


def test_the_range_window_of_each_model():
    T = np.eye(4)
    assert len(sim.simulate(NUSCENES, T, _wall(80.0, half=30))) == 0        # beyond 70 m
    assert len(sim.simulate(MODELS["velodyne-64"], T, _wall(80.0, half=30, n=200_000))) > 0  # within 120 m
    # a panel inside the blind radius is seen through: the wall behind returns
    rng = np.random.default_rng(1)
    panel = np.column_stack([rng.uniform(-0.5, 0.5, 20_000), np.full(20_000, 0.6), rng.uniform(-0.5, 0.5, 20_000)])
    got = sim.simulate(NUSCENES, T, np.concatenate([panel, _wall(10.0)]))
    assert len(got) > 200 and got.range_m.min() > 9.9


def test_removal_boxes_and_gaussian_cars():
    T = np.eye(4)
    wall = _wall(12.0)
    box = np.eye(4)
    box[:3, 3] = (0, 12.0, 0)
    assert len(sim.simulate(NUSCENES, T, wall, removal_boxes=[(box, (20.0, 1.0, 10.0))])) == 0
    car = shapes.procedural_car_gaussians(count=20_000, seed=1)
    place = np.eye(4)
    place[:3, 3] = (0.0, 6.0, -1.84)  # on the ground 6 m ahead of a sensor 1.84 m up
    means = car.means @ place[:3, :3].T + place[:3, 3]
    got = sim.simulate(NUSCENES, T, wall, gaussians=[(means, car.opacities, None)])
    on_car = got.source == 1
    assert on_car.sum() > 50 and np.all(got.range_m[on_car] < 9.0)
    car_box = np.eye(4)
    lo, hi = means.min(0), means.max(0)
    car_box[:3, 3] = (lo + hi) / 2
    assert counts(got, [(car_box, hi - lo + 0.1)])[0] == on_car.sum()  # its label box: the means' box, grown
    # transparent Gaussians are not surfaces
    none = sim.simulate(NUSCENES, T, np.zeros((0, 3)), gaussians=[(means, np.full(len(means), 0.1), None)])
    assert len(none) == 0


def test_sweep_for_frame_reads_the_renderers_scene_relative_to_its_origin():
    from backend.render import frames as fr

    origin = np.array([5000.0, -3000.0, 10.0])
    wall = _wall(10.0) + origin
    scene = fr.Scene(origin=origin, device=torch.device("cpu"))
    scene.xyz = torch.as_tensor((wall - origin).astype(np.float32))
    scene.rgb = torch.full((len(wall), 3), 0.5)
    car = shapes.procedural_car_gaussians(count=20_000, seed=1)
    place = np.eye(4)
    place[:3, 3] = origin + (0.0, 6.0, -1.84)
    scene.assets.append(fr.make_asset("car", car, {7: place}, "cpu"))
    scene.assets.append(fr.make_asset("elsewhere", car, {8: place}, "cpu"))  # not at frame 7
    T = np.eye(4)
    T[:3, 3] = origin
    got = sim.sweep_for_frame(scene, 7, T, NUSCENES)
    want = sim.simulate(NUSCENES, T, wall, np.full((len(wall), 3), 0.5),
                        gaussians=[(car.means @ place[:3, :3].T + place[:3, 3], car.opacities,
                                    np.clip(0.5 + 0.28209479177387814 * car.sh[:, 0], 0, 1))])
    assert np.array_equal(got.column, want.column) and np.array_equal(got.source, want.source)
    assert np.abs(got.range_m - want.range_m).max() < 1e-4 and (got.source == 1).sum() > 50
    assert not np.any(got.source == 2)
    # at a frame no asset has, with no source frame chosen: nothing (the scene's frames pick its points)
    scene.frame = torch.zeros(len(wall), dtype=torch.int64)
    scene.frames_present = frozenset({0})
    assert len(sim.sweep_for_frame(scene, 9, T, NUSCENES, source_frames=[])) == 0
    alone = sim.sweep_for_frame(scene, 9, T, NUSCENES, source_frames=[0])  # the wall, no car at frame 9
    assert len(alone) > (got.source == 0).sum() and np.all(alone.source == 0) and alone.range_m.min() > 9.9
