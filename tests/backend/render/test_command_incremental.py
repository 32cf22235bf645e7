"""Incremental rendering (core.frame_keys): an edit re-renders exactly the frames it touches, and the folder then
holds what a full render of the edited job makes, bit for bit.

The street's recorded drive (16 frames, 1 m apart along +y) at 128 x 72 with two parked cars: one beside the
first metres of the drive (seen in the first frames only), one far ahead (seen in every frame). Moving the first
car by 0.3 m must re-render the frames where it can be seen before or after the move and keep the others; every
frame whose layers really change must be among the re-rendered ones.
"""

import os

import numpy as np
import pytest

from backend.render import channels
from backend.render import command as render_cmd
from scpainter_blender.core import files, frame_keys, shapes
from scpainter_blender.core import job as J
from scpainter_blender.core.geometry import cameras, visibility
from scpainter_blender.core.output_layout import OutputLayout
from scpainter_blender.core.splats import gaussians as splats, inria, reader as splats_io
from tests_support import street_base_job

W, H = 128, 72
NEAR_CAR = (-3.5, 6.0, 0.0)   # beside the drive's first 6 m: behind the camera after them
FAR_CAR = (3.0, 40.0, 0.0)    # ahead of every camera


def _place(job: J.Job, where) -> dict:
    A = np.eye(4)
    A[:3, 3] = where
    return {e.frame: A.copy() for e in job.frames}


def _job(street, folder, near=NEAR_CAR) -> str:
    path = os.path.join(folder, "job.json")
    base = street_base_job(street, path)
    scale = np.diag([W / base.resolution[0], H / base.resolution[1], 1.0])
    for e in base.frames:
        e.K = scale @ e.K
    base.resolution = (W, H)
    car = os.path.join(os.path.dirname(folder), "car.ply")
    if not os.path.isfile(car):
        inria.write_ply(car, splats.encode(shapes.procedural_car_gaussians(count=3000, seed=4)))
    base.assets = [J.Asset("near", os.path.relpath(car, folder), _place(base, near)),
                   J.Asset("far", os.path.relpath(car, folder), _place(base, FAR_CAR))]
    J.save(path, base)
    return path


def _render(path, force=False) -> dict:
    return render_cmd.render_job(path, J.load(path), "cpu", force=force, allow_outside=True)


def _layers(folder, frame) -> dict:
    return channels.read(OutputLayout(os.path.join(folder, ".")).condition_exr(frame))


@pytest.fixture(scope="module")
def rendered(street, tmp_path_factory):
    root = tmp_path_factory.mktemp("incremental")
    first = str(root / "edited")
    os.makedirs(first)
    path = _job(street, first)
    done = _render(path)
    assert done["rendered"] == 16
    return root, path


def test_moving_a_car_renders_only_the_frames_it_touches(rendered, street):
    root, path = rendered
    folder = os.path.dirname(path)
    job = J.load(path)
    before = {f: _layers(folder, f) for f in (e.frame for e in job.frames)}
    mtimes = {f: os.stat(OutputLayout(folder).condition_exr(f)).st_mtime_ns for f in before}
    g = splats_io.load(J.resolve(path, job.assets[0].ply))
    bounds, max_sigma = visibility.asset_bounds(g.means, g.quats, g.scales)
    moved = tuple(np.add(NEAR_CAR, (0.3, 0.0, 0.0)))
    job.assets[0].object_to_world = _place(job, moved)
    J.save(path, job)

    centre = cameras.camera_centers(job.frames[0].world_to_camera)  # the renderer's scene origin

    def seen(where):
        A = _place(job, where)
        return {e.frame for e in job.frames if not visibility.asset_unseen(
            bounds, max_sigma, A[e.frame], centre, e.K, visibility.relative_camera(e.world_to_camera, centre), W, H)}

    touched = seen(NEAR_CAR) | seen(moved)
    assert 0 < len(touched) < 16, touched   # the car is seen in some frames, not all: the test means something

    done = _render(path)
    assert done["rendered"] == len(touched) and done["relabelled"] == 16 - len(touched)
    after = {f: _layers(folder, f) for f in before}
    rerendered = {f for f in before if os.stat(OutputLayout(folder).condition_exr(f)).st_mtime_ns != mtimes[f]}
    assert rerendered == touched
    changed = {f for f in before if any(not np.array_equal(before[f][c], after[f][c]) for c in channels.CHANNELS)}
    assert changed and changed <= touched   # every frame that really changed was rendered again

    # the folder now holds exactly what a full render of the edited job makes
    fresh = str(root / "fresh")
    os.makedirs(fresh)
    fresh_path = _job(street, fresh, near=moved)
    assert _render(fresh_path)["rendered"] == 16
    for f in before:
        full = _layers(fresh, f)
        for c in channels.CHANNELS:
            assert np.array_equal(after[f][c], full[c]), (f, c)
        a = files.read_json(OutputLayout(folder).frame_labels(f))
        b = files.read_json(OutputLayout(fresh).frame_labels(f))
        assert a["objects"] == b["objects"] and a["layers_key"] == b["layers_key"] and a["key"] == b["key"]

    # nothing changed: nothing rendered, and Blender's plan (from the record alone) agrees with the backend's
    p = frame_keys.plan_from_record(folder, path, J.load(path))
    assert p is not None and p.up_to_date and len(p.done) == 16
    assert _render(path)["rendered"] == 0


def test_plan_needs_the_backend_when_an_asset_file_changed(rendered):
    _, path = rendered
    folder = os.path.dirname(path)
    job = J.load(path)
    assert frame_keys.plan_from_record(folder, path, job) is not None
    car = J.resolve(path, job.assets[0].ply)
    st = os.stat(car)
    os.utime(car, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    assert frame_keys.plan_from_record(folder, path, job) is None   # its extent may have changed: the backend says
    os.utime(car, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert frame_keys.plan_from_record(folder, path, job).up_to_date


def test_a_frame_killed_after_its_exr_is_rendered_again(rendered):
    """A frame's labels are removed before its EXR is replaced: an EXR written under a new key never sits beside
    labels of the old one (reverting the edit would otherwise keep it)."""
    _, path = rendered
    folder = os.path.dirname(path)
    job = J.load(path)
    layout = OutputLayout(folder)
    f = job.frames[0].frame
    os.remove(layout.frame_labels(f))          # as a kill between the EXR and the labels leaves it
    p = frame_keys.plan_from_record(folder, path, job)
    assert p.render == {f}
    done = _render(path)
    assert done["rendered"] == 1 and os.path.isfile(layout.frame_labels(f))
