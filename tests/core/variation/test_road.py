"""The road found headless (core/variation/road.py) on a synthetic street whose every height is known: a road
(|x| < 5 m, z = 0), kerbs and sidewalks (z = 0.15 m) beyond, a recorded car (a block of points) on the road."""

import numpy as np
import pytest

from scpainter_blender.core.variation import placement, road as road_mod


def synthetic_street(offset=(0.0, 0.0, 0.0), slope=0.0, seed=0):
    """(points (N, 3), camera centres (F, 3), car box (centre, size)) of a straight street along +y; ``slope``:
    the road rises by that many metres per metre of y (a hill)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([-9.0, -5.0], [9.0, 40.0], (120_000, 2))
    z = np.where(np.abs(xy[:, 0]) < 5.0, 0.0, 0.15) + slope * xy[:, 1]
    ground = np.column_stack([xy, z + rng.normal(0, 0.005, len(z))])
    # a recorded car: the points of its surface (its sides, front, back and roof), on the left lane
    c, size = np.array([-3.0, 20.0, 0.75]), np.array([1.9, 4.5, 1.5])
    u = rng.uniform(-0.5, 0.5, (20_000, 3)) * size
    face = rng.integers(0, 3, len(u))
    u[np.arange(len(u)), face] = np.sign(u[np.arange(len(u)), face]) * size[face] / 2
    car = u + c
    car[:, 2] += slope * car[:, 1]
    ground = ground[~((np.abs(ground[:, 0] - c[0]) < size[0] / 2) & (np.abs(ground[:, 1] - c[1]) < size[1] / 2))]
    P = np.vstack([ground, car]) + np.asarray(offset)
    cams = np.column_stack([np.zeros(16), np.arange(16.0), 1.6 + slope * np.arange(16.0)]) + np.asarray(offset)
    return P, cams, (c + np.asarray(offset), size)


def rect(x, y, length=4.5, width=1.9, offset=(0.0, 0.0)):
    return placement.rectangle(np.array([x, y]) + np.asarray(offset[:2]), np.array([0.0, 1.0]), length, width)


@pytest.fixture(scope="module")
def street():
    P, cams, car = synthetic_street()
    return road_mod.Road(P, cams), car


def test_ground_height_and_road_extent(street):
    road, _ = street
    z, n = road.ground(np.array([[0.0, 10.0], [4.0, 30.0], [7.0, 10.0]]))
    assert np.allclose(z, [0.0, 0.0, 0.15], atol=0.01)
    assert np.allclose(n[:, 2], 1.0, atol=1e-3)
    assert road.is_road(np.array([[0.0, 10.0], [-4.4, 30.0]])).all()
    assert not road.is_road(np.array([[6.0, 10.0], [-8.0, 10.0]])).any()  # the sidewalks, beyond the kerbs
    assert road.edge_distance(np.array([0.0, 10.0]), np.array([1.0, 0.0]), 12.0) == pytest.approx(5.0, abs=0.5)


def test_each_rule_of_the_footprint(street):
    road, (c, size) = street
    assert road.check_footprint(rect(2.5, 10.0)) is None                     # on the right lane
    assert road.check_footprint(rect(7.0, 10.0)) == "off_road"               # on the sidewalk
    assert road.check_footprint(rect(5.0, 10.0)) == "off_road"               # across the kerb
    assert road.check_footprint(rect(0.0, 200.0)) == "off_road"              # beyond the reconstruction
    assert road.check_footprint(rect(c[0], c[1])) == "recorded_object"       # inside the recorded car
    assert road.check_footprint(rect(c[0] + 1.0, c[1] + 2.0)) == "recorded_object"  # half into it


def test_far_from_the_origin_and_on_a_hill():
    """1e5 m coordinates and a 5 % slope give the same answers."""
    off = (1e5, -2e5, 300.0)
    P, cams, (c, size) = synthetic_street(offset=off, slope=0.05)
    road = road_mod.Road(P, cams)
    assert road.check_footprint(rect(2.5, 10.0, offset=off)) is None
    assert road.check_footprint(rect(7.0, 10.0, offset=off)) == "off_road"
    assert road.check_footprint(rect(c[0], c[1])) == "recorded_object"
    z, _ = road.ground(np.array([[off[0] + 2.5, off[1] + 10.0]]))
    assert z[0] == pytest.approx(off[2] + 0.5, abs=0.02)


def test_no_road_under_the_drive_is_refused():
    rng = np.random.default_rng(0)
    wall = np.column_stack([rng.uniform(-5, 5, 5000), np.full(5000, 3.0), rng.uniform(0, 5, 5000)])  # vertical
    with pytest.raises(ValueError, match="no level ground"):
        road_mod.Road(wall, np.array([[0.0, 0.0, 1.6], [0.0, 1.0, 1.6]]))


def test_nan_rows_and_an_empty_cloud():
    P, cams, _ = synthetic_street()
    P[::7] = np.nan
    assert road_mod.Road(P, cams).check_footprint(rect(2.5, 10.0)) is None
    with pytest.raises(ValueError):
        road_mod.Road(np.zeros((0, 3)), cams)


def test_footprint_samples_cover_the_rectangle():
    S = road_mod.footprint_samples(rect(0.0, 0.0))
    assert S[:, 0].min() == pytest.approx(-0.95) and S[:, 0].max() == pytest.approx(0.95)
    assert S[:, 1].min() == pytest.approx(-2.25) and S[:, 1].max() == pytest.approx(2.25)
    assert np.diff(np.unique(S[:, 1])).max() <= road_mod.SAMPLE_SPACING_M + 1e-9
