"""core.geometry.trajectory: the direction of travel (straight, curved, stopping, parked, far away) and lateral shifts."""

import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core.geometry import trajectory


def test_heading_straight_and_curved():
    y = np.arange(20.0)
    straight = np.stack([np.zeros(20), y, np.full(20, 1.6)], 1)
    h = trajectory.heading_directions(straight)
    assert np.allclose(h, [0, 1, 0])
    ang = np.linspace(0, np.pi / 2, 50)
    arc = np.stack([100 * np.cos(ang), 100 * np.sin(ang), np.zeros(50)], 1)
    h = trajectory.heading_directions(arc, window_m=0.5)
    tangent = np.stack([-np.sin(ang), np.cos(ang), np.zeros(50)], 1)
    assert np.degrees(np.arccos(np.clip((h * tangent).sum(1), -1, 1))).max() < 2.0  # chord vs tangent at ends


def test_heading_stable_when_vehicle_stops():
    """Repeated positions (a stop, with 1 mm jitter) keep the heading of the motion around them."""
    rng = np.random.default_rng(0)
    before = np.stack([np.zeros(10), np.arange(10.0), np.zeros(10)], 1)
    stop = np.tile(before[-1], (30, 1)) + rng.normal(0, 1e-3, (30, 3)) * [1, 1, 0]
    after = before[-1] + np.stack([np.zeros(10), np.arange(1, 11.0), np.zeros(10)], 1)
    path = np.concatenate([before, stop, after])
    h = trajectory.heading_directions(path, window_m=2.0)
    assert np.degrees(np.arccos(np.clip(h @ [0, 1, 0], -1, 1))).max() < 1.0


def test_heading_parked_uses_fallback_or_explains():
    path = np.tile([3.0, 4.0, 1.6], (5, 1))
    with pytest.raises(ValueError, match="does not move"):
        trajectory.heading_directions(path)
    h = trajectory.heading_directions(path, fallback=[0.0, 1.0, -0.2])
    assert np.allclose(h, [0, 1, 0])


def test_heading_far_from_origin():
    y = np.arange(10.0)
    path = np.stack([np.full(10, 1e5), 1e5 + y, np.zeros(10)], 1)
    assert np.allclose(trajectory.heading_directions(path), [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize("offset", [0.0, 1e5])
def test_shift_trajectory_left_is_left_and_exact(offset):
    S = 12
    T = np.tile(np.eye(4), (S, 1, 1))
    T[:, :3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # looking along +Y
    centres = np.stack([np.full(S, offset), offset + np.arange(S) * 1.5, np.full(S, 1.6)], 1)
    T[:, :3, 3] = -np.einsum("nij,nj->ni", T[:, :3, :3], centres)
    out = trajectory.shift_trajectory(T, left_m=2.0)
    d = C.camera_centers(out) - centres
    assert np.abs(d - [-2.0, 0, 0]).max() < 1e-9 * max(1, offset)  # driving along +Y, left is -X
    assert np.array_equal(out[:, :3, :3], T[:, :3, :3])
    right = trajectory.shift_trajectory(T, left_m=-3.0, up_m=0.5)
    assert np.abs(C.camera_centers(right) - centres - [3.0, 0, 0.5]).max() < 1e-9 * max(1, offset)
