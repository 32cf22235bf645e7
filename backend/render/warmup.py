"""The renderer's kernels, ready before the first frame rather than inside it (docs/design.md §10, "Kernels").

The CPU kernels are numba functions compiled with ``cache=True`` into ``NUMBA_CACHE_DIR`` (``backend/__init__``):
the first run after an install (or after their source changed) compiles them, ~13-15 s; later processes load them
from the cache, ~2-3 s of the first frame (loading, and numba's and OpenMP's thread pools starting). Neither is
silent any more:

- ``warm(device)`` renders a tiny scene (points and two overlapping Gaussian cars, ``amodal_pixels`` too) through
  the same ``frames.render_frame`` a job uses, so every kernel is compiled or loaded for the argument types a
  render passes (a test renders a job afterwards and checks that numba compiled nothing more). The warm backend
  (``python -m backend serve``) calls it at its start, with a ``compile`` progress event.
- ``ensure(device)``, which ``frames.render_frame`` calls, does it once per process before the first frame when the
  kernels are not cached yet (``kernels_cached``), between two ``compile`` progress events, so a one-shot render on
  a new install says what its first 15 s are.
"""

from __future__ import annotations

import time

import numpy as np

from scpainter_blender.core.backend_protocol import COMPILE_STAGE

from .. import events

#: The devices whose kernels this process has made ready (or is making ready: ``warm`` renders through
#: ``render_frame``, which calls ``ensure``).
_ready: set = set()


def kernels() -> list:
    """The renderer's numba dispatchers (every ``@njit(cache=True)`` function of the CPU path)."""
    from . import points_cpu, project_cpu, tiles_cpu

    return [points_cpu._project, points_cpu._scatter, points_cpu._decode, project_cpu._project,
            project_cpu._compact, tiles_cpu._radix_order, tiles_cpu._bin, tiles_cpu._composite, tiles_cpu._pack]


def kernels_cached() -> bool | None:
    """True when every kernel has compiled code in numba's cache for its current source (its index file read as
    numba reads it: an index written for another source stamp or numba version counts as empty); False when one
    has none; None when this numba's cache cannot be inspected so (its internals changed)."""
    try:
        return all(bool(k._cache._cache_file._load_index()) for k in kernels())
    except AttributeError:
        return None


def _tiny_scene(device):
    """(Scene, Frame, width, height): 400 points and two overlapping 200-Gaussian cars in front of the camera."""
    import torch

    from scpainter_blender.core import job as job_mod
    from scpainter_blender.core import shapes

    from . import frames as fr

    rng = np.random.default_rng(0)
    xyz = np.stack([rng.uniform(-4, 4, 400), rng.uniform(-3, 3, 400), rng.uniform(5, 20, 400)], 1)
    frame = np.repeat(np.arange(2), 200)
    scene = fr.Scene(origin=np.zeros(3), device=torch.device(device))
    scene.xyz = torch.as_tensor(xyz.astype(np.float32), device=scene.device)
    scene.rgb = torch.as_tensor(rng.uniform(0, 1, (400, 3)).astype(np.float32), device=scene.device)
    scene.frame = torch.as_tensor(frame, device=scene.device)
    scene.frames_present = frozenset({0, 1})
    scene.frame_slices, scene.frame_boxes = fr.frame_index(frame, xyz.astype(np.float32))
    for i, x in enumerate((-0.5, 0.8)):
        place = np.eye(4)
        place[:3, 3] = (x, 0.5, 8.0 + 2 * i)
        scene.assets.append(fr.make_asset(f"car{i}", shapes.procedural_car_gaussians(count=200, seed=i), {1: place},
                                          scene.device))
    W, H = 48, 32
    K = np.array([[40.0, 0, W / 2], [0, 40.0, H / 2], [0, 0, 1]])
    return scene, job_mod.Frame(1, K, np.eye(4), [0, 1]), W, H


def warm(device) -> float:
    """Compile (or load) every kernel a render on ``device`` runs, by rendering a tiny scene; its seconds."""
    from . import frames as fr

    _ready.add(str(device))
    t = time.perf_counter()
    scene, entry, W, H = _tiny_scene(device)
    kept = {}
    fr.render_frame(scene, entry, W, H, 0, keep=kept)
    fr.amodal_pixels(scene, entry, W, H, projection=kept["projection"])
    return time.perf_counter() - t


def announce_and_warm(device, cached: bool | None) -> float:
    """``warm`` between two ``compile`` progress events (``cached``: what ``kernels_cached`` said, in both), the
    time logged; its seconds."""
    what = {True: "loading the renderer's kernels", None: "making the renderer's kernels ready"}.get(
        cached, "compiling the renderer's kernels (once after an install, about 15 s)")
    events.progress(COMPILE_STAGE, 0, 1, cached=cached, message=what)
    seconds = warm(device)
    events.progress(COMPILE_STAGE, 1, 1, cached=cached, message=what, seconds=seconds)
    events.log_here(f"{what}: {seconds:.1f} s")
    return seconds


def ensure(device) -> None:
    """Once per process and device, before its first frame: on the CPU, when the kernels are not cached yet,
    ``announce_and_warm`` (a cached kernel loads within the first frame, a second or two, said by nothing)."""
    if str(device) in _ready:
        return
    _ready.add(str(device))
    if str(device) != "cpu":  # Triton keeps its own cache; nothing to inspect here
        return
    cached = kernels_cached()
    if not cached:
        announce_and_warm(device, cached)
