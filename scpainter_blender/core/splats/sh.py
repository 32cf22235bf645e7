"""Real spherical harmonics as 3DGS renderers use them (degrees 0–3): the constants and the basis, defined once.

The INRIA rasterizer's ordering and signs (``SH_C0`` … ``SH_C3``, ``basis``): colour = max(0.5 + Σ_k Y_k(d) c_k, 0)
for the unit view direction d = normalise(mean − camera centre), in the Gaussians' frame. Plain Python floats and
arithmetic only (no numpy): ``basis`` runs unchanged on numpy arrays (``core.splats.gaussians.sh_basis``, the Blender
side and the tests' reference) and on torch tensors (``backend.render.gaussians.sh_colors``, the condition renderer), so
the two evaluate one formula.
"""

from __future__ import annotations

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
         1.445305721320277, -0.5900435899266435)

MAX_DEGREE = 3


def degree_of(num_coefficients: int) -> int:
    """The SH degree that has ``num_coefficients`` (1, 4, 9 or 16) coefficients per channel; ValueError otherwise."""
    for d in range(MAX_DEGREE + 1):
        if (d + 1) ** 2 == num_coefficients:
            return d
    raise ValueError(f"{num_coefficients} SH coefficients per channel is no degree 0-{MAX_DEGREE} (1, 4, 9 or 16)")


def basis(x, y, z, degree: int) -> list:
    """The (degree + 1)² basis values Y_k at unit directions with components ``x``, ``y``, ``z`` (arrays or tensors
    of one shape; Python floats work too), in the 3DGS order. The first (DC) value is the float ``SH_C0``:
    callers broadcast it. ValueError for a degree outside 0–3."""
    if not 0 <= degree <= MAX_DEGREE:
        raise ValueError(f"SH degree must be 0-{MAX_DEGREE}, got {degree}")
    out = [SH_C0]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy), SH_C2[3] * x * z,
                SH_C2[4] * (xx - yy)]
    if degree >= 3:
        out += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4 * zz - xx - yy),
                SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
                SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy)]
    return out
