"""Render a job's condition layers frame by frame: I (R G B), hole (M), asset_mask (M_a), Z, instance
(``channels``).

The scene is loaded once: the reconstruction's points in world metres (float64, removal boxes applied), moved
to a scene origin at the first camera so the device works in float32 without losing millimetres; each asset's
Gaussians in its file coordinates, mapped per frame by its object_to_world. Per frame: the source frames' points
are z-buffered, the Gaussians composited front to back over the nearest point, and

    I = C_gaussians + (1 - M_a) · I_points,   M_a = 1 - transmittance,   hole = no point and M_a < 1/255,
    Z = depth where the asset opacity reaches 0.5 if nearer than the point, else the point's depth (+inf: empty),
    instance = the asset (1-based id, ``Scene.assets`` order) with the largest Σ α·T if that exceeds the
    transmittance left, else 0 (``gaussians.rasterize``); ``visible_pixels`` counts it per asset and
    ``amodal_pixels`` counts what each asset would cover alone.

Nothing is computed for what the job leaves out: no ``scene``, no points; no ``assets``, no Gaussian pass. Nor
for what a frame cannot see (``Scene.skip_unseen``): a source frame whose points' bounding box projects wholly
outside the image (or lies behind the near plane) is not projected, and when every asset's Gaussians provably
reach no pixel the Gaussian pass is skipped; both tests are conservative, so the layers are the same without them.

The scene's points are cleaned once, at load (``scene.point_cleaning``): pixels on depth edges are left out of
each source frame (``core.geometry.point_cloud.depth_edges``), then outliers of the whole cloud (``cleaning``).

(About 500 lines: what a worker keeps between jobs (``KeptCloud``'s placed points, ``PointLayers``' z-buffers) is
keyed on the ``Scene``'s placement and read only by ``render_frame``; a module of its own for the two caches is the
next split, once the Scene's fields they key on settle.)
"""

from __future__ import annotations

import collections
import dataclasses
import functools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import torch

from scpainter_blender.core.geometry import cameras, visibility
from scpainter_blender.core.splats import gaussians as splats, reader as splats_io
from scpainter_blender.core import job_inputs
from scpainter_blender.core import job as job_mod

from . import channels as ch
from . import cleaning
from . import gaussians as gs
from . import points as pts
from . import scene_cache
from . import tiles
from . import warmup

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence


@dataclass
class Asset:
    name: str
    means: torch.Tensor        # (N, 3) file coordinates, float64 (see make_asset)
    factors: torch.Tensor      # (N, 3, 3) R S in file axes
    opacities: torch.Tensor
    sh: torch.Tensor
    object_to_world: dict      # frame (int) -> (4, 4) ndarray, as job.Asset holds it
    bounds: np.ndarray | None = None   # (2, 3) low, high corner of the means, file coordinates (None: not known)
    max_sigma: float = float("inf")    # the largest σ (file units) of any of its Gaussians


@dataclass
class Scene:
    origin: np.ndarray
    device: torch.device
    xyz: torch.Tensor | None = None       # (P, 3) relative to origin, float32
    rgb: torch.Tensor | None = None
    frame: torch.Tensor | None = None     # (P,) source frame of each point
    frames_present: frozenset | None = None  # the frames that have points (None: not known)
    assets: list = field(default_factory=list)
    removed_points: int = 0
    # source frame -> (start, stop) of its points in xyz (each frame's points contiguous) and (2, 3) float64 low,
    # high corner of their box relative to origin; None: not known (then every source frame is projected)
    frame_slices: dict | None = None
    frame_boxes: dict | None = None
    skip_unseen: bool = True              # leave out source frames and assets the frame cannot see (same layers)
    cleaning: dict = field(default_factory=dict)  # what load_scene's point cleaning dropped, and its time
    # the z-buffers of these points already made (``PointLayers``, shared by the jobs placing one kept cloud) and
    # this placement's part of their key (origin, device); None: every frame projects its points
    point_layers: PointLayers | None = None
    placement: tuple = ()


def load_scene(job: job_mod.Job, job_path: str, device: str | torch.device, points: bool = True) -> Scene:
    """The job's points and assets on ``device``, once per job: the points as the import read them, cleaned by
    ``scene.point_cleaning`` (depth edges per source frame, then outliers of the cloud left after the removal
    boxes; ``Scene.cleaning`` says what each dropped and took), with each source frame's slice and box.
    ``points=False``: the assets only (what labels and the per-frame keys need; ``load_points`` adds the points
    later when a frame has to be rendered)."""
    scene = Scene(origin=cameras.camera_centers(job.frames[0].world_to_camera), device=torch.device(device))
    if points:
        load_points(scene, job, job_path)
    for a in job.assets:
        scene.assets.append(load_asset(job_mod.resolve(job_path, a.ply), a.name, a.object_to_world, scene.device))
    return scene


def load_asset(path: str, name: str, object_to_world: dict, device: str | torch.device) -> Asset:
    """``make_asset`` of the Gaussian file at ``path``, named ``name`` and placed by ``object_to_world``; a warm
    backend serves the file's Gaussians from memory when it loaded them before (``scene_cache``)."""
    made = scene_cache.asset(path, device, lambda: make_asset(name, splats_io.load(path), {}, device))
    return dataclasses.replace(made, name=name, object_to_world=object_to_world)


class PointLayers:
    """The points' z-buffers (image (H, W, 3), depth (H, W) float32) already made of one kept cloud, by what they
    are a function of: the placement (origin, device: the points' float32 coordinates), the source frames
    projected, K, the camera (relative to that origin), the size and the splat radius. A batch's variants share
    camera paths (the same lateral shifts, the same frames before a lane change), so a worker renders each
    distinct view of the points once and copies it after. The last used kept, the oldest dropped beyond
    ``ZBUFFER_BYTES`` in all."""

    def __init__(self):
        self._kept: collections.OrderedDict = collections.OrderedDict()
        self._bytes = 0

    @staticmethod
    def key(placement: tuple, frames: list, K: np.ndarray, w2c: np.ndarray, width: int, height: int,
            radius_px: int) -> tuple:
        """What a z-buffer of the cloud is a function of (``placement``: ``KeptCloud.placement``'s key): exact
        bytes, no rounding."""
        return (placement, tuple(frames), np.asarray(K, np.float64).tobytes(),
                np.asarray(w2c, np.float64).tobytes(), int(width), int(height), int(radius_px))

    def get(self, key: tuple) -> tuple | None:
        """Copies of the (image, depth) kept under ``key`` (the caller may write into them), or None."""
        hit = self._kept.get(key)
        if hit is None:
            return None
        self._kept.move_to_end(key)
        return hit[0].clone(), hit[1].clone()

    def put(self, key: tuple, image: torch.Tensor, depth: torch.Tensor) -> None:
        """Keep copies of ``image`` and ``depth`` under ``key``, dropping the oldest beyond ``ZBUFFER_BYTES``."""
        size = image.numel() * image.element_size() + depth.numel() * depth.element_size()
        if size > ZBUFFER_BYTES or key in self._kept:
            return
        self._kept[key] = (image.clone(), depth.clone())
        self._bytes += size
        while self._bytes > ZBUFFER_BYTES:
            _, (i, d) = self._kept.popitem(last=False)
            self._bytes -= i.numel() * i.element_size() + d.numel() * d.element_size()


#: The bytes of point z-buffers one kept cloud keeps (``PointLayers``): ~450 views at 128 x 72, 6 at 1024 x 576.
ZBUFFER_BYTES = 64 * 2 ** 20
#: The bytes of placed positions one kept cloud keeps (``KeptCloud.place``): 5 placements of 2 M points, about
#: the lateral shifts of a variant batch (each variant's origin is its first camera).
PLACED_BYTES = 128 * 2 ** 20


@dataclass(frozen=True)
class KeptCloud:
    """A scene's cleaned points in world metres, as ``scene_cache`` keeps them (only ever read): ``positions``
    (P, 3) float64, ``colors`` (P, 3), ``frame`` (P,) int64 source frame, in the cloud's order; ``frames_present``;
    ``slices`` {frame: (start, stop)} (None: a frame's points are not contiguous) and ``lows``, ``highs`` {frame:
    (3,) float64 world corners of its points}; ``removed_points`` and the cleaning's ``stats``. Whatever does not
    depend on a job's scene origin, made once per cloud: a batch's jobs on one recording (cameras moved, cars
    changed) place it with ``place`` alone."""
    positions: np.ndarray
    colors: np.ndarray
    frame: np.ndarray
    frames_present: frozenset
    slices: dict | None
    lows: dict
    highs: dict
    removed_points: int
    stats: dict
    # what the jobs placing this cloud share (``place``), only ever read: the z-buffers they made, the positions
    # placed at the last origins used ((origin, device) -> (P, 3) float32 tensor) and the colours and source frames
    # on each device (independent of the origin)
    views: PointLayers = field(default_factory=PointLayers, compare=False, repr=False)
    _placed: collections.OrderedDict = field(default_factory=collections.OrderedDict, compare=False, repr=False)
    _on_device: dict = field(default_factory=dict, compare=False, repr=False)

    @staticmethod
    def placement(origin: np.ndarray, device: torch.device) -> tuple:
        """The key of a placement: the origin's exact float64 bytes and the device."""
        return (np.asarray(origin, np.float64).tobytes(), str(device))

    def place(self, origin: np.ndarray, device: torch.device) -> tuple:
        """(xyz (P, 3) float32 relative to ``origin``, rgb, frame (P,)) tensors on ``device``: float32(positions -
        origin) made once per origin (the last ones within ``PLACED_BYTES`` kept), the colours and frames once
        per device. Shared by every job that places the cloud there: read only."""
        key = self.placement(origin, device)
        xyz = self._placed.get(key)
        if xyz is None:
            xyz = torch.as_tensor((self.positions - origin).astype(np.float32), device=device)
            size = xyz.numel() * xyz.element_size()
            if size <= PLACED_BYTES:
                self._placed[key] = xyz
                while sum(x.numel() * x.element_size() for x in self._placed.values()) > PLACED_BYTES:
                    self._placed.popitem(last=False)
        else:
            self._placed.move_to_end(key)
        if str(device) not in self._on_device:
            self._on_device[str(device)] = (torch.as_tensor(np.array(self.colors), device=device),
                                            torch.as_tensor(np.array(self.frame), device=device))
        return (xyz, *self._on_device[str(device)])

    @classmethod
    def of(cls, cloud, keep: np.ndarray, stats: dict) -> KeptCloud:
        """From ``cleaning.clean_cloud``'s (cloud, keep, stats)."""
        positions = np.asarray(cloud.positions[keep], np.float64)
        frame = np.asarray(cloud.frame[keep]).astype(np.int64)
        slices, lows, highs = None, {}, {}
        if not (len(frame) and np.any(np.diff(frame) < 0)):  # frame_index's rule: contiguous frames only
            values, starts = np.unique(frame, return_index=True)
            stops = np.append(starts[1:], len(frame))
            slices = {}
            for f, a, b in zip(values.tolist(), starts.tolist(), stops.tolist()):
                slices[f] = (a, b)
                lows[f], highs[f] = positions[a:b].min(0), positions[a:b].max(0)
        stats = dict(stats)
        removed = stats.pop("removed_points")
        return cls(positions, cloud.colors[keep], frame, frozenset(np.unique(frame).tolist()), slices, lows, highs,
                   removed, stats)

    def boxes(self, origin: np.ndarray) -> dict | None:
        """``frame_index``' boxes of the points placed at ``origin`` ((2, 3) float64 per frame), from the world
        corners: float32(p - origin) is monotone in p (each rounding is), so its per-frame min and max are those
        of the corners, bit for bit."""
        if self.slices is None:
            return None
        return {f: np.stack([(self.lows[f] - origin).astype(np.float32),
                             (self.highs[f] - origin).astype(np.float32)]).astype(np.float64) for f in self.slices}


def load_points(scene: Scene, job: job_mod.Job, job_path: str) -> Scene:
    """Load the job's cleaned points into ``scene`` (``load_scene``'s first half; nothing without a job scene)."""
    if job.scene is None:
        return scene
    sc, device, origin = job.scene, scene.device, scene.origin
    # as the import loaded it: the same reading of the poses, the same crop (NaN/inf pixels are dropped)
    def clean():
        pred = job_inputs.scene_predictions(job_path, sc)
        return KeptCloud.of(*cleaning.clean_cloud(pred, sc.confidence_percentile, sc.vggt_to_world,
                                                  sc.point_cleaning, sc.removal_boxes))

    # a warm backend, a batch's worker and a rig job keep the cleaned cloud (scene_cache): everything below copies
    # out of it, never into it
    kept = scene_cache.points(job_mod.resolve(job_path, sc.predictions), job.layers_dict()["scene"], clean)
    scene.removed_points = kept.removed_points
    scene.cleaning = dict(kept.stats)
    # the jobs of a worker that place the cloud at one origin share these tensors and the z-buffers made of them
    scene.xyz, scene.rgb, scene.frame = kept.place(origin, device)
    scene.frames_present = kept.frames_present
    scene.frame_slices = None if kept.slices is None else dict(kept.slices)
    scene.frame_boxes = kept.boxes(origin)
    scene.point_layers, scene.placement = kept.views, kept.placement(origin, device)
    return scene


def frame_index(frame: np.ndarray, xyz: np.ndarray) -> tuple[dict, dict] | tuple[None, None]:
    """Each source frame's (start, stop) in the points and its box (2, 3) float64 (low, high corner of ``xyz``, the
    float32 positions the renderer projects), or (None, None) when a frame's points are not contiguous."""
    frame = np.asarray(frame)
    if len(frame) and np.any(np.diff(frame) < 0):
        return None, None  # point_cloud writes frames in order; anything else is projected frame by frame
    values, starts = np.unique(frame, return_index=True)
    stops = np.append(starts[1:], len(frame))
    slices, boxes = {}, {}
    for f, a, b in zip(values.tolist(), starts.tolist(), stops.tolist()):
        slices[f] = (a, b)
        boxes[f] = np.stack([xyz[a:b].min(0), xyz[a:b].max(0)]).astype(np.float64)
    return slices, boxes


def make_asset(name: str, g: splats.Gaussians, object_to_world: dict, device: str | torch.device) -> Asset:
    """An asset's Gaussians on the device in float64, the projection's precision (so no frame casts them again),
    rows with zero or non-finite quaternions or scales dropped; with the box of its means and its largest σ, for
    ``asset_unseen``."""
    t = lambda x: torch.as_tensor(np.asarray(x, np.float64), device=device)  # noqa: E731
    factors, ok = gs.covariance_factors(t(g.quats), t(g.scales))
    means, factors = t(g.means)[ok], factors[ok]
    # in numpy, on the file's arrays (tiny torch reductions cost milliseconds of thread start-up each); the same
    # function gives Blender the bounds of the per-frame keys (core.frame_keys)
    bounds, max_sigma = visibility.asset_bounds(g.means, g.quats, g.scales)
    return Asset(name, means, factors, t(g.opacities)[ok], t(g.sh)[ok], object_to_world, bounds, max_sigma)


# -- what a frame cannot see (the tests: core.geometry.visibility, which the per-frame keys share) ---------------

GAUSSIAN_NEAR = visibility.GAUSSIAN_NEAR
POINTS_NEAR = visibility.POINTS_NEAR
points_unseen = visibility.points_unseen


def asset_unseen(asset: Asset, frame: int, origin: np.ndarray, K: np.ndarray, world_to_camera: np.ndarray, width: int,
                 height: int, near: float = GAUSSIAN_NEAR) -> bool:
    """True when none of the asset's Gaussians can reach a pixel of the camera at output frame ``frame``
    (``world_to_camera`` relative to ``origin``): ``visibility.asset_unseen`` (its docstring has the bound) with the
    asset's own bounds and largest σ. An asset built without bounds (None) is never skipped unless empty."""
    if asset.bounds is None:
        return not bool(len(asset.means))  # nothing finite to draw; unknown bounds: never skip
    return visibility.asset_unseen(asset.bounds, asset.max_sigma, asset.object_to_world[frame], origin, K,
                                   world_to_camera, width, height, near)


def visible_frames(scene: Scene, source_frames: Iterable[int], K: np.ndarray, w2c: np.ndarray, width: int, height: int,
                   radius_px: int) -> list:
    """The source frames (sorted, unique) whose points may land in the image; all of them when boxes are unknown."""
    frames = sorted(set(int(f) for f in source_frames))
    if not scene.skip_unseen or scene.frame_boxes is None:
        return frames
    frames = [f for f in frames if f in scene.frame_boxes]  # a frame without points has nothing to project
    if not frames:
        return frames
    unseen = points_unseen(np.stack([scene.frame_boxes[f] for f in frames]), K, w2c, width, height, radius_px)
    return [f for f, u in zip(frames, unseen) if not u]


def select_points(scene: Scene, frames: list) -> tuple[torch.Tensor, torch.Tensor]:
    """(xyz, rgb) of the points of ``frames``, in the scene's order (the z-buffer's ties go to the lower index,
    so the order is kept): the stored tensors when every frame with points is chosen (no copy), one view when
    the chosen frames' points are contiguous, else their slices concatenated (a copy of those points only);
    without ``frame_slices`` a selection over every point."""
    if scene.frames_present is not None and scene.frames_present <= set(frames):
        return scene.xyz, scene.rgb
    if scene.frame_slices is not None:
        ranges = sorted(scene.frame_slices[f] for f in frames if f in scene.frame_slices)
        merged = []
        for a, b in ranges:
            if merged and merged[-1][1] == a:
                merged[-1][1] = b
            else:
                merged.append([a, b])
        if len(merged) == 1:
            (a, b), = merged
            return scene.xyz[a:b], scene.rgb[a:b]
        return (torch.cat([scene.xyz[a:b] for a, b in merged]), torch.cat([scene.rgb[a:b] for a, b in merged]))
    sel = torch.isin(scene.frame, torch.as_tensor(list(frames), device=scene.device))
    return scene.xyz[sel], scene.rgb[sel]


def render_frame(scene: Scene, entry: job_mod.Frame, width: int, height: int, point_radius_px: int = 0,
                 reference: bool = False, to_numpy: bool = True, tile: int | None = None,
                 keep: dict | None = None) -> dict:
    """The condition layers of one output frame as float32 (H, W) arrays keyed by ``channels.CHANNELS`` (R G B
    hole asset_mask Z instance): numpy arrays, or tensors on the scene's device with ``to_numpy=False``.
    ``instance`` holds the asset id (1-based, the asset's place in ``scene.assets``, i.e. the job's ``assets``)
    that dominates the pixel (``gaussians.rasterize``' rule), 0 where the scene or nothing wins and wherever no
    Gaussian pass ran. ``reference``
    composites Gaussians with the torch pair rasterizer instead of the tile kernels (same result, slower; for tests
    and benchmarks); ``tile`` (pixels) is the tile kernels' tile size (None: the device's default). With
    ``scene.skip_unseen`` the source frames ``visible_frames`` rules out are not projected and the Gaussian pass
    is skipped when ``asset_unseen`` holds for every asset: the same layers, less work. ``keep``: a dict that
    receives the Gaussians' projection as ``keep["projection"]`` (None when the pass was skipped), for
    ``amodal_pixels``, and, where the CPU tile kernel composited the frame, ``keep["amodal"]``: ``amodal_pixels``'
    counts from the same walk (``tiles_cpu.rasterize_amodal``: exact, no second render); ``frame_amodal`` takes
    whichever the frame left."""
    dev = scene.device
    warmup.ensure(dev.type)  # the kernels compiled before the first frame, saying so (not cached yet) or loaded
    K = np.asarray(entry.K, np.float64)
    w2c = pts.relative_camera(np.asarray(entry.world_to_camera, np.float64), scene.origin)
    image = torch.zeros((height, width, 3), device=dev)
    depth = torch.full((height, width), float("inf"), device=dev)
    if scene.xyz is not None and entry.source_frames:
        frames = visible_frames(scene, entry.source_frames, K, w2c, width, height, point_radius_px)
        if frames:  # none: no point could land (the z-buffer of nothing is this image and depth)
            image, depth = _point_layers(scene, frames, K, w2c, width, height, point_radius_px)
    asset_mask = torch.zeros((height, width), device=dev)
    zmed = torch.full((height, width), float("inf"), device=dev)
    instance = torch.zeros((height, width), dtype=torch.int32, device=dev)
    if keep is not None:
        keep["projection"] = keep["amodal"] = None
    # no Gaussian pass when no asset can reach a pixel: its output would be no colour, M_a = 0, no depth
    if scene.assets and not (scene.skip_unseen and all(
            asset_unseen(a, entry.frame, scene.origin, K, w2c, width, height) for a in scene.assets)):
        proj = project_assets(scene, range(len(scene.assets)), entry.frame, K, w2c, width, height)
        if keep is not None:
            keep["projection"] = proj
        if keep is not None and not reference and dev.type == "cpu" and len(proj["depth"]):
            color_g, asset_mask, zmed, instance, keep["amodal"] = _rasterize_amodal(
                proj, width, height, depth, tile, len(scene.assets))
        else:
            rasterize = gs.rasterize if reference else functools.partial(tiles.rasterize, tile=tile)
            color_g, asset_mask, zmed, instance = rasterize(proj, width, height, background_depth=depth)
        image = color_g + (1.0 - asset_mask)[..., None] * image
    hole = torch.isinf(depth) & (asset_mask < gs.ALPHA_MIN)
    z = torch.where(zmed < depth, zmed, depth)
    img = image.clamp(0.0, 1.0)
    layers = dict(zip(ch.CHANNELS, (img[..., 0], img[..., 1], img[..., 2], hole, asset_mask, z, instance)))
    layers = {k: v.to(torch.float32) for k, v in layers.items()}
    return {k: v.cpu().numpy() for k, v in layers.items()} if to_numpy else layers


def _point_layers(scene: Scene, frames: list, K: np.ndarray, w2c: np.ndarray, width: int, height: int,
                  radius_px: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(image (H, W, 3), depth (H, W)) of the points of ``frames``: ``pts.render_points``', or a copy of the same
    z-buffer an earlier job of this worker made of the same placed cloud (``Scene.point_layers``)."""
    kept = scene.point_layers
    key = None if kept is None else PointLayers.key(scene.placement, frames, K, w2c, width, height, radius_px)
    hit = None if key is None else kept.get(key)
    if hit is not None:
        return hit
    xyz, rgb = select_points(scene, frames)
    image, depth, _ = pts.render_points(xyz, rgb, K, w2c, width, height, radius_px=radius_px)
    if key is not None:
        kept.put(key, image, depth)
    return image, depth


def _rasterize_amodal(proj: dict, width: int, height: int, depth: torch.Tensor, tile: int | None,
                      n_assets: int) -> tuple:
    """``tiles.rasterize`` on the CPU (its tile kernel, its default tile, its shapes and dtype) with the amodal
    counts of the same walk (``tiles_cpu.rasterize_amodal``), as (A,) int64 for the scene's A assets. The CUDA and
    reference paths keep ``amodal_pixels``' second render (their kernels do not count it)."""
    from . import raster_choice, tiles_cpu

    tile = raster_choice.choose("cpu", len(proj["depth"]), width, height, method="tiles", tile=tile).tile
    color, asset_mask, zmed, instance, amodal = tiles_cpu.rasterize_amodal(proj, width, height, depth, tile)
    counts = np.zeros(n_assets, np.int64)
    counts[:len(amodal)] = amodal
    dt = proj["mean2d"].dtype
    return (color.reshape(height, width, 3).to(dt), asset_mask.reshape(height, width).to(dt),
            zmed.reshape(height, width).to(dt), instance.reshape(height, width), counts)


def frame_amodal(scene: Scene, entry: job_mod.Frame, width: int, height: int, kept: dict) -> np.ndarray:
    """``amodal_pixels`` of a frame ``render_frame(keep=kept)`` rendered: the counts its kernel made on the way
    (``kept["amodal"]``, the CPU tile kernel), else ``amodal_pixels`` on its projection (a render per asset)."""
    if kept.get("amodal") is not None:
        return kept["amodal"]
    return amodal_pixels(scene, entry, width, height, projection=kept["projection"])


def project_assets(scene: Scene, which: Sequence[int], frame: int, K: np.ndarray, w2c: np.ndarray, width: int,
                   height: int) -> dict:
    """``gaussians.project_factors`` of the assets ``scene.assets[i]`` for i in ``which`` (in that order) at output
    frame ``frame`` (``w2c`` relative to the scene origin), their rows concatenated, with ``asset_id`` (G,) int64:
    i + 1, the 1-based id of the asset each projected Gaussian came from (the projection's ``index`` row tells)."""
    dev = scene.device
    means, factors, opac, sh, ids = [], [], [], [], []
    K_max = max(scene.assets[i].sh.shape[1] for i in which)
    for i in which:
        a = scene.assets[i]
        # a copy (np.array): the job's own float64 matrix must not be moved to the scene origin in place
        A = np.array(a.object_to_world[frame], np.float64)
        A[:3, 3] -= scene.origin  # relative to the scene origin, like the points
        # the projection runs in float64 on every device (a few hundred flops per Gaussian; it keeps thin
        # Gaussians' pixel coordinates exact, see tiles_cpu): assets are stored in float64
        At = torch.as_tensor(A, dtype=torch.float64, device=dev)
        means.append(a.means @ At[:3, :3].T + At[:3, 3])
        factors.append(At[:3, :3] @ a.factors)
        opac.append(a.opacities)
        sh.append(torch.nn.functional.pad(a.sh, (0, 0, 0, K_max - a.sh.shape[1])))
        ids.append(torch.full((len(a.means),), i + 1, dtype=torch.int64, device=dev))
    proj = gs.project_factors(torch.cat(means), torch.cat(factors), torch.cat(opac), torch.cat(sh), K, w2c,
                              width, height, near=GAUSSIAN_NEAR)
    proj["asset_id"] = torch.cat(ids)[proj["index"]]
    return proj


def visible_pixels(instance: np.ndarray | torch.Tensor, n_assets: int) -> np.ndarray:
    """(n_assets,) int64: the pixels of each asset (ids 1..n_assets) in an ``instance`` layer (render_frame's,
    numpy or tensor, float32 ids); 0 (no asset) is not counted."""
    ids = np.asarray(instance.cpu() if isinstance(instance, torch.Tensor) else instance).astype(np.int64).ravel()
    return np.bincount(ids, minlength=n_assets + 1)[1:n_assets + 1].astype(np.int64)


def amodal_pixels(scene: Scene, entry: job_mod.Frame, width: int, height: int,
                  projection: str = "project") -> np.ndarray:
    """(A,) int64, A = len(scene.assets): for each asset the pixels it would be the instance of if it were
    rendered alone (no points, no other asset: no background depth), i.e. where its own M_a > 0.5 (its Σ α·T
    exceeds the transmittance left). 0 for an asset ``asset_unseen`` rules out (no pass for it). One
    ``tiles.rasterize`` per asset the frame shows: a separate cost, not part of ``render_frame``. ``projection``:
    the frame's projection of every asset from ``render_frame(keep=...)`` (None: its Gaussian pass was skipped,
    nothing to count), whose rows of one asset are exactly that asset's own projection (each row is projected on
    its own, the order kept); by default each asset is projected here. An asset nothing hides (no point or other
    asset in front of it, nor behind it where it would count) has ``visible_pixels`` == ``amodal_pixels``.

    The work follows what the frame shows: with the frame's ``projection``, an asset none of whose Gaussians
    survived it (behind the camera, outside the image, too faint: the projection drops every Gaussian whose extent
    holds no pixel centre) is counted 0 after one count of its rows, with no ``asset_unseen`` test and no render:
    its alone projection is those same zero rows, and a render of no Gaussian covers no pixel, so the count is the
    0 the render would give. Only an asset with rows is tested (``asset_unseen``, as before) and rendered."""
    K = np.asarray(entry.K, np.float64)
    w2c = pts.relative_camera(np.asarray(entry.world_to_camera, np.float64), scene.origin)
    out = np.zeros(len(scene.assets), np.int64)
    if projection is None:
        return out
    shown = None
    if isinstance(projection, dict):  # the rows each asset kept (ids 1..A; bincount's row 0 is no asset)
        shown = torch.bincount(projection["asset_id"], minlength=len(scene.assets) + 1)[1:].cpu().numpy() > 0
    for i, a in enumerate(scene.assets):
        if shown is not None and not shown[i]:
            continue
        if asset_unseen(a, entry.frame, scene.origin, K, w2c, width, height):
            continue
        if shown is not None:
            sel = projection["asset_id"] == i + 1
            proj = {k: v[sel] for k, v in projection.items()}
        else:
            proj = project_assets(scene, [i], entry.frame, K, w2c, width, height)
        out[i] = int((tiles.rasterize(proj, width, height)[3] > 0).sum())
    return out
