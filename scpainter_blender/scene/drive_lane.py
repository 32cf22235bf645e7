"""*Drive Along Lane*: a Gaussian car asset keyed driving along the recorded drive, in a lane, at a speed
(docs/design.md §8, §16).

The car's pose per frame is the scenario command's own (``core.variation.placement.drive``, what ``vary`` uses for
its moving cars): the drive is the recorded camera's ground track as the job sees it (``variants.reference_path``
of the job ``job_export.build_job`` writes from the recorded camera), the road is found from the points as the
renderer loads them (``variants.scene_points``, ``core.variation.road.Road``; kept for the session per points and
drive, ``road_of``), and the car's own box (its asset box, scene/asset_box.py: centre, size, front) stands on the
road's local plane at every frame, its front along the drive (against it when oncoming).

Rules (frames are scene frames, times seconds at the scene's frame rate):

- At ``start_frame`` the car is level with where it stands at that frame (its box centre projected on the drive,
  ``Path.project``), ``lane_m`` metres left of the drive (a negative lane is to the right); at frame f it is
  ``speed · (f − start_frame) / fps`` metres further along. Speed 0 stands still in the lane; a negative speed
  drives against the drive's direction (oncoming traffic), facing that way.
- Keys: location and rotation (quaternion; the rotation mode becomes QUATERNION) at every scene frame from
  ``max(start_frame, frame_start)`` to ``frame_end``, LINEAR (one key per frame: sub-frames, motion blur, lie on
  the straight line between). The asset's earlier location and rotation keys are replaced (its other curves are
  kept); before the first key the car holds its start pose (the curves' constant extrapolation), after the last
  its last.
- At the end of the road found along the drive (``Road.road_arc``: where the drive's line, continued, runs on the
  road) the car **stops** and holds there; the report says from which frame. A car that stands beyond that reach
  at the start frame is refused, and so is a lane whose ground the road does not know at some frame (off the
  reconstruction). Frames where its footprint leaves the road or runs into something recorded
  (``Road.check_footprint``) are keyed and reported.
"""

from __future__ import annotations

import json
import os
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..core.geometry import boxes, cameras
from ..core.variation import placement as car_placement, variants
from ..core.variation.road import Road
from ..core.variation.spec import VariationSpec
from . import asset_box, compat, job_export, keys, kinds, paths
from .props import SceneError

#: Roads kept for the session (each ~1 s to find on a street of 1.2 M points), newest last.
_ROADS: OrderedDict = OrderedDict()
_MAX_ROADS = 2
#: The seed of the road's RANSAC fits: the scenario command's default, so both find the same road for the same
#: points.
ROAD_SEED = VariationSpec.seed
#: The curves a drive keys (and replaces).
KEYED = ("location", "rotation_quaternion")


@dataclass
class Drive:
    """What a drive keyed: the scene ``frames`` (F,), the car's box per frame ``box_to_world`` (F, 4, 4) and its
    ``size`` (width, length, height) m, the metres along the drive ``arc`` (F,), the first frame it stood at the
    road's end (None: it never did), and the frames whose footprint broke a road rule (``{rule: [frames]}``)."""
    frames: list
    box_to_world: np.ndarray
    size: np.ndarray
    arc: np.ndarray
    stopped_at: int | None
    off_road: dict

    @property
    def distance_m(self) -> float:
        """Metres driven along the drive between the first and the last keyed frame."""
        return float(abs(self.arc[-1] - self.arc[0]))


def drive_job(context):
    """(job, job path) of the scene seen from its recorded camera (``job_export.build_job``; nothing written): the
    drive and the points the car drives on. SceneError without a recorded camera or a points object."""
    scene = context.scene
    cam = kinds.recorded_camera(scene)
    if cam is None:
        raise SceneError("scene.objects", "the scene has no recorded camera: the car drives along the recorded drive",
                         hint="import a VGGT reconstruction (File > Import > SCPainter VGGT Reconstruction)")
    pts = kinds.point_cloud(scene)
    if pts is None:
        raise SceneError("scene.objects", "the scene has no points object: the car drives on the reconstructed road",
                         hint="import a VGGT reconstruction (File > Import > SCPainter VGGT Reconstruction)")
    # a job beside the predictions (never written): their path in it stays a plain name
    job_path = os.path.join(os.path.dirname(paths.resolve(pts[keys.SOURCE])), "job.json")
    return job_export.build_job(context, job_path, camera=cam), job_path


def road_of(job, job_path) -> Road:
    """The road of a job's points along its drive (``variants.scene_points``, ``Road``), as the scenario command
    finds it; kept for the session per points (the scene block: file, transform, cleaning, removal boxes; the
    file's size and time) and drive. SceneError when no road lies under the drive."""
    d = job.to_dict()
    source = os.path.join(os.path.dirname(job_path), job.scene.predictions)
    try:
        st = os.stat(source)
        stamp = [st.st_size, st.st_mtime_ns]
    except OSError:
        stamp = None  # the reader says what is wrong with it
    key = json.dumps([d["scene"], [f["world_to_camera"] for f in d["frames"]], stamp], sort_keys=True)
    if key in _ROADS:
        _ROADS.move_to_end(key)
        return _ROADS[key]
    path = variants.reference_path(job)
    try:
        road = Road(variants.scene_points(job, job_path), path.centres, seed=ROAD_SEED)
    except ValueError as e:
        raise SceneError("scene.objects", f"points object: {e}",
                         hint="check the reconstruction (its scale and the recorded camera)") from None
    _ROADS[key] = road
    while len(_ROADS) > _MAX_ROADS:
        _ROADS.popitem(last=False)
    return road


def car_box(context, asset, frame: int) -> tuple:
    """(rigid box_to_world (4, 4), size (3,) m, matrix_world (4, 4)) of the asset at scene ``frame`` (float64 from
    its stored transforms). SceneError when it has no box, is parented, or is not a Gaussian asset."""
    if not kinds.is_kind(asset, kinds.GAUSSIAN_ASSET):
        raise SceneError("context.active_object", "no Gaussian car asset is active",
                         hint="select a car (File > Import > SCPainter Gaussian Asset)")
    box = kinds.asset_box(asset)
    if box is None:
        raise SceneError(f"objects[{asset.name!r}]", "has no box: the drive stands its box on the road",
                         hint="Estimate Box (Car Assets)")
    if asset.parent is not None:  # its keys are its own transform: a parent would move it again
        raise SceneError(f"objects[{asset.name!r}]", f"is parented to {asset.parent.name!r}: a drive keys the car's "
                         "own world transform", hint="clear its parent (Alt+P, Clear and Keep Transformation)")
    scene = context.scene
    current = scene.frame_current
    try:
        scene.frame_set(int(frame))
        M = np.array(asset.matrix_world, np.float64)
        T, size = boxes.rigid_box(M @ asset_box.box_to_data(asset, box))
    finally:
        scene.frame_set(current)
    return T, size, M


def lane_where_it_stands(context, asset, start_frame: int) -> float:
    """Metres left of the drive the asset's box stands at ``start_frame`` (what *Drive Along Lane* offers)."""
    job, _ = drive_job(context)
    T, _, _ = car_box(context, asset, start_frame)
    return variants.reference_path(job).project(T[:2, 3])[1]


def drive_along_lane(context, asset, lane_m: float, speed_mps: float, start_frame: int) -> Drive:
    """Key ``asset`` driving along the recorded drive (module docstring); returns what it keyed. SceneError: no
    recorded camera or points, no box, a start frame after the scene's end, a car beyond the road's reach, a lane
    off the reconstruction."""
    scene = context.scene
    T0, size, M0 = car_box(context, asset, start_frame)  # first: an inactive car is said before a missing road
    job, job_path = drive_job(context)
    frames = [f.frame for f in job.frames if f.frame >= start_frame]
    if not frames:
        raise SceneError("start_frame", f"frame {start_frame} is after the scene's last frame {scene.frame_end}",
                         hint="start within the scene's frame range")
    road, path = road_of(job, job_path), variants.reference_path(job)
    reach = road.road_arc(path, lane_m=lane_m)   # where its lane runs on the road
    start, _ = path.project(T0[:2, 3])
    if reach is None:
        raise SceneError("lane_offset", f"{lane_m:g} m left of the drive never runs on the road found",
                         hint="choose a lane offset over the road")
    if not reach[0] <= start <= reach[1]:
        raise SceneError(f"objects[{asset.name!r}]", f"stands {start:.1f} m along the drive at frame {start_frame}, "
                         f"beyond the road its lane runs on (from {reach[0]:.1f} to {reach[1]:.1f} m)",
                         hint="move it over the road near the drive")
    fps = job.frame_rate()[0]
    t = (np.array(frames, np.float64) - start_frame) / fps
    arc, poses = car_placement.drive(road, path, size, lane_m, speed_mps, start, t, reach=reach)
    lost = [f for f, T in zip(frames, poses) if T is None]
    if lost:
        raise SceneError("lane_offset", f"no ground is known {lane_m:g} m left of the drive at frames "
                         f"{frame_ranges(lost)}: the lane runs off the reconstruction",
                         hint="choose a lane offset over the road")
    B = np.stack(poses)
    # held at the end it drives towards (np.clip gives the bound itself); standing still never stops
    at_end = np.flatnonzero(arc == (reach[1] if speed_mps > 0 else reach[0])) if speed_mps else []
    stopped = frames[at_end[0]] if len(at_end) else None
    off_road = {}
    for f, T in zip(frames, B):
        reason = road.check_footprint(car_placement.box_footprint(T, size))
        if reason:
            off_road.setdefault(reason, []).append(f)
    _key(asset, B @ np.linalg.inv(T0) @ M0, frames)
    return Drive(frames, B, size, arc, stopped, off_road)


def _key(asset, matrix_world, frames) -> None:
    """Key the asset's location and rotation (quaternions, continuous) at ``frames`` from world matrices (F, 4, 4)
    (its scale kept), replacing its earlier keys of those curves."""
    R = matrix_world[:, :3, :3] / np.linalg.norm(matrix_world[:, :3, :3], axis=1, keepdims=True)
    quat = cameras.continuous_quaternions(cameras.rotation_to_quaternion(R))
    fcurves = compat.object_fcurves(asset, f"{asset.name} drive")
    for fc in [fc for fc in fcurves if fc.data_path in KEYED]:
        fcurves.remove(fc)
    asset.rotation_mode = "QUATERNION"
    asset.location = matrix_world[0, :3, 3].tolist()
    asset.rotation_quaternion = quat[0].tolist()
    for i in range(3):
        compat.key_fcurve(fcurves, "location", i, frames, matrix_world[:, i, 3])
    for i in range(4):
        compat.key_fcurve(fcurves, "rotation_quaternion", i, frames, quat[:, i])


def frame_ranges(frames) -> str:
    """``"3–5, 9"``: sorted scene frames written as runs."""
    out, frames = [], sorted(frames)
    start = prev = frames[0]
    for f in frames[1:] + [None]:
        if f is not None and f == prev + 1:
            prev = f
            continue
        out.append(f"{start}" if start == prev else f"{start}–{prev}")
        start = prev = f
    return ", ".join(out)


def summary(asset, drive: Drive, lane_m: float, speed_mps: float) -> tuple:
    """(level, text) of the operator's report: frames keyed, distance, lane, speed; where it stopped and the
    frames it left the road (a warning)."""
    f = drive.frames
    text = (f"{asset.name}: keyed frames {f[0]}–{f[-1]} ({len(f)}), {drive.distance_m:.1f} m at {speed_mps:g} m/s"
            f"{' (oncoming)' if speed_mps < 0 else ''}, {lane_m:g} m left of the drive")
    warn = []
    if drive.stopped_at is not None:
        warn.append(f"held from frame {drive.stopped_at} where its lane leaves the road found along the drive")
    names = {"off_road": "its footprint leaves the road", "recorded_object": "it runs into something recorded"}
    for rule, frames in drive.off_road.items():
        warn.append(f"{names.get(rule, rule)} at frame{'s' * (len(frames) > 1)} {frame_ranges(frames)}")
    return ("WARNING" if warn else "INFO"), "; ".join([text, *warn])
