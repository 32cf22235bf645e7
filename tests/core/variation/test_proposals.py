"""Box proposals (core/variation/proposals.py): on a synthetic street whose every object is known (a flat road,
sidewalks beyond kerbs, two parked boxes of points, a pole on the sidewalk), and on the ground-truth street."""

import time

import numpy as np
import pytest

from scpainter_blender.core import job as J
from scpainter_blender.core.variation import proposals, variants

from tests_support import street_base_job, street_parked_cars

#: The synthetic objects' boxes come back within these (the points are the boxes' surfaces, so only the search's
#: 0.02° steps and the road's 5 mm noise are lost).
CENTRE_TOL_M, SIZE_TOL_M, HEADING_TOL_DEG = 0.05, 0.05, 0.5


def surface(centre, size, yaw_deg, n, rng):
    """``n`` points on the sides and top of an upright box standing on z = 0 (what a camera sees of a car)."""
    u = rng.uniform(-0.5, 0.5, (n, 3)) * size
    face = rng.integers(0, 3, n)
    u[np.arange(n), face] = np.where(face == 2, 0.5, np.sign(u[np.arange(n), face]) * 0.5) * size[face]
    a = np.radians(yaw_deg)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return u @ R.T + np.asarray(centre)


def box_to_world(centre, yaw_deg):
    a = np.radians(yaw_deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    T[:3, 3] = centre
    return T


CARS = [((-3.0, 20.0, 0.75), np.array([1.9, 4.5, 1.5]), 4.0),     # covered by a recorded object
        ((3.5, 12.0, 0.9), np.array([2.0, 6.5, 1.8]), -3.0)]      # nothing labels it: a truck-sized proposal


def synthetic_job(recorded=True, n_frames=16):
    """(points, job): a straight street along +y (road |x| < 5 m at z = 0, sidewalks at 0.15 m), the two boxes of
    ``CARS`` standing on the road, a pole on the sidewalk; a drive along x = 0 at 1.6 m; the first car a recorded
    object when ``recorded``."""
    rng = np.random.default_rng(0)
    xy = rng.uniform([-9.0, -5.0], [9.0, 40.0], (120_000, 2))
    ground = np.column_stack([xy, np.where(np.abs(xy[:, 0]) < 5.0, 0.0, 0.15) + rng.normal(0, 0.005, len(xy))])
    parts = [ground]
    for centre, size, yaw in CARS:
        c = np.array(centre)
        c[2] = size[2] / 2
        parts.append(surface(c, size, yaw, 20_000, rng))
    parts.append(surface((7.5, 15.0, 1.65), np.array([0.3, 0.3, 3.0]), 0.0, 2_000, rng))   # a pole: not a proposal
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])        # OpenCV camera looking along +y
    frames = []
    for i in range(n_frames):
        w2c = np.eye(4)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ np.array([0.0, float(i), 1.6])
        frames.append(J.Frame(i + 1, np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]]), w2c, []))
    scene = J.Scene("predictions.npz", np.eye(4))
    if recorded:
        (c, size, yaw) = CARS[0]
        T = box_to_world((c[0], c[1], size[2] / 2), yaw)
        scene.recorded_objects = [J.RecordedObject("car_a", size, {f.frame: T for f in frames})]
    return np.vstack(parts), J.Job((64, 48), frames, ".", scene)


def heading_deg(T):
    return np.degrees(np.arctan2(-T[0, 1], T[1, 1]))   # the box's +y turned from the world's +y


def test_one_proposal_for_the_object_nothing_labels():
    points, job = synthetic_job()
    found = proposals.propose(points, job)
    assert [p.id for p in found] == ["proposal_01"]
    (c, size, yaw) = CARS[1]
    p = found[0]
    assert np.allclose(p.box_to_world[:3, 3], [c[0], c[1], size[2] / 2], atol=CENTRE_TOL_M)
    assert np.allclose(p.size, size, atol=SIZE_TOL_M)
    assert abs((heading_deg(p.box_to_world) - yaw + 90) % 180 - 90) < HEADING_TOL_DEG
    assert p.category == "truck" and p.points > 10_000 and 0.5 < p.score <= 1.0
    # as a recorded object: a static box at every frame, the ignore flag as asked
    o = p.recorded_object([f.frame for f in job.frames], ignore=True)
    assert o.ignore and o.category == "truck" and sorted(o.boxes) == list(range(1, 17))
    assert np.array_equal(o.boxes[3], p.box_to_world)
    assert proposals.Proposal.from_dict(p.to_dict()).to_dict() == p.to_dict()


def test_without_the_recorded_object_both_are_proposed_in_order_and_stably():
    points, job = synthetic_job(recorded=False)
    found = proposals.propose(points, job)
    # nearest the first camera (0, 0) first: the truck at y = 12, then the car at y = 20
    assert [(p.id, p.category) for p in found] == [("proposal_01", "truck"), ("proposal_02", "car")]
    assert [p.to_dict() for p in proposals.propose(points, job)] == [p.to_dict() for p in found]  # the same input
    again = proposals.propose(points[::-1].copy(), job)  # the points in another order: the same ids, the same boxes
    assert [(p.id, p.category) for p in again] == [(p.id, p.category) for p in found]
    for a, b in zip(again, found):
        assert np.allclose(a.box_to_world, b.box_to_world, atol=1e-3) and np.allclose(a.size, b.size, atol=1e-3)


def test_a_removal_box_or_an_asset_box_covers_too():
    points, job = synthetic_job(recorded=False)
    (c, size, yaw) = CARS[0]
    T = box_to_world((c[0], c[1], size[2] / 2), yaw)
    job.scene.removal_boxes = [J.RemovalBox(T, size)]
    assert [p.category for p in proposals.propose(points, job)] == ["truck"]
    job.scene.removal_boxes = []
    asset = J.Asset("car_01", "car.ply", {f.frame: T for f in job.frames}, box=J.AssetBox(np.eye(4), size))
    job.assets = [asset]
    assert [p.category for p in proposals.propose(points, job)] == ["truck"]


@pytest.mark.parametrize("size, expected", [((1.8, 4.4, 1.5), "car"), ((0.1, 3.5, 1.5), "car"),
                                            ((2.5, 8.0, 3.2), "truck"), ((0.5, 0.6, 1.7), "misc"),
                                            ((1.0, 2.0, 0.6), "misc")])
def test_class_from_size(size, expected):
    assert proposals.guess_class(size) == expected


def test_components_are_8_connected():
    grid = np.zeros((6, 6), bool)
    grid[0, 0] = grid[1, 1] = grid[2, 2] = True          # a diagonal: one cluster
    grid[4:6, 4:6] = True
    found = proposals.components(grid)
    assert [len(c) for c in found] == [3, 4]


def test_the_streets_parked_cars(street, tmp_path):
    """The street's parked cars that its reconstruction shows (points inside their true box) are each proposed
    once, and nothing else is: a proposal's centre lies inside its car's true box grown by 0.3 m, its box inside it
    grown by 0.3 m (what the points show: a car seen from one side has a thin box), and a car seen whole (both
    sides and the roof: parked car 2) matches its truth within 0.15 m and 2°. All within 2 s (measured: ~1.3 s on
    the 2-core machine, points loaded as the renderer does included)."""
    path = str(tmp_path / "job.json")
    street_base_job(street, path)
    job = J.load(path)
    t = time.perf_counter()
    found = proposals.propose(variants.scene_points(job, path), job)
    seconds = time.perf_counter() - t
    assert seconds < 2.0 * 3  # the 2 s budget, with room for a busy shared machine
    cars = street_parked_cars(street)
    points = variants.scene_points(job, path)
    seen = [k for k, (T, size) in enumerate(cars)
            if (np.abs((points - T[:3, 3]) @ T[:3, :3]) <= size / 2).all(1).sum() > 1000]
    assert len(seen) == 3 and len(found) == len(seen)
    matched = []
    for p in found:
        corners = p.box_to_world[:3, :3] @ (np.array(np.meshgrid(*[[-0.5, 0.5]] * 3)).reshape(3, -1)
                                            * p.size[:, None]) + p.box_to_world[:3, 3:4]
        k = [k for k in seen if (np.abs((p.box_to_world[:3, 3] - cars[k][0][:3, 3]) @ cars[k][0][:3, :3])
                                 <= cars[k][1] / 2 + 0.3).all()]
        assert len(k) == 1, p
        T, size = cars[k[0]]
        local = (corners.T - T[:3, 3]) @ T[:3, :3]
        assert (np.abs(local) <= size / 2 + 0.3).all()
        assert p.category == "car"
        matched.append(k[0])
        if k[0] == 1:
            assert np.allclose(p.box_to_world[:3, 3], T[:3, 3], atol=0.15)
            assert np.allclose(p.size, size, atol=0.15)
            assert abs(heading_deg(p.box_to_world) - heading_deg(T)) < 2.0
    assert sorted(matched) == seen


def test_every_camera_path_of_a_drive_shares_the_drives_proposals(street, tmp_path):
    """The road grows from the recording's own cameras (``variants.recorded_path``: the predictions' poses through
    ``vggt_to_world``, here within 1 mm of the street's true cameras), not the job's: a camera path 3 m to the
    side gets the drive's proposals, from the same per-process entry (computed once for both)."""
    from scpainter_blender.core import job_inputs

    path = str(tmp_path / "base" / "job.json")
    base = street_base_job(street, path)
    preds = job_inputs.scene_predictions(path, base.scene)
    assert np.abs(variants.recorded_path(base, preds).centres - variants.reference_path(base).centres).max() < 1e-3
    shifted_frames = []
    for f in base.frames:
        w2c = np.array(f.world_to_camera)
        w2c[:3, 3] -= w2c[:3, :3] @ np.array([-3.0, 0.0, 0.0])    # the camera 3 m to the left (world -x)
        shifted_frames.append(J.Frame(f.frame, f.K, w2c, f.source_frames))
    shifted_path = str(tmp_path / "shifted" / "job.json")
    import dataclasses
    import os

    os.makedirs(os.path.dirname(shifted_path))
    shifted = dataclasses.replace(base, frames=shifted_frames, scene=dataclasses.replace(
        base.scene, predictions=os.path.abspath(street.predictions_path)))
    proposals._SCENES.clear()
    _, found, _ = proposals.with_proposals(base, path, "ignore")
    _, found_shifted, _ = proposals.with_proposals(shifted, shifted_path, "ignore")
    assert len(proposals._SCENES) == 1 and len(found) == 3
    assert [(p.id, p.category) for p in found_shifted] == [(p.id, p.category) for p in found]
    assert all(np.array_equal(a.box_to_world, b.box_to_world) for a, b in zip(found, found_shifted))
