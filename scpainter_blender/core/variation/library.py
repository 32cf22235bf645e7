"""The cars a variation draws from: every file of a library folder the Blender import reads, stood in the world
as the import stands it (``core.splats.asset_frame``), each with its label box; mesh files converted to Gaussians
once (cached by file identity), recoloured copies written once per hue.

Units: ``box_to_file`` and ``size`` in the file's units (the job's ``AssetBox``); ``scale`` metres per file unit
(the import's default length: 4.5 m for a TRELLIS/Amodal3R unit cube, the file's units otherwise).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .. import colors, errors, files, outputs
from ..geometry import boxes
from ..job import DEFAULT_CLASS
from ..splats import asset_frame, inria, reader
from ..splats.gaussians import valid_rows
from .spec import VariationError

#: Library files larger than this are refused before reading (a 1 M-Gaussian PLY is ~250 MB).
MAX_ASSET_BYTES = 4 << 30
#: At most this many files in a library.
MAX_ASSETS = 10_000

# The shape of a road vehicle, which a library car's box (metres, as the import stands it: Z up, its length the
# longer horizontal side, so width <= length) must have (``vehicle_shape_problem``; the length's bounds are
# ``asset_frame.CAR_LENGTH_M``, where a length outside says "other units"). The widest and tallest vehicles allowed
# on public roads: 2.55 m wide (2.60 m refrigerated) and 4.00 m high in the EU (Council Directive 96/53/EC, Annex
# I), 102 in (2.59 m) wide in the US (23 CFR 658.15), 13.5-14.5 ft (4.1-4.4 m) high by state; mirrors are not
# counted, and the box of a capture's Gaussians runs a little beyond the body. Whatever is wider or taller than
# these, or taller than long, or flatter than the flattest cars (a Formula 1 car is 0.95 m high for 5.6 m long, a
# sixth), is no vehicle: a capture with its ground or a wall around the car, a room, a tree, a sheet.
#: Widest library car, metres: 2.60 m allowed plus 0.4 m for mirrors and the Gaussians' edge.
MAX_VEHICLE_WIDTH_M = 3.0
#: Tallest library car, metres: 4.4 m allowed (the tallest US states) plus 0.1 m.
MAX_VEHICLE_HEIGHT_M = 4.5
#: Least height for its length: a tenth (the flattest cars are a sixth).
MIN_VEHICLE_HEIGHT_RATIO = 0.1
#: What to do with a library file that is no car: a hint every shape refusal shares.
SHAPE_HINT = ("take it out of the car library, or crop it to the car (a capture's ground or surroundings?) and stand "
              "it Z up in metres")
#: What a bad library file's error adds to its hint when ``vary`` runs without ``--skip-bad``.
SKIP_BAD_HINT = "or run vary with --skip-bad to leave the library files that cannot be used out (listed in the manifest)"


def vehicle_shape_problem(width: float, length: float, height: float) -> str | None:
    """Why a box of ``width`` x ``length`` x ``height`` metres (width <= length, as ``boxes.estimate_box`` gives
    them) is not a road vehicle's (the rule above), or None."""
    lo, hi = asset_frame.CAR_LENGTH_M
    if not lo <= length <= hi:
        return (f"would be {length:.3g} m long in its file's units, not a car's {lo:g}–{hi:g} m (millimetres or "
                "centimetres?)")
    if width > MAX_VEHICLE_WIDTH_M:
        return (f"is not shaped like a road vehicle: {width:.2f} m wide ({length:.2f} m long, {height:.2f} m high), "
                f"wider than the {MAX_VEHICLE_WIDTH_M:g} m any road vehicle is (2.55–2.60 m allowed, with mirrors)")
    if height > MAX_VEHICLE_HEIGHT_M:
        return (f"is not shaped like a road vehicle: {height:.2f} m high, taller than the {MAX_VEHICLE_HEIGHT_M:g} m "
                "any road vehicle is")
    if height > length:  # what stands taller than it is long drives on no road: a stool, a tree, a car on its end
        return (f"is not shaped like a road vehicle: {height:.2f} m high for {length:.2f} m long (as the import "
                "stands it, Z up)")
    if height < MIN_VEHICLE_HEIGHT_RATIO * length:
        return (f"is not shaped like a road vehicle: {height:.2f} m high for {length:.2f} m long, flatter than a "
                f"tenth of its length (a sheet or a patch of ground, or its up axis wrong)")
    return None


@dataclass
class LibraryAsset:
    """One car of the library: ``name`` (its file name), ``source`` (the library file), ``ply`` (the Gaussian file
    jobs name: the source, or the mesh's conversion), ``box_to_file`` (4, 4) rigid and ``size`` (3,) (width,
    length, height) in file units, ``scale`` metres per file unit, ``category`` the label class."""
    name: str
    source: str
    ply: str
    box_to_file: np.ndarray
    size: np.ndarray
    scale: float
    category: str = DEFAULT_CLASS

    @property
    def size_m(self) -> np.ndarray:
        return self.size * self.scale

    def recoloured(self, degrees: int, folder: str) -> str:
        """The Gaussian file with its colours' hue turned by ``degrees`` (whole degrees; 0: ``ply`` itself),
        written once into ``folder`` as ``<name>.<file key>.hue±DDD.ply`` (INRIA layout, every SH coefficient
        turned by ``colors.hue_rotation``); the temporaries a killed run left for that name go first (``folder``:
        the variation run's own ``library/``, under its lock)."""
        if degrees == 0:
            return self.ply
        out = os.path.join(folder, f"{self.name}.{asset_frame.file_key(self.ply)}.hue{int(degrees):+04d}.ply")
        if not os.path.isfile(out):
            ply = reader.read(self.ply)
            M = colors.hue_rotation(degrees).astype(np.float32)
            ply.f_dc = np.ascontiguousarray(ply.f_dc @ M.T)
            ply.f_rest = np.ascontiguousarray(np.einsum("ij,njk->nik", M, ply.f_rest))
            ply.format = "inria"
            outputs.own_folder(*os.path.split(folder))   # never through a link planted there
            outputs.remove_temporaries(folder, [os.path.basename(out)])   # what a killed run left for it
            inria.write_ply(out, ply, comment=f"{self.name}: hue turned {int(degrees):+d} degrees by SCPainter")
        return out


def library_files(folder) -> list:
    """The asset files of a library folder (not recursive; hidden files and sub-folders left out), sorted by name. ``VariationError`` when the folder is
    missing, holds none, or too many."""
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise VariationError(folder, "cars.library", "is not a folder",
                             hint=f"give a folder of car files ({', '.join(reader.ASSET_EXTENSIONS)})")
    names = sorted(n for n in os.listdir(folder) if os.path.splitext(n)[1].lower() in reader.ASSET_EXTENSIONS
                   and not n.startswith(".") and os.path.isfile(os.path.join(folder, n)))  # files, not folders
    if not names:
        raise VariationError(folder, "cars.library", "holds no car files",
                             hint=f"put files of these kinds there: {', '.join(reader.ASSET_EXTENSIONS)}")
    if len(names) > MAX_ASSETS:
        raise VariationError(folder, "cars.library", f"holds {len(names)} car files, more than {MAX_ASSETS}")
    return [os.path.join(folder, n) for n in names]


def load_asset(path, cache: str, convert_mesh=None, mesh_count: int = 200_000, car: bool = True) -> LibraryAsset:
    """One library file as a ``LibraryAsset``. A mesh (``reader.MESH_EXTENSIONS``, or a mesh PLY) is converted by
    ``convert_mesh(mesh, out_ply, count)`` into ``cache`` (once: the name carries the file's identity), which
    ``None`` refuses. ``car``: refuse a file whose default size is no road vehicle's (a library car; not a car the
    base job already holds, which the user placed). Errors: the reader's ``SplatsError`` naming the file,
    ``VariationError`` for a file with no valid Gaussians, too large, or (``car``) not shaped like a car."""
    path = os.path.abspath(path)
    with files.open_regular(path, VariationError) as f:
        size = os.fstat(f.fileno()).st_size
    if size > MAX_ASSET_BYTES:
        raise VariationError(path, "(file)", f"is {size / 2**30:.1f} GiB, more than a car asset may be")
    is_mesh = reader.is_mesh(path)
    ply_path = path
    if is_mesh:
        if convert_mesh is None:
            raise VariationError(path, "(file)", "is a mesh, and this run cannot convert meshes to Gaussians",
                                 hint="run the variation through `blender -c scpainter vary` or convert it first "
                                      "with `python -m backend mesh-asset`")
        ply_path = os.path.join(cache, asset_frame.mesh_gaussians_name(path, mesh_count))
        if not os.path.isfile(ply_path):
            outputs.own_folder(*os.path.split(cache))   # never through a link planted there
            outputs.remove_temporaries(cache, [os.path.basename(ply_path)])   # what a killed run left for it
            convert_mesh(path, ply_path, mesh_count)
    ply = reader.read(ply_path)
    keep, dropped = valid_rows(ply)
    if keep.sum() < 4:
        raise VariationError(ply_path, "(file)", f"has {int(keep.sum())} valid Gaussians of {len(ply)} "
                                                 f"(dropped: {dropped})", hint="take it out of the library")
    frame = asset_frame.asset_frame(ply, keep, is_mesh)
    means_data = ply.xyz[keep].astype(np.float64) @ frame.file_to_data[:3, :3].T + frame.file_to_data[:3, 3]
    box_to_data, box_size = boxes.estimate_box(means_data, up=(0.0, 0.0, 1.0))
    box_to_file = np.linalg.inv(frame.file_to_data) @ box_to_data
    width, length, height = np.asarray(box_size, np.float64) * frame.scale
    problem = vehicle_shape_problem(width, length, height) if car else None
    if problem is not None:
        raise VariationError(path, "(file)", problem, hint=SHAPE_HINT)
    return LibraryAsset(os.path.basename(path), path, ply_path, box_to_file, np.asarray(box_size, np.float64),
                        float(frame.scale))


def load_library(folder, cache: str, convert_mesh=None, mesh_count: int = 200_000, skipped: list | None = None) -> list:
    """Every car of a library folder (``library_files``), loaded with ``load_asset``. A file that cannot be used
    (any ``InputError``: unreadable, damaged, no car's shape) stops the run, its error's hint suggesting
    ``--skip-bad`` (``SKIP_BAD_HINT``); with ``skipped`` (a list: ``vary --skip-bad``) it is left out and appended
    there as ``{"file": path, "field": ..., "reason": the error's text}``, and only a library of which no file
    can be used is an error (``VariationError`` ``cars.library``)."""
    paths, assets = library_files(folder), []
    for path in paths:
        try:
            assets.append(load_asset(path, cache, convert_mesh, mesh_count))
        except errors.InputError as e:
            if skipped is None:
                e.hint = f"{e.hint}; {SKIP_BAD_HINT}" if e.hint else SKIP_BAD_HINT[len("or "):]
                raise
            skipped.append({"file": path, "field": e.field, "reason": str(e)})
    if not assets:
        raise VariationError(folder, "cars.library", f"none of its {len(paths)} car files can be used (the first: "
                                                     f"{skipped[0]['reason'] if skipped else 'none'})",
                             hint="put car files that the import reads into the library")
    return assets


def skipped_text(entry: dict) -> str:
    """The warning for a library file ``load_library`` left out (one of its ``skipped`` entries)."""
    return f"library file {os.path.basename(entry['file'])} left out (--skip-bad): {entry['reason']}"
