"""``python -m backend splat-asset FILE --out PLY``: any Gaussian file the readers accept (the formats of
``core.splats.formats``, read by ``core.splats.reader``) rewritten as an INRIA-layout PLY
(``core.splats.inria.write_ply``, atomically), the values as read, rows unchanged (invalid ones included: the
import and the renderer count and drop them as for any file).

What Blender's import runs for formats whose decoding needs what Blender's Python lacks (their records'
``needs_backend``: SOG's WebP images, the backend's decoder ``backend/webp.py``), as it runs ``mesh-asset`` for
meshes. A mesh is refused with the message that points at ``mesh-asset``. No bpy, no torch.
"""

from __future__ import annotations

import os


def convert(source: str, out: str) -> dict:
    """Read ``source`` and write its Gaussians to ``out`` (INRIA PLY); the ``done`` event's ``result``: ``ply``
    (the written file), ``source``, ``format`` (``GaussianPly.format``), ``count`` (rows written), ``sh_degree``
    and ``dropped`` (rows that decoding will drop, by reason). SplatsError (an InputError) for an unusable file."""
    from scpainter_blender.core import outputs
    from scpainter_blender.core.splats import gaussians as splats, inria, reader

    source, out = os.path.abspath(source), os.path.abspath(out)
    ply = reader.read(source)
    outputs.make_folder(os.path.dirname(out), "--out folder")
    inria.write_ply(out, ply, comment=f"splat-asset of {os.path.basename(source)} ({ply.format})")
    _, dropped = splats.valid_rows(ply)
    return {"ply": out, "source": source, "format": ply.format, "count": len(ply), "sh_degree": ply.sh_degree,
            "dropped": dropped}
