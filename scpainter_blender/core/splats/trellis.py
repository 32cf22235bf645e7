"""TRELLIS / Amodal3R Gaussian files: their axes, and how to recognise them (``detect_axes``).

TRELLIS (microsoft/TRELLIS) and Amodal3R write the INRIA layout (``core.splats.inria``) with SH degree 0
(``TRELLIS_PROPERTIES``: 17 float properties, zero normals), the object inside the unit cube
(``TRELLIS_MEAN_BOUND``), and positions/rotations multiplied by ``ZUP_TO_TRELLIS_FILE`` (the file holds (x, -z, y)
of their Z-up frame); the Gaussian import undoes it with ``ZUP_TO_TRELLIS_FILE.T`` when ``detect_axes`` says
"TRELLIS". Everything else decodes exactly like an INRIA file.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import numpy as np

from . import inria
from .gaussians import FORMAT_NAMES, GaussianPly, valid_rows

#: File axes from TRELLIS's Z-up object axes: p_file = ZUP_TO_TRELLIS_FILE @ p (a -90° turn about X undoes it).
ZUP_TO_TRELLIS_FILE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

#: What TRELLIS's ``Gaussian.save_ply`` writes (microsoft/TRELLIS ``trellis/representations/gaussian/
#: gaussian_model.py``, ``construct_list_of_attributes`` with SH degree 0), in this order, all float32.
TRELLIS_PROPERTIES = ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
                      "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")

#: How far a TRELLIS/Amodal3R mean can be from the origin. microsoft/TRELLIS
#: ``trellis/models/structured_latent_vae/decoder_gs.py`` (``to_representation``) puts each Gaussian at its voxel
#: centre (i + 0.5) / 64 plus tanh(.) / 64 · 0.5 · voxel_size, with resolution 64 and voxel_size 1.5 in the
#: released decoder's config (``slat_dec_gs_swin8_B_64l8gs32_fp16``), so at most 0.75 voxel from the centre; the
#: ``Gaussian`` aabb [-0.5, -0.5, -0.5, 1, 1, 1] then shifts the cube to [-0.5, 0.5]^3 and save_ply only permutes
#: axes. The tightest bound is 0.5 - 0.5/64 + 0.75/64 = 0.50390625; we accept 0.75 voxel beyond the cube's face,
#: 0.5 + 0.75/64 = 0.51171875, plus float slack, so that a fork with another voxel-centre convention still passes.
TRELLIS_MEAN_BOUND = 0.5 + 0.75 / 64 + 1e-5


def _layout(ply: GaussianPly) -> tuple:
    """The vertex properties of ``ply``'s file, or for an in-memory one those ``write_ply`` would write."""
    return tuple(ply.properties) if ply.properties else tuple(inria.write_names(ply))


def detect_axes(ply: GaussianPly, keep=None) -> tuple[str, str]:
    """("TRELLIS" or "NONE", one sentence why) for the import report.

    TRELLIS/Amodal3R files are recognised by their exact layout (``TRELLIS_PROPERTIES`` in that order, all normals
    zero, SH degree 0, float PLY) and all kept means within ``TRELLIS_MEAN_BOUND`` (see there); ``keep`` is the
    mask of rows to use (default: the rows ``decode`` keeps).
    """
    if ply.format != "inria":
        return "NONE", f"not TRELLIS: its layout is {FORMAT_NAMES.get(ply.format, ply.format)}"
    if ply.sh_degree:
        return "NONE", f"not TRELLIS: has f_rest (SH {ply.sh_degree})"
    if not {"nx", "ny", "nz"} <= set(ply.extra):
        return "NONE", "not TRELLIS: no normals (TRELLIS writes zero nx ny nz)"
    layout = _layout(ply)
    if layout != TRELLIS_PROPERTIES:
        others = [n for n in layout if n not in TRELLIS_PROPERTIES]
        if others:
            return "NONE", f"not TRELLIS: extra properties {others}"
        return "NONE", "not TRELLIS: the properties are not in TRELLIS's save_ply order"
    if any(np.any(np.asarray(ply.extra[n]) != 0) for n in ("nx", "ny", "nz")):
        return "NONE", "not TRELLIS: normals are not all zero"
    keep = valid_rows(ply)[0] if keep is None else np.asarray(keep, bool)
    if not keep.any():
        return "NONE", "not TRELLIS: no valid Gaussians"
    reach = float(np.abs(ply.xyz[keep].astype(np.float64)).max())
    if reach > TRELLIS_MEAN_BOUND:
        return "NONE", (f"not TRELLIS: means reach {reach:.4g}, outside the unit cube (TRELLIS stays within "
                        f"±{TRELLIS_MEAN_BOUND:.4f})")
    return "TRELLIS", (f"TRELLIS/Amodal3R layout ({len(TRELLIS_PROPERTIES)} properties, zero normals, SH 0) and all "
                       f"means within ±{TRELLIS_MEAN_BOUND:.4f} (the decoder's unit cube)")
