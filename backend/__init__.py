"""SCPainter backend: the torch side, run as ``python -m backend <command>`` in a subprocess (docs/design.md §2,
§4.4).

Importing this package imports nothing heavy: each command imports what it needs when it runs, so ``doctor`` on a
machine without a GPU never initialises CUDA.

It does set ``OMP_WAIT_POLICY=PASSIVE`` unless the environment already names a policy, before anything loads torch
or numba: both use GNU OpenMP (torch its bundled libgomp, numba's ``omp`` threading layer the system's), whose
threads otherwise spin for milliseconds after every parallel region (``GOMP_SPINCOUNT`` 300000). On a shared CPU
(Blender itself, a second render), and between the two runtimes of one process, spinning threads take the cores
the working ones need: issue 16 measured a frame 7-15x slower with one busy process beside it, ~1.5-2x with
PASSIVE (``bench/render.py``, section ab, measures it). libgomp reads the variable once, when it is loaded, so it is
set here, at the top of ``python -m backend``, not later.

Likewise ``NUMBA_CACHE_DIR`` (unless set): the renderer's numba kernels (``cache=True``) compile once, ~15 s, and
are kept in the user's cache (``$XDG_CACHE_HOME/scpainter/numba``), never beside the source, which for an installed
extension is the add-on's own folder (docs/design.md §6).

(``core.backend_protocol.BACKEND_SETS_ENV`` names both for clients.)

And it makes OpenCV's WebP decoder (``backend/webp.py``, loaded when first used) the one ``core.splats.sog`` reads SOG
images with, so every command that reads an asset reads SOG.
"""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
if "NUMBA_CACHE_DIR" not in os.environ:
    from scpainter_blender.core.user_cache import user_cache_dir as _user_cache_dir  # stdlib only: doctor runs anywhere

    os.environ["NUMBA_CACHE_DIR"] = _user_cache_dir("numba")

from . import webp as _webp  # noqa: E402  (imports neither numpy nor OpenCV until a SOG is read)

_webp.register()
