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
``MAX_ASSETS_CUDA`` assets (the Triton kernel keeps one weight per pixel and asset in registers). The tile
size, and whether a frame is composited with the tiles at all or with the pair rasterizer, is
``raster_choice.choose``'s (by device and measured size; ``rasterize``' ``method`` and ``tile`` force it).

Every path also returns the instance (``gaussians.rasterize``' rule: per pixel the asset with the largest
Σ α·transmittance, ties to the lower id, where that weight exceeds the transmittance left; else 0), from each
Gaussian's asset id (``proj["asset_id"]``, 1-based; none: every Gaussian is asset 1).
"""

from __future__ import annotations

import torch

from . import gaussians as gs
from . import raster_choice

#: More assets than this in one frame: CUDA composites with the torch reference (the Triton kernel's per-pixel,
#: per-asset accumulator is a [TILE², A_PAD] block, A_PAD the next power of two ≥ the number of assets).
MAX_ASSETS_CUDA = 32
#: Rows of ``kernel_inputs``' params (F32_ROWS, stride) float32, one column per tile entry: the mean relative to
#: the entry's tile, conic, opacity, depth, colour, asset id (1-based, exact in float32 below 2^24), and the pixel
#: box as the bits of two int32 (x0 | x1 << 16, y0 | y1 << 16: one row gathers every field of an entry).
MX, MY, CA, CB, CC, OPACITY, DEPTH, RED, GREEN, BLUE, ASSET, BOX_X, BOX_Y = range(13)
F32_ROWS = 13
#: The packed boxes' limit: pixel coordinates below 2^15 (the bits of x0 | x1 << 16 stay a positive int32).
MAX_SIDE = 32767
#: Row stride alignment of params (elements): every row starts 128-byte aligned whatever the frame's
#: entry count, so Triton's alignment specialisation of the pointers never changes between frames.
STRIDE_ALIGN = 32


def bin_tiles(proj, width: int, height: int, tile: int = raster_choice.TILE_CUDA) -> dict:
    """Tile lists of projected Gaussians (see the module docstring). Returns ``boxes`` (G, 4) int32 x0 x1 y0 y1,
    ``entries`` (E,) int32 rows of ``proj`` sorted by (tile, depth rank), ``entry_tile`` (E,) int64 the tile of
    each entry, ``tile_start`` (tiles + 1,) int64, ``tiles_x``, ``tiles_y`` and ``tile``.

    On the device, without Python loops: the Gaussians in depth order (``gaussians.depth_order``), their entries
    generated in that order, then one stable sort by tile id alone (int16 keys when the tiles fit, else int32:
    half or a quarter of the radix passes of a (tile, depth) int64 key), and the tile ranges by a binary search
    of the sorted ids. One host sync: the entry count, to size the arrays."""
    dev = proj["mean2d"].device
    tiles_x, tiles_y = -(-width // tile), -(-height // tile)
    n_tiles = tiles_x * tiles_y
    G = len(proj["depth"])
    boxes = gs.pixel_boxes(proj, width, height)
    order = gs.depth_order(proj)
    tx0, tx1, ty0, ty1 = (boxes[order] // tile).unbind(1)
    tw, th = tx1 - tx0 + 1, ty1 - ty0 + 1
    counts = tw * th
    ends = torch.cumsum(counts, 0)
    n_entries = int(ends[-1]) if G else 0  # the one host sync
    rank = torch.repeat_interleave(torch.arange(G, device=dev), counts, output_size=n_entries)
    k = torch.arange(n_entries, device=dev) - (ends - counts)[rank]
    key_type = torch.int16 if n_tiles < torch.iinfo(torch.int16).max else torch.int32
    tile_id = ((ty0[rank] + k // tw[rank]) * tiles_x + tx0[rank] + k % tw[rank]).to(key_type)
    entry_tile, perm = torch.sort(tile_id, stable=True)  # entries were made in depth order: (tile, rank) order
    entries = order[rank[perm]].to(torch.int32)
    tile_start = torch.searchsorted(entry_tile, torch.arange(n_tiles + 1, device=dev, dtype=key_type))
    return {"boxes": boxes.to(torch.int32), "entries": entries, "entry_tile": entry_tile.to(torch.int64),
            "tile_start": tile_start.to(torch.int64), "tiles_x": tiles_x, "tiles_y": tiles_y, "tile": tile}


def kernel_inputs(proj, bins, width, height, background_depth, dtype=torch.float32):
    """The arrays the Triton kernel reads (``tiles_cuda``), one column per tile entry in list order, fields in
    rows so that a batch of entries is one contiguous load per field: ``params`` (F32_ROWS, S) float32 = mean x,
    mean y relative to the entry's tile origin, conic a b c, opacity, depth, r g b, the asset id (1-based,
    ``gaussians.asset_ids``; exact in float32 below 2^24), then the pixel box (``bins["boxes"]``, absolute) as the
    bits of two int32, x0 | x1 << 16 and y0 | y1 << 16 (read back with a bitcast; a gather copies bits exactly);
    ``tile_start``; the background depth (HW,). S is the entry count rounded up to ``STRIDE_ALIGN`` (the columns
    past the entries are never read). Every field but the means is one gather of a per-Gaussian table.

    Precision: the projection arrives in float64 (``frames.render_frame``); the kernel gets float32 (``dtype``)
    with means made relative to the tile in the projection's precision (values below the tile size: ~1e-6 px of
    rounding instead of ~6e-5 px at x ~ 1000, which thin, edge-on Gaussians would turn into ~1e-4 of α)."""
    if dtype != torch.float32:
        raise ValueError(f"the Triton kernel reads float32 params, not {dtype}")
    if max(width, height) > MAX_SIDE:
        raise ValueError(f"{width} x {height}: the CUDA kernel's packed pixel boxes hold sides up to {MAX_SIDE} px")
    dev, dt = proj["mean2d"].device, dtype
    bg = (torch.full((height * width,), float("inf"), dtype=dt, device=dev) if background_depth is None
          else background_depth.reshape(-1).to(dt).contiguous())
    G = len(proj["depth"])
    table = torch.empty((G, F32_ROWS), dtype=dt, device=dev)  # per Gaussian, in proj rows
    table[:, CA:BOX_X] = torch.cat([proj["conic"], proj["opacity"][:, None], proj["depth"][:, None], proj["color"],
                                    gs.asset_ids(proj)[:, None].to(proj["conic"].dtype)], 1)
    box = bins["boxes"]
    table[:, BOX_X:] = (box[:, 0::2] | (box[:, 1::2] << 16)).view(dt)  # (x0, y0) | (x1, y1) << 16, as bits
    e = bins["entries"].to(torch.int64)
    n = len(e)
    stride = max(STRIDE_ALIGN, -(-n // STRIDE_ALIGN) * STRIDE_ALIGN)
    params = torch.empty((F32_ROWS, stride), dtype=dt, device=dev)  # the columns past n are never read
    params[:, :n] = table.index_select(0, e).T               # one gather, in entry order
    t, tile, tiles_x = bins["entry_tile"], bins["tile"], bins["tiles_x"]
    m2 = proj["mean2d"][e]                                   # the projection's precision until the tile origin is off
    params[MX, :n] = m2[:, 0] - (t % tiles_x) * tile
    params[MY, :n] = m2[:, 1] - (t // tiles_x) * tile
    return params, bins["tile_start"].contiguous(), bg


def rasterize(proj, width: int, height: int, background_depth=None, tile: int | None = None,
              method: str = "auto"):
    """Drop-in for ``gaussians.rasterize``: (color (H, W, 3) premultiplied, asset_mask (H, W) = 1 - transmittance,
    depth (H, W), instance (H, W) int32). The compositor and tile size are ``raster_choice.choose``'s for this
    frame's sizes; ``method`` ("auto", "tiles", "pairs") and ``tile`` (pixels, a power of two) force them."""
    dev = proj["mean2d"].device
    G = len(proj["depth"])
    choice = raster_choice.choose(dev.type, G, width, height, method=method, tile=tile)
    if G == 0 or choice.method == "pairs":
        return gs.rasterize(proj, width, height, background_depth)
    tile = choice.tile
    if dev.type == "cpu":
        from . import tiles_cpu

        color, asset_mask, depth, instance = tiles_cpu.rasterize(proj, width, height, background_depth, tile)
    else:
        n_assets = int(gs.asset_ids(proj).max()) if "asset_id" in proj else 1
        if n_assets > MAX_ASSETS_CUDA:
            return gs.rasterize(proj, width, height, background_depth)
        try:
            color, asset_mask, depth, instance = composite_triton(proj, width, height, background_depth, tile,
                                                                  n_assets)
        except ImportError:  # no Triton: the reference is exact, only slower
            return gs.rasterize(proj, width, height, background_depth)
    dt = proj["mean2d"].dtype
    return (color.reshape(height, width, 3).to(dt), asset_mask.reshape(height, width).to(dt),
            depth.reshape(height, width).to(dt), instance.reshape(height, width))


def composite_triton(proj: dict, width: int, height: int, background_depth: torch.Tensor | None, tile: int,
                     n_assets: int, stats: dict | None = None,
                     batch: int | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The CUDA path of ``rasterize`` after the choice: binning, the kernel's inputs and the Triton kernel, on
    ``proj``'s device (CUDA; CPU tensors under Triton's interpreter, which the tests use). Returns (color (HW, 3),
    asset_mask (HW), depth (HW)) float32 and instance (HW) int32. ImportError where Triton is missing.
    ``stats``, a dict if given, receives ``entries`` (per tile list lengths, (tiles,) int64) and ``batches`` (the
    batches each tile's program composited, (tiles,) int32; ``tiles_cuda.composite``). ``batch``: the kernel's
    batch size (default: ``tiles_cuda.launch_config``'s)."""
    from . import tiles_cuda

    bins = bin_tiles(proj, width, height, tile)
    batches = torch.empty(bins["tiles_x"] * bins["tiles_y"], dtype=torch.int32, device=proj["mean2d"].device)
    out = tiles_cuda.composite(*kernel_inputs(proj, bins, width, height, background_depth), width, height,
                               bins["tiles_x"], tile, n_assets, batches=batches, batch=batch)
    if stats is not None:
        stats.update(entries=torch.diff(bins["tile_start"]), batches=batches)
    return out
