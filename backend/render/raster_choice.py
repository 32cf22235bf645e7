"""Which Gaussian compositor a frame uses — the tile kernels (and their tile size) or the pair rasterizer — from
the frame's measured sizes: the one place the rule and its thresholds live.

``choose(device_type, n_gaussians, width, height, method="auto", tile=None)`` returns a ``Choice``; ``method``
"tiles" or "pairs" (and ``tile``) force it. ``tiles.rasterize`` asks it for every frame it is not told about;
``bench/render.py``'s ``choice`` section prints, per scene size, each method's and tile size's time and error
against the float64 reference beside what ``choose`` picked, so a device run can re-derive the thresholds below.

Sources of the thresholds (each a measurement, its machine and date):

* CUDA, ``shared/gpu/render_cuda.json`` (NVIDIA H200, 2026-12-04, main cec9ed7, the per-Gaussian Triton kernel
  that the batched one replaced): whole 576 x 1024 frames of 3 M points + 200 k Gaussians (the accuracy rows are
  timed on the speed scene): pair rasterizer 23.8 ms, tiles 8 24.8 ms, tiles 16 30.6 ms, tiles 32 63.0 ms. Tiles of
  8 beat 16 and 32, so 8 is the CUDA tile. The pair rasterizer and tiles 8 were within 4 % (3 repeats): no size
  where the pairs are clearly faster was measured, and both costs grow with the pixel–Gaussian pairs, so
  their ratio, not a size, decides; the batched kernel cuts the tile path's per-entry cost (``tiles_cuda``), so
  the pairs are not chosen on CUDA (``CUDA_PAIRS_MAX_GAUSSIANS_PER_MPIX`` = 0) until a device run's ``choice`` table
  shows a size where they win. The pair rasterizer also refuses frames over its pair budget (200 M), the tiles
  never do.
* CPU, this project's 2-CPU machine, 2026-12-05 (``bench/render.py --sections choice``, 576 x 1024, 2 threads,
  1 M points, the car 8 m ahead; a machine shared with other work, so absolute times are inflated): Gaussian pass
  ms at 2 k / 20 k / 100 k Gaussians: pairs 2100 / 2681 / 5981, tiles 4: 113 / 172 / 388, tiles 8: 77 / 162 / 372,
  tiles 16: 78 / 175 / 456. The numba tiles beat the pairs 20-30x at every size and 8-px tiles were the fastest at
  each (4 and 16 within 1-25 %), so the CPU keeps tiles of 8 at every size.
"""

from __future__ import annotations

from typing import NamedTuple

TILE_CUDA = 8   # H200, render_cuda.json: tiles 8 24.8 ms < 16 30.6 ms < 32 63.0 ms (3 M points + 200 k Gaussians)
TILE_CPU = 8    # this machine's CPUs: 8 beats 4 and 16 (bench/render.py --sections choice)
#: CUDA frames with at most this many projected Gaussians per megapixel of the image composite with the pair
#: rasterizer (0: never; see the module docstring for why the H200 figures set no threshold yet). Per megapixel:
#: both methods' costs grow with the pixel–Gaussian pairs, which for a given asset grow with the image's area.
CUDA_PAIRS_MAX_GAUSSIANS_PER_MPIX = 0.0
#: The same for the CPU (0: never: the numba tiles were 20-30x faster than the pairs at every size measured, 2 k to
#: 100 k Gaussians at 576 x 1024).
CPU_PAIRS_MAX_GAUSSIANS_PER_MPIX = 0.0
METHODS = ("auto", "tiles", "pairs")


class Choice(NamedTuple):
    """``method`` "tiles" or "pairs"; ``tile`` the tile size in pixels (None for the pairs); ``reason`` says which
    rule decided (printed by the bench)."""
    method: str
    tile: int | None
    reason: str


def choose(device_type: str, n_gaussians: int, width: int, height: int, method: str = "auto",
           tile: int | None = None) -> Choice:
    """The compositor for a frame of ``n_gaussians`` projected Gaussians at ``width`` x ``height`` on a device of
    type ``device_type`` ("cpu", "cuda", other: the pairs, the only code that runs there). ``method`` "tiles" or
    "pairs" forces the method, ``tile`` the tile size (and with it the tiles)."""
    if method not in METHODS:
        raise ValueError(f"unknown Gaussian compositor {method!r}: one of {', '.join(METHODS)}")
    if tile is not None and (int(tile) < 1 or (device_type == "cuda" and int(tile) & (int(tile) - 1))):
        raise ValueError(f"tile size {tile}: a positive number of pixels, on CUDA a power of two (the Triton "
                         "kernel's lanes)")
    if method == "pairs":
        return Choice("pairs", None, "forced")
    if device_type not in ("cpu", "cuda"):
        return Choice("pairs", None, f"no tile kernel on {device_type}")
    default_tile = TILE_CUDA if device_type == "cuda" else TILE_CPU
    if method == "tiles" or tile is not None:
        return Choice("tiles", int(tile or default_tile), "forced")
    per_mpix = CUDA_PAIRS_MAX_GAUSSIANS_PER_MPIX if device_type == "cuda" else CPU_PAIRS_MAX_GAUSSIANS_PER_MPIX
    limit = int(per_mpix * width * height / 1e6)
    if n_gaussians <= limit:
        return Choice("pairs", None, f"{n_gaussians} Gaussians <= {limit} ({per_mpix:g}/Mpx) on {device_type}")
    return Choice("tiles", default_tile, f"{device_type}: tiles of {default_tile} above {limit} Gaussians")
