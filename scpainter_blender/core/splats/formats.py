"""The Gaussian-splat file formats, one record each (``FORMATS``): the one place a format's key, names, extensions,
reader and needs are written. Everything that lists formats is made from it: ``FORMAT_NAMES`` and ``ACCEPTED``
(here, re-exported by ``core.splats.gaussians``), ``core.splats.reader``'s ``READERS``, ``FORMAT_EXTENSIONS``,
``SPLAT_EXTENSIONS`` / ``ASSET_EXTENSIONS`` and the extensions ``_not_accepted`` names, the import's choice of the
backend (``scene.gaussians.is_backend_splat_file``: ``needs_backend``) and the import's tooltip
(``operators/import_gaussians.py``). Prose elsewhere refers here, or a test checks it against these records
(tests/core/splats/test_formats.py, tests/test_docs.py).

Adding a format: its reader module, its record here (in the order the file browser lists extensions), its branch
in ``reader.detect`` (content sniffing stays code) and its tests.

This module imports nothing of the package: ``gaussians`` (which every reader imports) takes ``ACCEPTED`` and
``FORMAT_NAMES`` from here, so a record names its reader by ``module.function`` and ``reader`` resolves it.
No bpy, no torch, no numpy.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SplatFormat:
    """One Gaussian-splat file format.

    ``key``: what ``reader.detect`` returns for it and ``reader.READERS``' key; ``name``: how it reads in a list of
    formats (a tooltip); ``extensions``: the file extensions (lower case, with the dot) it is saved under, the
    file browsers' filter (``.glb``/``.gltf``/``.ply`` are meshes too, told apart by content); ``read``: its reader,
    ``"module.function"`` within ``core.splats``, taking a path and returning a ``GaussianPly``; ``layouts``: the
    ``GaussianPly.format`` values its reader gives, with their human names (``FORMAT_NAMES``); ``accepted``: the
    phrases ``ACCEPTED`` names it by when ``name`` alone does not say it all (empty: its ``name``); ``by_extension``: ``detect`` names it by its extension alone (a headerless
    format: nothing in its bytes says what it is); ``needs_backend``: its decoding needs what Blender's Python
    lacks, so the import has ``python -m backend splat-asset`` rewrite it as an INRIA PLY first.
    """

    key: str
    name: str
    extensions: tuple
    read: str
    layouts: tuple
    accepted: tuple = ()
    by_extension: bool = False
    needs_backend: bool = False

    @property
    def accepted_phrases(self) -> tuple:
        """The phrases ``ACCEPTED`` names this format by: ``accepted``, else its ``name``."""
        return self.accepted or (self.name,)


#: Every Gaussian format the readers take, in the order the file browser's filter lists their extensions.
FORMATS = (
    SplatFormat("ply", "PLY (INRIA 3DGS, TRELLIS/Amodal3R, half floats, SuperSplat compressed)", (".ply",),
                "reader.read_ply",
                (("inria", "INRIA 3DGS PLY"), ("inria_half", "INRIA 3DGS PLY, half floats"),
                 ("supersplat_compressed", "SuperSplat compressed PLY")),
                ("binary INRIA 3DGS PLY (float, double or half floats in ushort slots; TRELLIS/Amodal3R included)",
                 "SuperSplat compressed PLY (.compressed.ply)")),
    SplatFormat("splat", "antimatter15 .splat", (".splat",), "compressed.read_splat",
                (("splat", "antimatter15 .splat"),), by_extension=True),
    SplatFormat("ksplat", "GaussianSplats3D .ksplat", (".ksplat",), "ksplat.read",
                (("ksplat", "GaussianSplats3D .ksplat"),)),
    SplatFormat("spz", "Niantic .spz", (".spz",), "spz.read", (("spz", "Niantic SPZ"),)),
    SplatFormat("sog", "PlayCanvas SOG (.sog or meta.json)", (".sog",), "sog.read", (("sog", "PlayCanvas SOG"),),
                needs_backend=True),
    SplatFormat("gltf_splats", "glTF/GLB with KHR_gaussian_splatting", (".glb", ".gltf"), "gltf_splats.read",
                (("gltf_splats", "glTF KHR_gaussian_splatting"),)),
)
#: The record of each key.
BY_KEY = {f.key: f for f in FORMATS}

#: Human names of ``GaussianPly.format`` values, for import reports.
FORMAT_NAMES = {layout: name for f in FORMATS for layout, name in f.layouts}

#: The order ``ACCEPTED`` names the formats in: its text predates the table and names SPZ before ``.ksplat``
#: (the file browser lists ``.ksplat`` first); a format not here follows in the table's order.
ACCEPTED_ORDER = ("ply", "splat", "spz", "ksplat")


def _accepted_text() -> str:
    ordered = [BY_KEY[k] for k in ACCEPTED_ORDER] + [f for f in FORMATS if f.key not in ACCEPTED_ORDER]
    phrases = [p for f in ordered for p in f.accepted_phrases]
    return ", ".join(phrases[:-1]) + " and " + phrases[-1]


#: What the readers accept, for messages.
ACCEPTED = _accepted_text()
