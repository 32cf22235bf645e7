"""Render a job's condition layers frame by frame: I (R G B), hole (M), asset_mask (M_a), Z (``channels``).

The scene is loaded once: the reconstruction's points in world metres (float64, removal boxes applied), moved
to a scene origin at the first camera so the device works in float32 without losing millimetres; each asset's
Gaussians in its file coordinates, mapped per frame by its object_to_world. Per frame: the source frames' points
are z-buffered, the Gaussians composited front to back over the nearest point, and

    I = C_gaussians + (1 - M_a) · I_points,   M_a = 1 - transmittance,   hole = no point and M_a < 1/255,
    Z = depth where the asset opacity reaches 0.5 if nearer than the point, else the point's depth (+inf: empty).

Nothing is computed for what the job leaves out: no ``scene``, no points; no ``assets``, no Gaussian pass.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from scpainter_blender.core import cameras, geometry, outputs, point_cloud, splats, splats_io, vggt_io
from scpainter_blender.core import job as job_mod

from . import channels as ch
from . import gaussians as gs
from . import points as pts
from . import tiles


@dataclass
class Asset:
    name: str
    means: torch.Tensor        # (N, 3) file coordinates, float64 (see make_asset)
    factors: torch.Tensor      # (N, 3, 3) R S in file axes
    opacities: torch.Tensor
    sh: torch.Tensor
    object_to_world: dict      # frame (int) -> (4, 4) ndarray, as job.Asset holds it


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


def load_scene(job: job_mod.Job, job_path: str, device) -> Scene:
    device = torch.device(device)
    origin = cameras.camera_centers(job.frames[0].world_to_camera)
    scene = Scene(origin=origin, device=device)
    if job.scene is not None:
        sc = job.scene
        # as the import loaded it: the same reading of the poses, the same crop (NaN/inf pixels are dropped)
        pred = vggt_io.load_predictions(job_mod.resolve(job_path, sc.predictions), world_points=False,
                                        extrinsic_convention=sc.extrinsic_convention, crop=list(sc.crop))
        cloud = point_cloud.point_cloud(pred, sc.confidence_percentile, vggt_to_world=sc.vggt_to_world)
        keep = np.ones(len(cloud), bool)
        for box in sc.removal_boxes:
            keep &= ~geometry.points_in_box(cloud.positions, box.box_to_world, box.size)
        scene.removed_points = int((~keep).sum())
        scene.xyz = torch.as_tensor((cloud.positions[keep] - origin).astype(np.float32), device=device)
        scene.rgb = torch.as_tensor(cloud.colors[keep], device=device)
        scene.frame = torch.as_tensor(cloud.frame[keep].astype(np.int64), device=device)
        scene.frames_present = frozenset(np.unique(cloud.frame[keep]).tolist())
    for a in job.assets:
        scene.assets.append(make_asset(a.name, splats_io.load(job_mod.resolve(job_path, a.ply)), a.object_to_world,
                                       device))
    return scene


def make_asset(name: str, g: splats.Gaussians, object_to_world: dict, device) -> Asset:
    """An asset's Gaussians on the device in float64, the projection's precision (so no frame casts them again),
    rows with zero or non-finite quaternions or scales dropped."""
    t = lambda x: torch.as_tensor(np.asarray(x, np.float64), device=device)  # noqa: E731
    factors, ok = gs.covariance_factors(t(g.quats), t(g.scales))
    return Asset(name, t(g.means)[ok], factors[ok], t(g.opacities)[ok], t(g.sh)[ok], object_to_world)


def render_frame(scene: Scene, entry: job_mod.Frame, width: int, height: int, point_radius_px: int = 0,
                 reference: bool = False, to_numpy: bool = True, cutoff: float = gs.CUTOFF,
                 tile: int | None = None) -> dict:
    """The condition layers of one output frame as float32 (H, W) arrays keyed by ``channels.CHANNELS`` (R G B
    hole asset_mask Z): numpy arrays, or tensors on the scene's device with ``to_numpy=False``. ``reference``
    composites Gaussians with the torch pair rasterizer instead of the tile kernels (same result, slower; for tests
    and benchmarks); ``cutoff`` (σ) and ``tile`` (pixels) are the Gaussian cutoff and the tile kernels' tile size
    (None: the device's default)."""
    dev = scene.device
    K = np.asarray(entry.K, np.float64)
    w2c = pts.relative_camera(np.asarray(entry.world_to_camera, np.float64), scene.origin)
    image = torch.zeros((height, width, 3), device=dev)
    depth = torch.full((height, width), float("inf"), device=dev)
    if scene.xyz is not None and entry.source_frames:
        if scene.frames_present is not None and scene.frames_present <= set(entry.source_frames):
            xyz, rgb = scene.xyz, scene.rgb  # every frame: no selection pass, no copy
        else:
            sel = torch.isin(scene.frame, torch.as_tensor(list(entry.source_frames), device=dev))
            xyz, rgb = scene.xyz[sel], scene.rgb[sel]
        image, depth, _ = pts.render_points(xyz, rgb, K, w2c, width, height, radius_px=point_radius_px)
    asset_mask = torch.zeros((height, width), device=dev)
    zmed = torch.full((height, width), float("inf"), device=dev)
    if scene.assets:
        means, factors, opac, sh = [], [], [], []
        K_max = max(a.sh.shape[1] for a in scene.assets)
        for a in scene.assets:
            # a copy (np.array): the job's own float64 matrix must not be moved to the scene origin in place
            A = np.array(a.object_to_world[entry.frame], np.float64)
            A[:3, 3] -= scene.origin  # relative to the scene origin, like the points
            # the projection runs in float64 on every device (a few hundred flops per Gaussian; it keeps thin
            # Gaussians' pixel coordinates exact, see tiles.kernel_inputs): assets are stored in float64
            At = torch.as_tensor(A, dtype=torch.float64, device=dev)
            means.append(a.means @ At[:3, :3].T + At[:3, 3])
            factors.append(At[:3, :3] @ a.factors)
            opac.append(a.opacities)
            sh.append(torch.nn.functional.pad(a.sh, (0, 0, 0, K_max - a.sh.shape[1])))
        proj = gs.project_factors(torch.cat(means), torch.cat(factors), torch.cat(opac), torch.cat(sh), K, w2c,
                                  width, height, cutoff=cutoff)
        if reference:
            color_g, asset_mask, zmed = gs.rasterize(proj, width, height, background_depth=depth)
        else:
            color_g, asset_mask, zmed = tiles.rasterize(proj, width, height, background_depth=depth, tile=tile)
        image = color_g + (1.0 - asset_mask)[..., None] * image
    hole = torch.isinf(depth) & (asset_mask < gs.ALPHA_MIN)
    z = torch.where(zmed < depth, zmed, depth)
    img = image.clamp(0.0, 1.0)
    layers = dict(zip(ch.CHANNELS, (img[..., 0], img[..., 1], img[..., 2], hole, asset_mask, z)))
    layers = {k: v.to(torch.float32) for k, v in layers.items()}
    return {k: v.cpu().numpy() for k, v in layers.items()} if to_numpy else layers


def write_png(path, rgb) -> None:
    """8-bit RGB PNG (the condition image is display-referred already), stdlib only, written atomically."""
    import struct
    import zlib

    a = (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    H, W, _ = a.shape
    raw = np.concatenate([np.zeros((H, 1), np.uint8), a.reshape(H, W * 3)], axis=1).tobytes()

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    with outputs.atomic_write(path) as f:
        f.write(png)
