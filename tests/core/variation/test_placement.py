"""Footprints and the rejection rules of core/variation/placement.py."""

import numpy as np
import pytest

from scpainter_blender.core.geometry import boxes
from scpainter_blender.core.variation import placement, road as road_mod
from tests.core.variation.test_road import synthetic_street


def test_overlap_matches_the_reference_on_random_rectangles():
    rng = np.random.default_rng(0)
    a, b = [], []
    for _ in range(2000):
        for out in (a, b):
            h = rng.normal(size=2)
            out.append(placement.rectangle(rng.uniform(-3, 3, 2), h / np.linalg.norm(h), *rng.uniform(0.2, 5, 2)))
    fast = placement.rectangles_overlap(np.array(a), np.array(b))
    ref = np.array([placement.rectangles_overlap_reference(x, y) for x, y in zip(a, b)])
    assert (fast == ref).all() and 200 < fast.sum() < 1800


def test_box_footprint_and_box_on_ground():
    P, cams, _ = synthetic_street(slope=0.05)
    road = road_mod.Road(P, cams)
    size = np.array([1.9, 4.5, 1.5])
    heading = np.array([np.sin(0.3), np.cos(0.3)])
    T = placement.box_on_ground(road, np.array([2.5, 10.0]), heading, size)
    assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
    bottom = T[:3, 3] - T[:3, 2] * size[2] / 2
    assert bottom[2] == pytest.approx(road.ground(bottom[:2])[0], abs=1e-3)     # stands on the plane
    assert T[:3, 2] @ np.array([0, -0.05, 1]) / np.linalg.norm([0, -0.05, 1]) > 0.99999  # up = the hill's normal
    foot = placement.box_footprint(T, size)
    corners = boxes.corners(T, size)[:, :2]
    # the box's own rectangle, about its centre: on a 5 % hill the tilted bottom face lies h/2 · sin(2.9°) downhill
    assert np.allclose(np.sort(foot, 0), np.sort(corners[::2], 0), atol=0.75 * 0.05 + 0.003)
    assert placement.box_on_ground(road, np.array([0.0, 500.0]), heading, size) is None


def test_each_rule_rejects_its_case():
    P, cams, (c, _) = synthetic_street()
    road = road_mod.Road(P, cams)
    frames = [1, 2, 3]
    ego = {f: placement.rectangle(np.array([0.0, float(f)]), np.array([0.0, 1.0]), 5.8, 3.0) for f in frames}
    fixed = {f: [placement.rectangle(np.array([3.0, 30.0]), np.array([0.0, 1.0]), 4.5, 1.9)] for f in frames}
    rules = placement.Rules(road, frames, ego, fixed, gap_m=0.5)
    size = np.array([1.9, 4.5, 1.5])

    def parked(x, y):
        T = placement.box_on_ground(road, np.array([x, y]), np.array([0.0, 1.0]), size)
        foot = placement.box_footprint(T, size)
        return placement.Car(size, dict.fromkeys(frames, T), dict.fromkeys(frames, foot))

    assert rules.check(parked(2.5, 12.0)) is None
    assert rules.check(parked(0.5, 2.0)) == "ego_path"              # on the ego path
    assert rules.check(parked(7.0, 12.0)) == "off_road"              # on the sidewalk
    assert rules.check(parked(c[0], c[1])) == "recorded_object"      # inside the recorded car (its points)
    assert rules.check(parked(3.0, 30.0 + 4.8)) == "recorded_box"    # 0.3 m from a recorded box: inside the gap
    rules.placed.append(parked(2.5, 12.0))
    assert rules.check(parked(2.8, 15.0)) == "car_overlap"           # stacked onto the car placed before
    assert rules.check(parked(2.5, 12.0 + 4.5 + 0.6)) is None        # 0.6 m behind it: beyond the gap


def test_a_moving_car_is_checked_at_every_frame():
    P, cams, _ = synthetic_street()
    road = road_mod.Road(P, cams)
    frames = [1, 2, 3]
    far = {f: placement.rectangle(np.array([0.0, -50.0]), np.array([0.0, 1.0]), 1.0, 1.0) for f in frames}
    rules = placement.Rules(road, frames, far, {f: [] for f in frames}, gap_m=0.5)
    size = np.array([1.9, 4.5, 1.5])
    xs = {1: 2.5, 2: 4.0, 3: 6.5}  # drifts onto the sidewalk by frame 3
    Ts = {f: placement.box_on_ground(road, np.array([xs[f], 10.0 + f]), np.array([0.0, 1.0]), size) for f in frames}
    car = placement.Car(size, Ts, {f: placement.box_footprint(T, size) for f, T in Ts.items()}, moving=True)
    assert rules.check(car) == "off_road"


def test_path_is_continued_beyond_its_ends():
    c = np.column_stack([np.zeros(5), np.arange(5.0), np.zeros(5)])
    h = np.tile([0.0, 1.0, 0.0], (5, 1))
    path = placement.Path.of(c, h)
    xy, head = path.at(np.array([-2.0, 1.5, 7.0]))
    assert np.allclose(xy, [[0, -2], [0, 1.5], [0, 7]]) and np.allclose(head, [[0, 1]] * 3)


def test_project_is_the_inverse_of_at_with_an_offset():
    """A point ``off`` m left of the path at arc ``s`` projects back to (s, off): on a bend, and beyond both ends
    (the path continued straight)."""
    a = np.radians(np.arange(0.0, 90.5, 1.0))    # a quarter circle of radius 20 m, turning left, 1° steps
    c = np.column_stack([-20.0 * (1 - np.cos(a)), 20.0 * np.sin(a), np.zeros_like(a)])
    h = np.column_stack([-np.sin(a), np.cos(a), np.zeros_like(a)])
    path = placement.Path.of(c, h)
    for s, off in ((5.0, 1.5), (17.0, -2.0), (-4.0, 3.5), (path.length + 6.0, -1.0)):
        xy, head = path.at(np.array([s]))
        p = xy[0] + off * np.array([-head[0, 1], head[0, 0]])
        s2, off2 = path.project(p)
        assert s2 == pytest.approx(s, abs=0.05) and off2 == pytest.approx(off, abs=0.02)


def test_drive_is_box_on_ground_along_the_lane():
    """``drive``: start + speed · t along the path, the lane to its left, each pose ``box_on_ground``; oncoming
    (negative speed) faces the other way; ``reach`` holds it at the end; no ground: None."""
    P, cams, _ = synthetic_street()
    road = road_mod.Road(P, cams)
    path = placement.Path.of(cams, np.tile([0.0, 1.0, 0.0], (len(cams), 1)))
    size = np.array([1.9, 4.5, 1.5])
    t = np.arange(6) / 10.0
    arc, poses = placement.drive(road, path, size, 2.5, 8.0, 3.0, t)
    assert np.allclose(arc, 3.0 + 8.0 * t)
    for s, T in zip(arc, poses):   # the path runs along +y at x = 0: left is −x
        assert np.array_equal(T, placement.box_on_ground(road, np.array([-2.5, s]), np.array([0.0, 1.0]), size))
    assert T[2, 3] == pytest.approx(0.75, abs=0.02) and np.allclose(T[:3, 1], [0, 1, 0], atol=0.01)
    _, back = placement.drive(road, path, size, -2.5, -5.0, 20.0, t)
    assert np.allclose(back[-1][:3, 1], [0, -1, 0], atol=0.01) and back[-1][1, 3] == pytest.approx(17.5, abs=0.01)
    arc, held = placement.drive(road, path, size, 0.0, 8.0, 3.0, t, reach=(0.0, 5.0))
    assert arc.max() == 5.0 and np.array_equal(held[-1], held[-2])
    _, lost = placement.drive(road, path, size, 200.0, 8.0, 3.0, t)   # far beyond the reconstruction
    assert all(T is None for T in lost)
