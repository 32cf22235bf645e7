"""The fast Gaussian rasterizer: tile binning, then per-pixel front-to-back loops in a compiled kernel.

Same rules and the same result as ``gaussians.rasterize`` (the tested torch reference, which builds every
(Gaussian, pixel) pair and sorts them): a pixel composites the Gaussians whose pixel box
(``gaussians.pixel_boxes``, the exact screen extent) contains it, in depth order with ties by original index,
skips α < 1/255, stops before the one that would take the transmittance below 1e-4, and ignores Gaussians at or
behind its nearest point. The difference is the cost: the reference touches every pair; here each pixel walks the
depth-sorted list of its tile and leaves it as soon as it is saturated or the next Gaussian lies behind its point,
so opaque surfaces cost a few Gaussians per pixel, not all of them.

Binning: every Gaussian is entered in each ``tile`` x ``tile`` pixel tile its box touches; the entries are sorted
by (tile, depth rank) and ``tile_start[t] .. tile_start[t + 1]`` delimits tile t's list. ``bin_tiles`` does it in
torch (any device; the reference); on the CPU ``tiles_cpu`` does it in numba with a counting sort and gets the
same lists. Compositing: numba on the CPU (``tiles_cpu``), Triton on CUDA (``tiles_cuda``, fed by
``kernel_inputs``); the reference is used on a CUDA machine without Triton, and on CUDA for more than
``MAX_ASSETS_CUDA`` assets (the Triton kernel keeps one weight per pixel and asset in registers).

Every path also returns the instance (``gaussians.rasterize``' rule: per pixel the asset with the largest
Σ α·transmittance, ties to the lower id, where that weight exceeds the transmittance left; else 0), from each
Gaussian's asset id (``proj["asset_id"]``, 1-based; none: every Gaussian is asset 1).
"""

from __future__ import annotations

import torch

from . import gaussians as gs

TILE = 16       # CUDA: one Triton program per 16 x 16 tile (256 lanes)
TILE_CPU = 8    # CPU: smaller tiles mean shorter lists per pixel (measured faster: bench/render.py)
#: More assets than this in one frame: CUDA composites with the torch reference (the Triton kernel's per-pixel,
#: per-asset accumulator is a [TILE², A_PAD] block, A_PAD the next power of two ≥ the number of assets).
MAX_ASSETS_CUDA = 32


def bin_tiles(proj, width: int, height: int, tile: int = TILE) -> dict:
    """Tile lists of projected Gaussians (see the module docstring). Returns ``boxes`` (G, 4) int32 x0 x1 y0 y1,
    ``entries`` (E,) int32 rows of ``proj`` sorted by (tile, depth rank), ``entry_tile`` (E,) the tile of each
    entry, ``tile_start`` (tiles + 1,) int64, ``tiles_x``, ``tiles_y`` and ``tile``."""
    dev = proj["mean2d"].device
    tiles_x, tiles_y = -(-width // tile), -(-height // tile)
    G = len(proj["depth"])
    boxes = gs.pixel_boxes(proj, width, height)
    tx0, tx1, ty0, ty1 = (boxes // tile).unbind(1)
    tw, th = tx1 - tx0 + 1, ty1 - ty0 + 1
    counts = tw * th
    g = torch.repeat_interleave(torch.arange(G, device=dev), counts)
    k = torch.arange(len(g), device=dev) - (torch.cumsum(counts, 0) - counts)[g]
    tile_id = (ty0[g] + k // tw[g]) * tiles_x + tx0[g] + k % tw[g]
    order = torch.argsort(tile_id * max(G, 1) + gs.depth_rank(proj)[g])
    entries = g[order].to(torch.int32)
    entry_tile = tile_id[order]
    per_tile = torch.bincount(tile_id, minlength=tiles_x * tiles_y)
    tile_start = torch.zeros(tiles_x * tiles_y + 1, dtype=torch.int64, device=dev)
    tile_start[1:] = torch.cumsum(per_tile, 0)
    return {"boxes": boxes.to(torch.int32), "entries": entries, "entry_tile": entry_tile, "tile_start": tile_start,
            "tiles_x": tiles_x, "tiles_y": tiles_y, "tile": tile}


def kernel_inputs(proj, bins, width, height, background_depth, dtype=torch.float32):
    """The flat, contiguous arrays the Triton kernel reads, one row per tile entry: ``params`` (E, 12) = mean x,
    mean y relative to the entry's tile origin, conic a b c, opacity, depth, r g b, the asset id (1-based,
    ``gaussians.asset_ids``; exact in float32 below 2^24), one pad; ``boxes`` (E, 4) int32 absolute pixel boxes;
    ``tile_start``; the background depth.

    Precision: the projection arrives in float64 (``frames.render_frame``); the kernel gets float32 (``dtype``)
    with means relative to the tile (values below the tile size: ~1e-6 px of rounding instead of ~6e-5 px at
    x ~ 1000, which thin, edge-on Gaussians would turn into ~1e-4 of α)."""
    dev, dt = proj["mean2d"].device, dtype
    bg = (torch.full((height * width,), float("inf"), dtype=dt, device=dev) if background_depth is None
          else background_depth.reshape(-1).to(dt).contiguous())
    per_gaussian = torch.zeros((len(proj["depth"]), 12), dtype=torch.float64, device=dev)
    per_gaussian[:, 0:2] = proj["mean2d"]
    per_gaussian[:, 2:5] = proj["conic"]
    per_gaussian[:, 5] = proj["opacity"]
    per_gaussian[:, 6] = proj["depth"]
    per_gaussian[:, 7:10] = proj["color"]
    per_gaussian[:, 10] = gs.asset_ids(proj)
    e = bins["entries"].to(torch.int64)
    params = per_gaussian[e]                              # one gather: entry order, read front to back
    t, tile = bins["entry_tile"], bins["tile"]
    params[:, 0] -= (t % bins["tiles_x"]) * tile          # relative to the entry's tile, still in float64
    params[:, 1] -= (t // bins["tiles_x"]) * tile
    return params.to(dt), bins["boxes"][e].contiguous(), bins["tile_start"].contiguous(), bg


def rasterize(proj, width: int, height: int, background_depth=None, tile: int | None = None):
    """Drop-in for ``gaussians.rasterize``: (color (H, W, 3) premultiplied, asset_mask (H, W) = 1 - transmittance,
    depth (H, W), instance (H, W) int32).
    ``tile``: the tile size in pixels (default ``TILE_CPU`` on the CPU, ``TILE`` elsewhere)."""
    dev = proj["mean2d"].device
    tile = tile or (TILE_CPU if dev.type == "cpu" else TILE)
    if len(proj["depth"]) == 0:
        return gs.rasterize(proj, width, height, background_depth)
    if dev.type == "cpu":
        from . import tiles_cpu

        color, asset_mask, depth, instance = tiles_cpu.rasterize(proj, width, height, background_depth, tile)
    elif dev.type == "cuda":
        n_assets = int(gs.asset_ids(proj).max())
        try:
            from . import tiles_cuda
        except ImportError:  # no Triton: the reference is exact, only slower
            return gs.rasterize(proj, width, height, background_depth)
        if n_assets > MAX_ASSETS_CUDA:
            return gs.rasterize(proj, width, height, background_depth)
        bins = bin_tiles(proj, width, height, tile)
        color, asset_mask, depth, instance = tiles_cuda.composite(
            *kernel_inputs(proj, bins, width, height, background_depth), width, height, bins["tiles_x"], tile,
            n_assets)
    else:
        return gs.rasterize(proj, width, height, background_depth)
    dt = proj["mean2d"].dtype
    return (color.reshape(height, width, 3).to(dt), asset_mask.reshape(height, width).to(dt),
            depth.reshape(height, width).to(dt), instance.reshape(height, width))
