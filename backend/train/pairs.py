"""Training pairs (paper §3.4, docs/design.md §5): condition layers rendered from a clip, with the real frames as
targets.

A sample is ``frames`` consecutive target frames t0 .. t0+F−1 of one clip. For each target frame t:

* **Novel-view pair**: the points of a random subset of the frames within ±``source_window`` of t, never t itself (each
  neighbour kept with probability ``source_prob``; at least one), are projected into frame t's camera. Points
  from other frames land where frame t's own pixels would have been, with the holes and misalignments a novel
  view has, while the target stays the real frame t.
* **Asset pair** (probability ``asset_prob``, clips with a tracked car that has an asset): that car's points are
  removed from every source frame inside its box grown by ``grow_ratio`` and ``grow_m``, and its Gaussian asset
  is composited at its box in frame t. The rendered asset mask M_a at this observed viewpoint comes out with I.

Rendering is the inference renderer's (``backend.render.frames.render_frame``) at the training resolution, with the
clip's intrinsics scaled to it, and the clip's points are cleaned as a job's scene is (``PairSettings.point_cleaning``,
a ``core.job.PointCleaning`` with the job's defaults): pixels on depth edges left out of each source frame, then,
when set, outliers of the whole cloud; so the condition layers the model learns from have the artefacts (and the
holes) of those it gets at inference. Layers, as ``generate`` loads them: I (3, H, W) and M_a, validity = 1 − hole
(1, H, W), float32 in [0, 1]. All randomness comes from the generator the caller passes, so a sample index and a
seed determine the sample (exact resume, identical across DataLoader workers).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
import torch

from scpainter_blender.core.geometry import cameras
from scpainter_blender.core import errors, files
from scpainter_blender.core.splats import reader as splats_io
from scpainter_blender.core import job as job_mod

from ..render import cleaning
from ..render import frames as fr
from . import clip as clip_mod
from .view_settings import ViewSettings

if TYPE_CHECKING:
    from collections.abc import Sequence
    from scpainter_blender.core.vggt.predictions import VGGTPredictions


@dataclass(frozen=True)
class PairSettings(ViewSettings):
    """The view (``ViewSettings``: resolution, frames, source window, removal-box growth, confidence), and how a
    sample is drawn and rendered. A pair's sources are a random subset of the window, frame t itself excluded."""

    source_prob: float = 0.5       # each neighbour's chance of contributing points
    asset_prob: float = 0.5        # chance that a sample is an asset pair (when the clip has assets)
    point_radius: int = 0
    # the job's scene.point_cleaning, with its defaults (job.POINT_CLEANING); None: no cleaning
    point_cleaning: job_mod.PointCleaning | None = field(default_factory=job_mod.PointCleaning)


def load_resized(path: str, width: int, height: int) -> torch.Tensor:
    """(3, height, width) uint8: an image file as RGB, resized with Lanczos (antialiased) when its size differs."""
    from PIL import Image

    try:
        with files.open_regular(path) as f, Image.open(f) as im:  # a FIFO swapped in after loading cannot block
            im = im.convert("RGB")
            if im.size != (width, height):
                im = im.resize((width, height), Image.LANCZOS)
            return torch.from_numpy(np.asarray(im).copy()).permute(2, 0, 1)
    except (OSError, Image.DecompressionBombError, SyntaxError) as e:
        raise errors.InputError(path, "(file)", f"cannot read the image ({e})") from None


def load_clip_frames(clip: clip_mod.Clip, width: int, height: int, indices: Sequence[int] | None = None,
                     view: float | None = None) -> torch.Tensor:
    """(N, 3, height, width) uint8: a clip's frames ``indices`` (default all), or those of its ground-truth view
    ``view`` (a lateral shift), as training and evaluation use them: ``Clip.load_frames`` (undistorted to
    ``clip.K`` when the clip gives its lens distortion, a video decoded once, resized with Lanczos)."""
    return torch.from_numpy(clip.load_frames(width, height, indices, view)).permute(0, 3, 1, 2)


def load_clip_frame(clip: clip_mod.Clip, t: int, width: int, height: int, view: float | None = None) -> torch.Tensor:
    """(3, height, width) uint8: frame t of a clip (or of its view ``view``), as ``load_clip_frames``."""
    return load_clip_frames(clip, width, height, [t], view)[0]


def clean_cloud(pred: VGGTPredictions, confidence_percentile: float, vggt_to_world: np.ndarray,
                point_cleaning: job_mod.PointCleaning | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """The clip's points as ``frames.load_scene`` makes a scene's, cleaned by ``point_cleaning`` (a
    ``job.PointCleaning``; None: not cleaned): ``point_cloud`` with the depth-edge test per source frame, then
    ``cleaning.outlier_keep`` on the whole cloud. Returns (positions (N, 3) float64 output world, colors (N, 3)
    float32 sRGB, offsets (S + 1,) int64: source frame i's points are [offsets[i], offsets[i + 1]), stats dict).

    The same function as load_scene (``cleaning.clean_cloud``). One difference: a job's removal boxes are applied
    before its outlier removal, while an asset pair removes its car's points per sample, after it (open3d once per
    sample would cost seconds), so with ``outliers`` set the car's points take part in judging their neighbours."""
    cloud, keep, stats = cleaning.clean_cloud(pred, confidence_percentile, vggt_to_world, point_cleaning)
    stats = {k: stats[k] for k in ("depth_edge_points", "outlier_points")}
    if keep.all():  # no outlier removal, or nothing removed: no copies
        return cloud.positions, cloud.colors, cloud.offsets, stats
    # point_cloud writes the frames in order, so the kept points stay grouped by frame; count them again
    counts = np.bincount(cloud.frame[keep], minlength=pred.num_frames)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return cloud.positions[keep], cloud.colors[keep], offsets, stats


class PairMaker:
    """Renders training samples of one clip. Holds the clip's point cloud (cleaned by ``settings.point_cleaning``,
    relative to the first camera, float32, grouped by source frame), its assets, and the targets resized to the
    training resolution. ``cleaning`` says how many points each filter dropped."""

    def __init__(self, clip: clip_mod.Clip, settings: PairSettings, device: str | torch.device = "cpu") -> None:
        s = self.settings = settings
        if clip.num_frames < s.frames:
            raise clip_mod.ClipError(clip.path, "predictions",
                                     f"the clip has {clip.num_frames} frames, fewer than the {s.frames} of a sample")
        self.clip, self.device = clip, torch.device(device)
        positions, colors, self.offsets, self.cleaning = clean_cloud(clip.predictions, s.confidence_percentile,
                                                                     clip.vggt_to_world, s.point_cleaning)
        self.origin = cameras.camera_centers(clip.world_to_camera[0])
        self.xyz = torch.as_tensor((positions - self.origin).astype(np.float32), device=self.device)
        self.rgb = torch.as_tensor(colors, device=self.device)
        self.K = clip.K_for(s.width, s.height)
        self.assets = {}
        for i, car in enumerate(clip.cars):
            if car.asset is None:
                continue
            g = splats_io.load(car.asset)
            self.assets[i] = (fr.make_asset(car.id, g, {}, self.device), clip_mod.asset_to_box(car, g.means))
        self._targets = {}

    def target(self, t: int) -> torch.Tensor:
        """(3, H, W) float32 in [0, 1]: real frame t as ``Clip.load_frames`` gives it (undistorted to the clip's K
        when it has lens distortion, resized with Lanczos), cached as uint8. A video clip is decoded once, whole."""
        if t not in self._targets:
            s = self.settings
            if self.clip.video is not None:  # seeking costs a decode from the last key frame: take them all now
                self._targets.update(enumerate(load_clip_frames(self.clip, s.width, s.height)))
            else:
                self._targets[t] = load_clip_frame(self.clip, t, s.width, s.height)
        return self._targets[t].float() / 255.0

    def sources(self, t: int, rng: np.random.Generator) -> list:
        s, S = self.settings, self.clip.num_frames
        near = [f for f in range(max(0, t - s.source_window), min(S, t + s.source_window + 1)) if f != t]
        keep = [f for f in near if rng.random() < s.source_prob]
        return keep or [near[int(rng.integers(len(near)))]]

    def _points(self, sources: list, car: clip_mod.Car | None):
        """Points of the source frames, minus the car's points inside its grown box at each source frame."""
        xyz, rgb = [], []
        for f in sources:
            sl = slice(int(self.offsets[f]), int(self.offsets[f + 1]))
            p, c = self.xyz[sl], self.rgb[sl]
            if car is not None and f in car.boxes:
                T, size = clip_mod.grown_box(car.boxes[f], car.size, self.settings.grow_m, self.settings.grow_ratio)
                R = torch.as_tensor(T[:3, :3], dtype=torch.float32, device=self.device)
                c0 = torch.as_tensor(T[:3, 3] - self.origin, dtype=torch.float32, device=self.device)
                local = (p - c0) @ R
                inside = (local.abs() <= torch.as_tensor(size / 2, dtype=torch.float32, device=self.device)).all(1)
                p, c = p[~inside], c[~inside]
            xyz.append(p)
            rgb.append(c)
        return torch.cat(xyz), torch.cat(rgb)

    def sample(self, rng: np.random.Generator, t0: int | None = None, asset: bool | None = None,
               car: int | None = None) -> dict:
        """One training sample: target, image (F, 3, H, W); asset_mask (M_a), valid (F, 1, H, W); and what was drawn.
        ``t0``, ``asset`` (asset pair or not) and ``car`` (its index) override the draws, for tests and samples."""
        s, S = self.settings, self.clip.num_frames
        t0 = int(rng.integers(0, S - s.frames + 1)) if t0 is None else t0
        targets = range(t0, t0 + s.frames)
        with_asset = [i for i in self.assets if any(t in self.clip.cars[i].boxes for t in targets)]
        want = (rng.random() < s.asset_prob) if asset is None else asset
        car_i = with_asset[int(rng.integers(len(with_asset)))] if (want and with_asset) else None
        if car is not None:
            car_i = car
        car = None if car_i is None else self.clip.cars[car_i]
        out = {k: [] for k in ("target", "image", "asset_mask", "valid")}
        drawn = []
        for t in targets:
            src = self.sources(t, rng)
            drawn.append(src)
            xyz, rgb = self._points(src, car)
            scene = fr.Scene(origin=self.origin, device=self.device, xyz=xyz, rgb=rgb, frames_present=frozenset(src))
            if car is not None and t in car.boxes:
                a, a2b = self.assets[car_i]
                scene.assets = [replace(a, object_to_world={t: car.boxes[t] @ a2b})]
            entry = job_mod.Frame(t, self.K[t], self.clip.world_to_camera[t], list(src))
            layers = fr.render_frame(scene, entry, s.width, s.height, s.point_radius, to_numpy=False)
            out["target"].append(self.target(t))
            out["image"].append(torch.stack([layers["R"], layers["G"], layers["B"]]).cpu())
            out["asset_mask"].append(layers["asset_mask"][None].cpu())
            out["valid"].append(1.0 - layers["hole"][None].cpu())
        sample = {k: torch.stack(v) for k, v in out.items()}
        sample.update(t0=t0, car=-1 if car_i is None else car_i, sources=drawn)
        return sample


class PairDataset(torch.utils.data.Dataset):
    """Sample ``i`` of a training run: clip, start frame and sources drawn from ``np.random.default_rng([seed, i])``
    — the same sample in any worker, on any rank, after any resume. Clips are opened lazily per worker, the most
    recent ``cache`` of them kept (a clip's point cloud is tens of MB)."""

    def __init__(self, clip_paths: list, settings: PairSettings, seed: int = 0, cache: int = 4,
                 length: int = 2**62) -> None:
        if not clip_paths:
            raise ValueError("no training clips given")
        self.clip_paths, self.settings, self.seed, self.cache, self.length = list(clip_paths), settings, seed, cache, length
        self._makers: OrderedDict = OrderedDict()

    def __len__(self):
        return self.length

    def maker(self, k: int) -> PairMaker:
        if k not in self._makers:
            self._makers[k] = PairMaker(clip_mod.load(self.clip_paths[k]), self.settings)
            while len(self._makers) > self.cache:
                self._makers.popitem(last=False)
        self._makers.move_to_end(k)
        return self._makers[k]

    def __getitem__(self, i: int) -> dict:
        rng = np.random.default_rng([self.seed, int(i)])
        k = int(rng.integers(len(self.clip_paths)))
        try:
            sample = self.maker(k).sample(rng)
        except ValueError as e:  # a plain ValueError crosses the DataLoader's process boundary with its message
            raise ValueError(f"training sample {i}: {e}") from None
        return {"target": sample["target"], "image": sample["image"], "asset_mask": sample["asset_mask"],
                "valid": sample["valid"], "clip": k, "t0": sample["t0"], "car": sample["car"], "index": int(i)}

