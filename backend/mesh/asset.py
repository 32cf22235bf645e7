"""Car meshes as Gaussian assets, the ``python -m backend mesh-asset`` command: sample the surface of a mesh, one
flat Gaussian per sample, written as an INRIA-layout PLY with what the command reports.

Where the rest lives (no bpy; trimesh):

* ``backend.mesh.load``: reading the file into Z-up parts (formats, axes, glTF/OBJ scenes), ``MeshAssetError``;
* ``backend.mesh.colors``: the samples' colours (textures, vertex/face colours, materials);
* ``backend.mesh.box``: the upright oriented box (stage-1 size) and the 3D box the command reports;
* ``backend.mesh.silhouette``: the rendered asset mask against the mesh's silhouette (how "Choice of c" below
  was measured).

Gaussians
---------
Samples are area-weighted and uniform on each triangle (``trimesh.sample.sample_surface`` with explicit face
weights: zero for triangles with zero or non-finite area, so degenerate faces and NaN vertices never produce a
Gaussian). Each sample gets one flat Gaussian:

* rotation R = [t1, t2, n] (columns): local z = the face normal n = normalise((v1 - v0) x (v2 - v0)) (the winding's
  normal, as trimesh's ``face_normals``), t1 = normalise(v1 - v0), t2 = n x t1;
* in-plane standard deviation σ = c · sqrt(A / N) (A the total area, N the count; ``SIGMA_FACTOR`` = c), along the
  normal ``NORMAL_RATIO`` · σ (flat, but > 0 so Σ stays invertible);
* opacity ``OPACITY``; colour as the SH degree-0 term f_dc = (rgb - 0.5) / C0, rgb sRGB-encoded in [0, 1] (the
  values 3DGS renders and the condition images hold).

Choice of c (``bench/mesh_assets.py``, bench/results/mesh_assets.json). With N/A samples per unit area, the summed
weight Σ o exp(-r²/2σ²) of the Gaussians at a point of the surface is 2π c² o on average, so one layer lets through
about a transmittance of exp(-2π c² o) and a closed surface (two layers on every line of sight) exp(-4π c² o); past
a free edge the mask falls to 0.5 at the distance d where Φ(-d/σ) = ln 2 / (2π c² o). c ≈ 0.5 puts that edge on the
outline but leaves the car a few per cent transparent; c = 1 closes it and moves the edge out by 1.2 σ. Measured on
close-ups (the car 80 % of a 1024 x 576 frame's height) of the procedural car and two real TRELLIS GLBs: c = 0.5 has
the least mean |M_a - silhouette| but shows the background through the car (leak 1.5 % at 20 k Gaussians, speckles
to the eye); c = 0.6 keeps the leak at or under 0.5 % for 20 k and 0.1 % for 200 k at a mask error 0.001-0.014
higher; c >= 0.7 only widens the outline. ``DEFAULT_COUNT`` = 200 k is where those close-ups stop improving (σ ≈
0.6-0.9 px, the size of the renderer's own 0.3 px² blur: beyond it more Gaussians only pile blur past the outline).

No bpy, no torch.
"""

from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass, field

import numpy as np

from scpainter_blender.core.geometry import cameras
from scpainter_blender.core import errors, outputs, shapes
from scpainter_blender.core.splats import gaussians as splats, inria as splats_inria
from scpainter_blender.core.splats.sh import SH_C0

from .box import oriented_box_3d, upright_box
from .colors import DEFAULT_WRAP, part_colours
from .load import MeshAsset, MeshAssetError, as_parts, face_areas, load_mesh

try:
    import fcntl
except ImportError:  # no flock (Windows): killed runs' temporaries are then left in place
    fcntl = None

SIGMA_FACTOR = 0.6       # c in σ = c sqrt(A / N); see "Choice of c" above
NORMAL_RATIO = 1e-3      # σ along the normal / σ in the plane
OPACITY = 0.99
DEFAULT_COUNT = 200_000
MAX_COUNT = 10_000_000
#: ``warning`` code: samples left out for a non-finite position, rotation or colour (the rest is written).
DROPPED_SAMPLES = "mesh_samples_dropped"


@dataclass
class MeshGaussians:
    """``mesh_to_gaussians``' result with what the command reports: total ``area`` (units²), ``sigma`` (in-plane σ,
    units), ``colour_source`` (the source of most samples) and ``colour_counts`` (samples per source),
    ``dropped`` (samples left out for non-finite values: normally none)."""

    gaussians: splats.Gaussians
    area: float
    sigma: float
    colour_source: str
    colour_counts: dict = field(default_factory=dict)
    dropped: int = 0


# --------------------------------------------------------------------------------------------------------------
# Gaussians
# --------------------------------------------------------------------------------------------------------------

def sample_gaussians(mesh, count: int, seed: int = 0, sigma_factor: float = SIGMA_FACTOR,
                     opacity: float = OPACITY, normal_ratio: float = NORMAL_RATIO) -> MeshGaussians:
    """``count`` flat surface Gaussians of ``mesh`` (a MeshAsset, a trimesh.Trimesh, or a list of them), with
    what the command reports (``MeshGaussians``). See the module docstring for the rules; same seed, same result.

    Raises ValueError when the mesh has no face with a positive finite area (``MeshAssetError`` naming the file
    for a ``MeshAsset``: a file whose areas overflow float64) or ``count`` < 1 (the caller's to check).
    """
    import trimesh

    count = int(count)
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    parts, gltf = as_parts(mesh)
    wraps = (mesh.wraps if isinstance(mesh, MeshAsset) else None) or [DEFAULT_WRAP] * len(parts)
    verts = [np.asarray(p.vertices, np.float64) for p in parts]
    faces = [np.asarray(p.faces, np.int64) for p in parts]
    offsets = np.cumsum([0] + [len(v) for v in verts])
    face_offsets = np.cumsum([0] + [len(f) for f in faces])
    V = np.concatenate(verts) if verts else np.zeros((0, 3))
    F = np.concatenate([f + o for f, o in zip(faces, offsets[:-1])]) if faces else np.zeros((0, 3), np.int64)
    area = face_areas(V, F)
    total = float(area.sum())
    if not total > 0 or not math.isfinite(total):
        what = "the mesh has no face with a positive, finite area (in sum): nothing to sample"
        if isinstance(mesh, MeshAsset):  # read from the user's file: bad input, not our bug
            raise MeshAssetError(mesh.path, what, hint="check the mesh's units and that its faces are not all "
                                                       "degenerate")
        raise ValueError(what)
    # geometry only (no visuals, NaN corners replaced: zero-weight faces are never sampled anyway)
    geom = trimesh.Trimesh(np.nan_to_num(V, nan=0.0, posinf=0.0, neginf=0.0), F, process=False, validate=False)
    means, fidx, bary = trimesh.sample.sample_surface(geom, count, face_weight=area, return_barycentric=True,
                                                      seed=seed)
    R = shapes.face_frames(V[F[fidx]])                # columns: local x, y, z in the output frame
    rgb = np.empty((count, 3))
    sources = np.empty(count, object)
    part_of = np.searchsorted(face_offsets, fidx, side="right") - 1
    for k, part in enumerate(parts):
        sel = np.nonzero(part_of == k)[0]
        if len(sel):
            rgb[sel], sources[sel] = part_colours(part, fidx[sel] - face_offsets[k], bary[sel], gltf, wraps[k])
    rgb = np.clip(rgb, 0.0, 1.0)
    sigma = float(sigma_factor) * math.sqrt(total / count)
    ok = (np.isfinite(means).all(1) & np.isfinite(R).all((1, 2)) & np.isfinite(rgb).all(1) & (area[fidx] > 0))
    quats = np.zeros((count, 4))
    quats[ok] = cameras.rotation_to_quaternion(R[ok])
    m = int(ok.sum())
    sh = ((rgb[ok] - 0.5) / SH_C0)[:, None, :]
    g = splats.Gaussians(means=means[ok].astype(np.float32),
                         scales=np.tile([sigma, sigma, normal_ratio * sigma], (m, 1)).astype(np.float32),
                         quats=quats[ok].astype(np.float32), opacities=np.full(m, opacity, np.float32),
                         sh=sh.astype(np.float32))
    kinds, counts = np.unique(sources[ok].astype(str), return_counts=True) if m else (np.array([]), np.array([]))
    colour_counts = {str(k): int(c) for k, c in zip(kinds, counts)}
    main = max(colour_counts, key=colour_counts.get) if colour_counts else "none"
    return MeshGaussians(g, total, sigma, main, colour_counts, count - m)


def mesh_to_gaussians(mesh, count: int, seed: int = 0, sigma_factor: float = SIGMA_FACTOR) -> splats.Gaussians:
    """``count`` flat Gaussians on the surface of ``mesh`` (MeshAsset, trimesh.Trimesh or a list of them), in the
    mesh's frame and units: means (N, 3), scales (σ, σ, NORMAL_RATIO σ) with σ = sigma_factor sqrt(area / count),
    quaternions whose local z is the face normal, opacity OPACITY, SH degree 0. ValueError for a mesh with no area."""
    return sample_gaussians(mesh, count, seed, sigma_factor).gaussians


# --------------------------------------------------------------------------------------------------------------
# The command
# --------------------------------------------------------------------------------------------------------------

@contextlib.contextmanager
def _writing(out):
    """Held while ``out`` is written: a shared ``flock`` on its folder. A killed run leaves its temporary
    (``core.outputs``: ``.<name>.<random>.tmp``); the next run for the same output removes it, but only when no
    other ``mesh-asset`` is writing in that folder (an exclusive, non-blocking ``flock`` succeeds): a live run's
    temporary is never taken from it. Where the folder cannot be locked, nothing is removed."""
    folder = os.path.dirname(os.path.abspath(out))
    fd = None
    if fcntl is not None:
        with contextlib.suppress(OSError):
            fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        if fd is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                outputs.remove_temporaries(folder, [os.path.basename(out)])
            except OSError:  # another mesh-asset is writing here (or no flock on this file system)
                pass
            with contextlib.suppress(OSError):
                fcntl.flock(fd, fcntl.LOCK_SH)  # from exclusive, or after another run's clean-up
        yield
    finally:
        if fd is not None:
            os.close(fd)  # the lock goes with it (and with the process, if it is killed)


def _emit_warning(message: str, code: str) -> None:
    from backend import events

    events.warning(message, code)


def convert(path, out, count: int = DEFAULT_COUNT, up: str = "auto", seed: int = 0,
            sigma_factor: float = SIGMA_FACTOR, progress=None, warn=None) -> dict:
    """``python -m backend mesh-asset``: mesh file -> INRIA-layout Gaussian PLY (Z up, the mesh's units, SH 0, no
    normals), written atomically (a killed run's temporary is removed by the next run: ``_writing``).
    ``progress(stage, done, total)`` is called between steps; ``warn(message, code)`` once per warning (default: a
    ``warning`` event), before the PLY is written. Returns the ``done`` event's result (see the backend docs), its
    ``warnings`` the same (dicts: message, code). Raises MeshAssetError (the mesh, ``--out``; also when no sample
    is left to write) or ``errors.ArgumentError`` (``--count``) on bad input."""
    progress = progress or (lambda *a: None)
    warn = warn or _emit_warning
    path, out = os.fspath(path), os.fspath(out)
    if not 1 <= int(count) <= MAX_COUNT:
        raise errors.ArgumentError("--count", f"must be between 1 and {MAX_COUNT:,}, got {count}")
    if os.path.exists(out) and os.path.exists(path) and os.path.samefile(path, out):
        raise MeshAssetError(out, "--out is the input mesh itself: choose another file", "--out")
    if not out.lower().endswith(".ply"):
        raise MeshAssetError(out, "--out must be a .ply file", "--out")
    if os.path.isdir(out):
        raise MeshAssetError(out, "--out is a folder: name the .ply file to write", "--out")
    progress("load", 0, 3)
    asset = load_mesh(path, up)
    progress("sample", 1, 3)
    res = sample_gaussians(asset, count, seed, sigma_factor)
    if not len(res.gaussians):  # never an empty car with exit 0
        raise MeshAssetError(path, f"none of the {count:,} samples has a finite position, rotation and colour: "
                                   "nothing to write", hint="check the mesh opens in Blender with its textures, "
                                                            "or export it again as GLB")
    found = list(asset.warnings)
    if res.dropped:
        found.append({"message": f"{os.path.basename(path)}: {res.dropped:,} of {count:,} samples had a non-finite "
                                 f"position, rotation or colour and were left out ({len(res.gaussians):,} written)",
                      "code": DROPPED_SAMPLES})
    for w in found:
        warn(w["message"], w["code"])
    V = asset.vertices
    used = V[np.unique(asset.faces)]
    used = used[np.isfinite(used).all(axis=1)]
    box = upright_box(used)
    progress("write", 2, 3)
    outputs.make_folder(os.path.dirname(os.path.abspath(out)), "--out")
    name = "".join(ch if " " <= ch <= "~" else "?" for ch in os.path.basename(path))  # the header is ASCII
    try:
        with _writing(out):
            splats_inria.write_ply(out, splats.encode(res.gaussians),
                                   comment=f"scpainter mesh-asset {name} up={asset.up}")
    except PermissionError as e:
        raise MeshAssetError(out, f"--out cannot be written: {e.strerror}", "--out") from None
    progress("write", 3, 3)
    return {"ply": out, "count": len(res.gaussians), "up": asset.up, "area": res.area, "sigma": res.sigma,
            "colour_source": res.colour_source, "colour_counts": res.colour_counts, "dropped": res.dropped,
            "parts": len(asset.parts), "faces": int(len(asset.faces)),
            "obb": {"size": box["size"], "yaw_deg": box["yaw_deg"], "center": box["center"]},
            "obb_3d": oriented_box_3d(used),
            "bounds": [used.min(axis=0).tolist(), used.max(axis=0).tolist()], "warnings": found}
