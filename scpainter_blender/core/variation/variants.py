"""Variants of one base job, written as job folders with a ``batch`` list and a manifest (docs/design.md §16).

Reads top to bottom: ``make_variants`` loads the base (its points, the road, the library), then for variant i,
with ``numpy.random.default_rng([seed, i])`` alone (so variant i is the same whatever the count):

1. the camera: the base path shifted left by a drawn shift, plus a lane change (a smoothstep shift) when drawn;
2. the cars: a count, then per car an asset, a scale and a hue, parked or moving, and up to ``tries`` placements,
   each checked against the rules of ``placement`` (the first that passes is kept);
3. the job: the base job with the new frames and the cars added (labelled: class and box; named ``car_names``,
   never a name of the base's own cars, which every variant keeps with their class and box), or, when a car found
   no place, no job and the reasons in the manifest.

Nothing is dropped silently: every variant is in the manifest with its outcome; the list names the placed ones.

The run's folder (``make_variants``): the base confined as ``render`` confines it (``check_base``), the folder
checked for a user's files (``check_out``) and locked, a running manifest first, each new variant folder renamed
into place whole, the finished manifest and then the list last (docs/design.md §16).

Why one module over 400 lines: the variants and the folder they are written to are one run (``make_variants``):
what a run may remove or overwrite is what its manifest (written here) says it placed, so the manifest's writer and
its reader stay together.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from .. import batch_items, errors, files, job as job_mod, job_inputs, locking, outputs
from ..geometry import boxes, cameras, point_cloud, similarity, trajectory
from ..output_layout import VariationLayout
from . import library as library_mod, placement
from .road import Road
from . import spec as spec_mod
from .spec import VariationError, VariationSpec

if TYPE_CHECKING:
    from collections.abc import Callable
    from .library import LibraryAsset



#: A road smaller than this (m²) is most likely a reconstruction not in metres: the run warns.
MIN_ROAD_M2 = 100.0


def scene_points(job: job_mod.Job, job_path: str | os.PathLike, predictions=None) -> np.ndarray:
    """World points (N, 3) of a job's reconstruction as the renderer loads them (same reading of the file,
    confidence, depth edges, ``vggt_to_world``), minus the points inside its removal boxes. The job's optional
    outlier removal (open3d, backend only) is not applied: the road's RANSAC planes and its per-cell point counts
    are robust to floaters. ``predictions``: the file already read (``job_inputs.scene_predictions``), else read."""
    sc = job.scene
    ratio = sc.point_cleaning.depth_edge_ratio if sc.point_cleaning is not None else None
    if predictions is None:
        predictions = job_inputs.scene_predictions(job_path, sc)
    cloud, keep = point_cloud.scene_cloud(predictions, sc.confidence_percentile, sc.vggt_to_world, ratio,
                                          sc.removal_boxes)
    return cloud.positions[keep]


def ground_track(world_to_camera: np.ndarray) -> tuple:
    """(centres (F, 3), unit horizontal directions of travel (F, 3)) of a camera path, world_to_camera (F, 4, 4):
    ``trajectory.heading_directions``, the cameras' forward axes where the path does not move."""
    centres = cameras.camera_centers(world_to_camera)
    return centres, trajectory.heading_directions(centres, fallback=world_to_camera[:, 2, :3])


def reference_path(job: job_mod.Job) -> placement.Path:
    """The base job's camera path on the ground: centres and directions of travel."""
    return placement.Path.of(*ground_track(np.stack([f.world_to_camera for f in job.frames])))


def recorded_path(job: job_mod.Job, predictions) -> placement.Path:
    """The recording's own camera path on the ground (``predictions.world_to_camera``, VGGT units, carried into the
    world by ``job.scene.vggt_to_world``): the same for every camera path and variant of a drive. A camera at
    X_c = R X_v + t sits at c_v = −Rᵀ t; in metres at M c_v, M = vggt_to_world = [sQ | m], turned by R Qᵀ
    (world-to-camera rotation, the scale taken out)."""
    s, Q, m = similarity.decompose_similarity(job.scene.vggt_to_world)
    E = cameras.orthonormalize(np.asarray(predictions.world_to_camera, np.float64).reshape(-1, 4, 4))
    R, t = E[:, :3, :3], E[:, :3, 3]
    centres_v = -np.einsum("sji,sj->si", R, t)
    w2c = np.tile(np.eye(4), (len(E), 1, 1))
    w2c[:, :3, :3] = R @ Q.T
    centres_w = s * centres_v @ Q.T + m
    w2c[:, :3, 3] = -np.einsum("sij,sj->si", w2c[:, :3, :3], centres_w)
    return placement.Path.of(*ground_track(w2c))


def _car(box_to_world: list, size, frames, moving: bool) -> placement.Car | None:
    """The ``placement.Car`` of a drive's poses (``placement.drive``: one for a parked car, kept at every frame;
    one per frame for a moving one); None where a pose found no ground."""
    if any(T is None for T in box_to_world):
        return None
    if not moving:
        T = box_to_world[0]
        return placement.Car(size, dict.fromkeys(frames, T), dict.fromkeys(frames, placement.box_footprint(T, size)),
                             False)
    return placement.Car(size, dict(zip(frames, box_to_world)),
                         {f: placement.box_footprint(T, size) for f, T in zip(frames, box_to_world)}, True)


#: A variant's cars are called CAR_NAME.format(n) for n = 1, 2, … (the names the base's own assets hold skipped).
CAR_NAME = "car_{:02d}"


def car_names(count: int, taken: list) -> list:
    """The names of a variant's ``count`` cars: ``CAR_NAME`` numbered from 1, skipping the ``taken`` names (the
    base job's assets, which every variant keeps: a job's asset names are unique, ``job.load``)."""
    taken, out, n = set(taken), [], 0
    while len(out) < count:
        n += 1
        if CAR_NAME.format(n) not in taken:
            out.append(CAR_NAME.format(n))
    return out


def smoothstep(x: np.ndarray | float) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class Variation:
    """One run: the base job and what every variant shares (its road, its library, the obstacles of the base)."""

    def __init__(self, base_path: str | os.PathLike, spec: VariationSpec, out: str | os.PathLike,
                 convert_mesh: Callable[[str, str, int], object] | None = None, mesh_count: int = 200_000,
                 skip_bad: bool = False, allow_outside: bool = False, data_roots=()) -> None:
        self.base_path = os.path.abspath(base_path)
        self.base = check_base(self.base_path, allow_outside, data_roots)
        # the camera path a variant shifts and checks: the job's camera, a rig job's first camera (its ego path
        # moves by that camera's shift, so every camera moves together: ``_job``)
        self.view = self.base.camera_jobs()[0][1]
        self.spec, self.layout = spec, VariationLayout(os.path.abspath(out))
        self.reading = lambda: job_inputs.reading(self.base_path, allow_outside, data_roots)  # noqa: E731
        t0 = time.perf_counter()
        self.path = reference_path(self.view)
        try:
            with self.reading():   # the base's files read where render would read them, checked as opened
                points = scene_points(self.base, self.base_path)
            self.road = Road(points, self.path.centres, seed=spec.seed)
        except ValueError as e:
            raise VariationError(self.base_path, "scene.predictions", str(e),
                                 hint="check the reconstruction (its scale and the recorded camera)") from None
        # cars are drawn where the drive's line (continued) runs on the road: the reconstruction's reach
        self.arc = self.road.road_arc(self.path)
        self.warnings = []
        if self.road.area_m2 < MIN_ROAD_M2:
            self.warnings.append(f"the road found is only {self.road.area_m2:.0f} m² (a street is hundreds): is the "
                                 "reconstruction in metres? (import it with a camera height, a metric trajectory "
                                 "or a scale factor)")
        t1 = time.perf_counter()
        self.library, self.skipped = [], []  # skipped: the library files --skip-bad left out, with why
        if spec.car_count[1] > 0:
            if not spec.library:
                raise VariationError("(variation spec)", "cars.library", "cars are asked for but no library is given",
                                     hint="set cars.library in the spec or pass --library DIR")
            self.library = library_mod.load_library(spec.library, self.layout.library, convert_mesh, mesh_count,
                                                    skipped=self.skipped if skip_bad else None)
            self.warnings += [library_mod.skipped_text(entry) for entry in self.skipped]
        self.fixed = self._base_obstacles(convert_mesh, mesh_count)
        self.timings = {"road_s": t1 - t0, "library_s": time.perf_counter() - t1}

    def _base_obstacles(self, convert_mesh, mesh_count) -> dict:
        """{frame: footprints (K, 4, 2)}: the base job's removal boxes, recorded objects and cars, per frame (stacked
        once: every variant checks against them)."""
        frames = [f.frame for f in self.base.frames]
        sc = self.base.scene
        fixed = {f: [placement.box_footprint(b.box_to_world, b.size) for b in sc.removal_boxes] for f in frames}
        for obj in sc.recorded_objects:
            for f in frames:
                if f in obj.boxes:
                    fixed[f].append(placement.box_footprint(obj.boxes[f], obj.size))
        for a in self.base.assets:
            box = a.box
            if box is None:  # estimated as labels estimate it
                with self.reading():
                    lib = library_mod.load_asset(job_mod.resolve(self.base_path, a.ply), self.layout.library,
                                                 convert_mesh, mesh_count, car=False)
                box = job_mod.AssetBox(lib.box_to_file, lib.size)
            for f in frames:
                T, size = boxes.place_box(box.box_to_file, box.size, a.object_to_world[f])
                fixed[f].append(placement.box_footprint(T, size))
        return {f: np.array(rects, np.float64).reshape(-1, 4, 2) for f, rects in fixed.items()}

    # -- one variant -------------------------------------------------------------------------------------------

    def camera(self, rng: np.random.Generator) -> tuple:
        """(world_to_camera (F, 4, 4), details): the base path shifted, with a lane change when drawn."""
        s = self.spec
        shift = float(rng.uniform(*s.shift_range_m)) if s.shift_range_m else float(rng.choice(s.shifts_m))
        F = len(self.base.frames)
        left = np.full(F, shift)
        details = {"shift_m": round(shift, 6), "lane_change": None}
        if rng.random() < s.lane_change_probability:
            by = float(rng.choice(s.lane_change_m))
            start = int(rng.integers(0, max(1, F - s.lane_change_frames) + 1))
            left += by * smoothstep((np.arange(F) - start) / s.lane_change_frames)
            details["lane_change"] = {"shift_m": by, "start_frame": self.base.frames[start].frame if start < F
                                      else self.base.frames[-1].frame, "frames": s.lane_change_frames}
        T = np.stack([f.world_to_camera for f in self.view.frames])
        return trajectory.shift_trajectory(T, left_m=left), details

    def check_camera(self, world_to_camera: np.ndarray) -> str | None:
        """None when the new path may be driven, else the rule it breaks (``placement.CAMERA_RULES``): the ego's
        footprint (``ego_size_m``, no margin) at some frame off the road where the ground was seen
        (``camera_off_road``: a kerb, a sidewalk, a shift past the road's edge; ground never seen, behind the first
        camera, counts as road) or on something standing there or a box of the base (``camera_blocked``: a
        recorded car, a removal box, a car of the base job)."""
        fixed = self.fixed
        for f, ego in self.ego_rects(world_to_camera, grow=0.0).items():
            reason = self.road.check_footprint(ego, unseen_ok=True)
            if reason == "recorded_object" or (reason is None and placement.overlaps_any(ego, fixed[f])):
                return "camera_blocked"
            if reason == "off_road":
                return "camera_off_road"
        return None

    def ego_rects(self, world_to_camera: np.ndarray, grow: float) -> dict:
        """{frame: (4, 2)}: the ego vehicle's footprint (``ego_size_m``) around each camera of a new path, grown by
        ``grow`` on every side."""
        centres, heads = ground_track(world_to_camera)
        w, length = self.spec.ego_size_m
        return {f.frame: placement.rectangle(centres[i, :2], heads[i, :2], length + 2 * grow, w + 2 * grow)
                for i, f in enumerate(self.base.frames)}

    def draw_car(self, rng: np.random.Generator, asset: LibraryAsset, rules: placement.Rules) -> tuple:
        """(placed ``placement.Car`` or None, details with the tries and the rejections by rule)."""
        s = self.spec
        scale = asset.scale * float(rng.uniform(1.0 - s.size_jitter, 1.0 + s.size_jitter))
        hue = int(round(float(rng.uniform(-s.hue_jitter_deg, s.hue_jitter_deg)))) if s.hue_jitter_deg else 0
        moving = bool(rng.random() < s.moving_probability)
        size = asset.size * scale
        fps = self.base.frame_rate()[0]
        frames = [f.frame for f in self.base.frames]
        t = (np.array(frames, np.float64) - frames[0]) / fps
        details = {"asset": asset.name, "mode": "moving" if moving else "parked", "scale": scale,
                   "size_m": [float(v) for v in size], "hue_deg": hue}
        rejections = dict.fromkeys(placement.RULES, 0)
        lo, hi = self.arc
        for attempt in range(1, s.tries + 1):
            if moving:
                lane = float(rng.choice(s.lane_offsets_m))
                speed = float(rng.uniform(*s.speed_mps))
                # its whole drive within the road's reach (where there is room for it)
                start = float(rng.uniform(lo, max(lo, hi - speed * t[-1])))
                drawn = {"lane_offset_m": lane, "speed_mps": speed}
            else:  # at the road's edge on a drawn side, a drawn gap from it: a drive at speed 0, at one time
                side = 1.0 if rng.random() < 0.5 else -1.0
                gap = float(rng.uniform(*s.kerb_gap_m))
                start = float(rng.uniform(lo, hi))
                xy0, head0 = self.path.at(np.array([start]))
                edge = self.road.edge_distance(xy0[0], side * np.array([-head0[0, 1], head0[0, 0]]),
                                               s.parked_offset_m[1])
                off = edge - 0.5 * size[0] - gap
                drawn = {"offset_m": side * off, "kerb_gap_m": gap}
                lane, speed = side * off, 0.0
            no_room = not moving and off < s.parked_offset_m[0]
            car = None
            if not no_room:  # its pose at every frame (moving), or once (parked)
                _, poses = placement.drive(self.road, self.path, size, lane, speed, start, t if moving else t[:1])
                car = _car(poses, size, frames, moving)
            reason = "off_road" if car is None else rules.check(car)
            if reason is None:
                T0 = car.box_to_world[frames[0]]
                yaw = np.degrees(np.arctan2(-T0[0, 1], T0[1, 1]))
                details.update(drawn, tries=attempt, rejections=rejections,
                               position_m=[float(v) for v in T0[:3, 3]], heading_deg=float(yaw))
                car.details = dict(details, scale=scale, hue_deg=hue)
                return car, details
            rejections[reason] += 1
        details.update(tries=s.tries, rejections=rejections)
        return None, details

    def variant(self, index: int) -> tuple:
        """(job or None, manifest entry) of variant ``index``."""
        s = self.spec
        rng = np.random.default_rng([s.seed, index])
        entry = {"id": VariationLayout.variant_name(index), "seed": [s.seed, index], "cars": []}
        rejections = dict.fromkeys(placement.CAMERA_RULES, 0)
        for attempt in range(1, s.tries + 1):  # a camera path on the road, clear of what the base holds
            w2c, cam = self.camera(rng)
            reason = self.check_camera(w2c)
            if reason is None:
                break
            rejections[reason] += 1
        entry["camera"] = dict(cam, tries=attempt, rejections=rejections)
        if reason is not None:
            entry.update(outcome="unplaced", job=None,
                         unplaced={"car": None, "what": "camera", "tries": s.tries, "rejections": rejections})
            return None, entry
        rules = placement.Rules(self.road, [f.frame for f in self.base.frames],
                                self.ego_rects(w2c, grow=s.ego_margin_m), self.fixed,
                                s.gap_m, headway_frames=round(s.headway_s * self.base.frame_rate()[0]))
        count = int(rng.integers(s.car_count[0], s.car_count[1] + 1))
        names = car_names(count, [a.name for a in self.base.assets])
        placed = []
        for j in range(count):
            asset = self.library[int(rng.integers(len(self.library)))]
            car, details = self.draw_car(rng, asset, rules)
            if car is None:
                entry.update(outcome="unplaced", job=None, unplaced=dict(details, car=j + 1, what="car"))
                return None, entry
            details["name"] = car.details["name"] = names[j]
            rules.placed.append(car)
            placed.append((asset, car))
            entry["cars"].append(details)
        entry["outcome"] = "placed"
        return self._job(index, w2c, placed), entry

    def _job(self, index, world_to_camera, placed) -> job_mod.Job:
        base, s = self.base, self.spec
        folder = self.layout.variant(index).root
        if base.rig is not None:
            frames, rig = self._rig_frames(world_to_camera)
        else:
            frames, rig = [], None
            scale = np.ones(3)
            if s.resolution is not None:
                scale = np.array([s.resolution[0] / base.width, s.resolution[1] / base.height, 1.0])
            for f, T in zip(base.frames, world_to_camera):
                frames.append(job_mod.Frame(f.frame, scale[:, None] * f.K, T, list(f.source_frames)))
        path = lambda p: self._path(folder, job_mod.resolve(self.base_path, p))  # noqa: E731
        assets = [replace(a, ply=path(a.ply)) for a in base.assets]
        for asset, car in placed:
            ply = asset.recoloured(car.details["hue_deg"], self.layout.library)
            S = np.diag([car.details["scale"]] * 3 + [1.0])
            to_box = np.linalg.inv(asset.box_to_file)
            o2w = {f: T @ S @ to_box for f, T in car.box_to_world.items()}
            assets.append(job_mod.Asset(car.details["name"], self._path(folder, ply), o2w, asset.category,
                                        job_mod.AssetBox(asset.box_to_file, asset.size)))
        scene = replace(base.scene, predictions=path(base.scene.predictions))
        generate = base.generate
        if generate is not None and generate.checkpoint:
            generate = replace(generate, checkpoint=path(generate.checkpoint))
        resolution = None if rig is not None else tuple(s.resolution or base.resolution)
        return replace(base, resolution=resolution, frames=frames, output_dir=".", scene=scene, assets=assets,
                       generate=generate, rig=rig)

    def _rig_frames(self, world_to_camera) -> tuple:
        """(frames, rig) of a rig job's variant whose first camera follows ``world_to_camera`` (the shifted path of
        ``camera``: a translation per frame, orientation kept): every frame's ``ego_to_world`` moved by that
        camera's shift, so all cameras move together; with the spec's ``resolution``, every camera scaled by its
        width over the first camera's."""
        base, s = self.base, self.spec
        shift = cameras.camera_centers(world_to_camera) - \
            cameras.camera_centers(np.stack([f.world_to_camera for f in self.view.frames]))
        frames = []
        for f, d in zip(base.frames, shift):
            E = np.array(f.ego_to_world, np.float64)
            E[:3, 3] += d
            frames.append(job_mod.Frame(f.frame, None, None, list(f.source_frames), E))
        rig = base.rig
        if s.resolution is not None:
            rig = rig.scaled(s.resolution[0] / rig.cameras[0].resolution[0])
        return frames, rig

    def _path(self, folder, absolute) -> str:
        """A path as a variant's job names it: relative inside the run's folder (it moves as one), else absolute."""
        absolute = os.path.abspath(absolute)
        if outputs.inside(absolute, self.layout.root):
            return os.path.relpath(absolute, folder)
        return absolute

    def data_roots(self) -> list:
        """The folders the variants' jobs lead into: the run's own folder, the reconstruction's, the library's
        and the base cars' (each once, outermost first)."""
        dirs = [self.layout.root, os.path.dirname(job_mod.resolve(self.base_path, self.base.scene.predictions))]
        dirs += [os.path.dirname(a.ply) for a in self.library]
        dirs += [os.path.dirname(job_mod.resolve(self.base_path, a.ply)) for a in self.base.assets]
        roots = []
        for d in sorted({os.path.realpath(d) for d in dirs}, key=len):
            if not any(outputs.inside(d, r) for r in roots):
                roots.append(d)
        return roots


def check_base(base_path: str | os.PathLike, allow_outside: bool = False, data_roots=()) -> job_mod.Job:
    """The base job, loaded, with a reconstruction, its paths confined as ``render`` confines them
    (``job_inputs.job_paths``: its folder and ``data_roots`` unless ``allow_outside``; a JobError naming the field
    otherwise), and each folder a variant's list would name as a ``data-root:`` line writable as one
    (``batch_items.list_line``): a variation never reads what a render of the base may not, and never makes its
    list trust more."""
    base_path = os.path.abspath(base_path)
    base = job_mod.load(base_path)
    if base.scene is None:
        raise VariationError(base_path, "scene", "the base job has no reconstruction: variations place "
                             "cars on its road", hint="export the job from a scene with imported points")
    paths = job_inputs.job_paths(base_path, base, allow_outside, checkpoint=True, data_roots=data_roots)
    for field, p in paths.items():
        if field != "output_dir":
            batch_items.list_line(os.path.dirname(p), base_path, field)
    return base


#: The top-level names a variation run writes in its folder besides its variant folders.
_OWN_NAMES = (VariationLayout.LIST, VariationLayout.MANIFEST, VariationLayout.LIBRARY)
_VARIANT_NAME = re.compile(r"v[0-9]+", re.ASCII)


def owned_names(layout: VariationLayout) -> set:
    """The top-level names of ``layout``'s folder that an earlier variation run wrote (its manifest's ``files``;
    a manifest without them, from an older run: its placed variants, list, manifest and library); none without a
    readable manifest. Only plain names (``_OWN_NAMES``, ``base``, ``vNNNN``) count: a manifest's field never
    makes a run touch anything else."""
    try:
        earlier = files.read_json(layout.manifest)
        if not isinstance(earlier, dict) or earlier.get("schema") != MANIFEST_SCHEMA:
            return set()
        names = earlier.get("files")
        if names is None:
            names = [e["id"] for e in earlier["variants"] if e.get("outcome") == "placed"] + list(_OWN_NAMES)
    except (errors.InputError, KeyError, TypeError, AttributeError):
        return set()
    if not isinstance(names, list):
        return {VariationLayout.MANIFEST}
    plain = {n for n in names if isinstance(n, str)
             and (n in _OWN_NAMES or n == VariationLayout.BASE or _VARIANT_NAME.fullmatch(n))}
    return {VariationLayout.MANIFEST} | plain


def check_out(out: str | os.PathLike, variants_count: int, writes=()) -> set:
    """What a variation run into ``out`` may write: nothing there yet, or what an earlier run wrote
    (``owned_names``). A file or folder of the user's (not in an earlier manifest) with a name the run would
    write (its list, manifest, ``library/``, a variant folder ``vNNNN`` of the ``variants_count``, or ``writes``)
    is an InputError naming it, before anything is written: never overwritten. Other files stay untouched.
    Returns the owned names."""
    layout = VariationLayout(os.path.abspath(out))
    if not os.path.lexists(layout.root):
        return set()
    if not os.path.isdir(layout.root):
        raise errors.InputError(layout.root, "--out", "exists and is not a folder")
    owned = owned_names(layout)
    present = set(os.listdir(layout.root))
    wanted = set(_OWN_NAMES) | set(writes) | {VariationLayout.variant_name(i) for i in range(variants_count)}
    theirs = sorted((present & wanted) - owned)
    if theirs:
        raise errors.InputError(os.path.join(layout.root, theirs[0]), "--out",
                                f"was not written by a variation run (no earlier {VariationLayout.MANIFEST} there "
                                f"names it{f'; nor {len(theirs) - 1} more' if len(theirs) > 1 else ''}): vary never "
                                "overwrites it", hint="give a new or empty folder, or move those files away")
    return owned


MANIFEST_SCHEMA = "scpainter.variation-manifest/1"


def make_variants(base_path: str | os.PathLike, spec: VariationSpec, out: str | os.PathLike,
                  convert_mesh: Callable[[str, str, int], object] | None = None,
                  progress: Callable[[int, int], None] | None = None, mesh_count: int = 200_000,
                  skip_bad: bool = False, allow_outside: bool = False, data_roots=(), busy=None,
                  own=()) -> dict:
    """Write ``spec.variants`` variants of the job at ``base_path`` into ``out`` (``VariationLayout``): a job folder
    per placed variant, the ``batch`` list and the manifest, which it returns. ``convert_mesh(mesh, out_ply,
    count)`` turns a library mesh into Gaussians (None: meshes refused). ``progress(done, total)`` after each.
    ``skip_bad`` (``vary --skip-bad``): library files that cannot be used are left out, each in the manifest's
    ``library_skipped`` (file, field, reason) and its ``warnings`` (``library.load_library``).
    ``allow_outside``, ``data_roots``: where the base's paths may lead (``check_base``, as ``render``). ``own``:
    top-level names the caller wrote into ``out`` for this run (Blender's ``base``, after its own ``check_out``),
    recorded as the run's. The folder is locked for the run (``locking.OutputLock``; ``busy(message, hint, file=,
    owner=)`` the error when another run holds it); a user's files are never overwritten (``check_out``); until
    the run ends the manifest says it is running and there is no list, so a killed run's folder is never taken as
    whole (its next run finishes or removes what it left). Errors: ``VariationError`` / the readers'
    ``InputError`` naming the file and field."""
    layout = VariationLayout(os.path.abspath(out))
    check_base(base_path, allow_outside, data_roots)  # refused before anything is made
    if spec.library:   # the library's folder becomes a data-root: line of the list
        batch_items.list_line(os.path.abspath(spec.library), "(variation spec)", "cars.library")
    check_out(layout.root, spec.variants)
    outputs.make_folder(layout.root, "--out", root=True)
    busy = busy or (lambda message, hint, **fields: VariationError(layout.root, "(folder)", message, hint))
    with locking.OutputLock(layout.root, "vary", busy=busy):
        owned = check_out(layout.root, spec.variants)   # again, now that no other run writes here
        return _make_variants(layout, owned, base_path, spec, convert_mesh, progress, mesh_count, skip_bad,
                              allow_outside, data_roots, own)


def _make_variants(layout, owned, base_path, spec, convert_mesh, progress, mesh_count, skip_bad, allow_outside,
                   data_roots, own) -> dict:
    """``make_variants``' run, its folder locked and checked (``owned``: ``check_out``'s names)."""
    pending = sorted(owned | set(own) | set(_OWN_NAMES)
                     | {VariationLayout.variant_name(i) for i in range(spec.variants)})
    # first: the manifest says a run is under way and names everything it may leave; the list goes (batch then
    # finds no list to take as whole until this run has written every variant)
    outputs.write_json(layout.manifest, {
        "schema": MANIFEST_SCHEMA, "state": "running", "base": os.path.abspath(base_path),
        "spec": spec_mod.to_file(spec), "library": [], "road_area_m2": None, "warnings": [], "removed": [],
        "summary": summarize([]), "variants": [],
        "files": pending, "timings": {}})
    with contextlib.suppress(FileNotFoundError):
        os.remove(layout.list)
    # what a killed run left half-made: temporary files of the list and manifest, temporary variant folders
    outputs.remove_temporaries(layout.root, pending, folders=True)
    if os.path.lexists(layout.library):
        outputs.own_folder(layout.root, VariationLayout.LIBRARY)   # never a link planted there
    v = Variation(base_path, spec, layout.root, convert_mesh, mesh_count, skip_bad, allow_outside, data_roots)
    entries, listed = [], []
    t0 = time.perf_counter()
    for i in range(spec.variants):
        job, entry = v.variant(i)
        if job is not None:
            _publish(layout, i, job)
            entry["job"] = os.path.relpath(layout.variant(i).job, layout.root)
            listed.append(entry["job"])
        entries.append(entry)
        if progress:
            progress(i + 1, spec.variants)
    seconds = time.perf_counter() - t0
    placed = {VariationLayout.variant_name(i) for i, e in enumerate(entries) if e["outcome"] == "placed"}
    # what an earlier (or killed) run wrote that this run does not place (fewer variants, or unplaced now): its
    # folders go, so no one collects one run's labels beside another's; only names a manifest of ours listed
    removed = sorted(n for n in set(pending) - placed if _VARIANT_NAME.fullmatch(n)
                     and os.path.isdir(os.path.join(layout.root, n)))
    for name in removed:
        outputs.remove_own_folder(layout.root, name)   # a link there is refused, never followed into
    summary = summarize(entries)
    warnings = v.warnings + ([f"no variant could be placed ({summary['variants']} tried)"]
                             if not summary["placed"] else [])
    names = sorted(placed | set(own) | {VariationLayout.LIST, VariationLayout.MANIFEST}
                   | ({VariationLayout.LIBRARY} if os.path.lexists(layout.library) else set()))
    manifest = {"schema": MANIFEST_SCHEMA, "state": "complete", "base": v.base_path, "spec": spec_mod.to_file(spec),
                "library": [{"name": a.name, "source": a.source, "ply": a.ply, "size_m": a.size_m.tolist(),
                             "category": a.category} for a in v.library],
                "library_skipped": v.skipped,
                "road_area_m2": v.road.area_m2, "warnings": warnings, "removed": removed,
                "summary": summary, "variants": entries, "files": names,
                "timings": dict(v.timings, placement_s=seconds,
                                variants_per_s=spec.variants / seconds if seconds > 0 else None)}
    outputs.write_json(layout.manifest, manifest)
    roots = [os.path.relpath(r, layout.root) if outputs.inside(r, layout.root) else r for r in v.data_roots()]
    # the list last: the run's own folder as "." (it can move as a whole)
    batch_items.write_job_list(layout.list, roots, listed,
                               comment=f"SCPainter variants: python -m backend batch --list {VariationLayout.LIST}")
    return manifest


def _publish(layout: VariationLayout, index: int, job: job_mod.Job) -> None:
    """Variant ``index``'s folder with its job: a new folder built under a temporary name and renamed whole; an
    existing one (an earlier run's: ``check_out``) opened without following a link, the job file's temporaries a
    killed run left removed, its job rewritten only when it changed (``_save_if_changed``)."""
    name = VariationLayout.variant_name(index)
    folder = os.path.join(layout.root, name)
    if not os.path.lexists(folder):
        with outputs.atomic_folder(folder, usual_mode=True) as tmp:
            job_mod.save(os.path.join(tmp, os.path.basename(layout.variant(index).job)), job)
        return
    outputs.own_folder(layout.root, name)
    # what a killed run left half-written there: the temporaries of the job file (only its name)
    outputs.remove_temporaries(folder, [os.path.basename(layout.variant(index).job)])
    _save_if_changed(layout.variant(index).job, job)


def _save_if_changed(path, job) -> None:
    """Write ``job`` unless the file already holds exactly it (its time is then kept: a render made from it
    stays newer than it, which ``contact-sheet`` checks)."""
    content = job_mod.validate(job.to_dict(), path).to_dict()   # what save would write
    try:
        with open(path, encoding="utf-8") as f:
            if json.loads(f.read()) == content:
                return
    except (OSError, ValueError):
        pass
    job_mod.save(path, job)


def summarize(entries: list) -> dict:
    """Counts over the variants: placed / unplaced; over the placed ones (what the jobs hold) cars per asset and
    mode, variants per shift, lane changes; and rejections per rule over every try, placed or not (what the
    placement spent its tries on)."""
    def count(d, key):
        d[key] = d.get(key, 0) + 1

    out = {"variants": len(entries), "placed": 0, "unplaced": 0, "cars": 0, "per_asset": {}, "per_mode": {},
           "per_shift": {}, "lane_changes": 0,
           "rejections": dict.fromkeys(placement.CAMERA_RULES + placement.RULES, 0)}
    for e in entries:
        count(out, e["outcome"])
        for rule, n in e["camera"]["rejections"].items():
            out["rejections"][rule] += n
        for car in e["cars"] + ([e["unplaced"]] if e["outcome"] == "unplaced" and e["unplaced"]["car"] else []):
            for rule, n in car["rejections"].items():
                out["rejections"][rule] += n
        if e["outcome"] != "placed":
            continue
        count(out["per_shift"], f"{e['camera']['shift_m']:g}")
        out["lane_changes"] += e["camera"]["lane_change"] is not None
        for car in e["cars"]:
            out["cars"] += 1
            count(out["per_asset"], car["asset"])
            count(out["per_mode"], car["mode"])
    return out


#: The warning events' ``code``s (both CLIs): a variant that could not be placed, a run's own warning.
UNPLACED = "variant_unplaced"
VARIATION_WARNING = "variation"


def warnings(manifest: dict) -> list:
    """The warning events' fields of a finished run (``code``, ``message``, more): one per unplaced variant (its
    rejections per rule), one per warning of the run (a small road, nothing placed)."""
    out = [{"code": UNPLACED, "message": unplaced_text(e), "rejections": e["unplaced"]["rejections"]}
           for e in manifest["variants"] if e["outcome"] != "placed"]
    return out + [{"code": VARIATION_WARNING, "message": w} for w in manifest["warnings"]]


def done_fields(manifest: dict, out: str | os.PathLike) -> dict:
    """What ``vary``'s done event carries (both CLIs): the folder, the base, the list, the manifest, the summary,
    what an earlier run left that was removed, the timings."""
    layout = VariationLayout(os.path.abspath(out))
    return {"output_dir": layout.root, "base": manifest["base"], "list": layout.list, "manifest": layout.manifest,
            "summary": manifest["summary"], "removed": manifest["removed"], "timings": manifest["timings"]}


def unplaced_text(entry: dict) -> str:
    """One sentence for a manifest entry whose outcome is ``unplaced``: what found no place (the camera path, or
    car N: its asset and mode), in how many tries, and the rules that refused it most."""
    u = entry["unplaced"]
    worst = ", ".join(f"{rule} {n}" for rule, n in sorted(u["rejections"].items(), key=lambda kv: -kv[1]) if n)
    what = "the camera path" if u["what"] == "camera" else f"car {u['car']} ({u['asset']}, {u['mode']})"
    return f"{entry['id']} could not be placed: {what} found no place in {u['tries']} tries ({worst})"
