"""CPU path of ``tiles.rasterize``: numba binning (a counting sort by tile) and compositing, parallel over tiles.

Rules and names: see ``gaussians`` (module docstring) and ``tiles``. The torch binning (``tiles.bin_tiles``) is the
reference: the lists here are identical, entry for entry (tested), and the compositing kernel reads the same
numbers and does the same operations in the same order as it did from ``tiles.kernel_inputs``' per-entry copy, so
the layers are identical too (tested: the kernel fed either list).

* Depth order: the Gaussians sorted once by (depth, original index): a stable sort of the depth, since the
  projection returns rows in ascending index (an LSD radix sort of the float64 bit patterns, ``_radix_order``).
  ``params`` (G, 8), ``colors`` (G, 3) and ``boxes`` (G, 4) hold them in that order: a Gaussian's rank is its row.
* Binning: count the entries of every tile (each Gaussian enters each tile its pixel box touches), prefix sum to
  ``tile_start``, then scatter the ranks 0, 1, 2, ... into their tiles' slots: each tile's list comes out sorted by
  depth rank without sorting the entries (``_bin``; sequential, a few ms for 10^6 entries).
* Compositing: each tile first copies its list's parameters (through the ranks) into a small buffer, then each of
  its pixels walks that buffer front to back. No per-entry copy for the whole image (``tiles.kernel_inputs``, the
  CUDA layout, cost more than the compositing itself on the CPU), and no indirection in the pixel loop (reading
  through the rank per pixel was 1.5x slower). Tiles are handed to threads dynamically, ``CHUNK_TILES`` at a time:
  an asset covers a few neighbouring tiles, which a static split would give to one thread.
  Transmittance and colour are accumulated in float64 so the 1e-4 stop decision matches the reference's float64
  log-space product; outputs are float32.
* Instance: the asset id rides in ``params``' column 7 (``_ASSET``); each pixel sums its weights per asset in a
  small float64 accumulator (one per tile, reset per pixel) and takes the first maximum; with a single asset only
  the sum is kept (the same additions), so one car costs no per-asset work.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange, set_parallel_chunksize

from . import gaussians as gs
from .gaussians import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN, pixel_boxes

CHUNK_TILES = 8  # tiles per work item of the compositing loop, handed out dynamically (measured: design note)

# columns of params (G, 8), one 64-byte row per Gaussian in depth order; colours (G, 3) apart
_DEPTH, _MX, _MY, _CA, _CB, _CC, _OPACITY, _ASSET = 0, 1, 2, 3, 4, 5, 6, 7


def depth_order(proj: dict) -> np.ndarray:
    """(G,) int64: proj rows front to back, ties by original index (``gaussians.depth_rank``'s order)."""
    depth = np.ascontiguousarray(proj["depth"].numpy(), dtype=np.float64)
    index = proj["index"].numpy()
    if len(index) > 1 and not bool(np.all(index[1:] > index[:-1])):  # not the projection's order: sort by index
        return np.lexsort((index, depth))
    if not bool(np.all(depth > 0.0)):  # the radix sort reads positive floats' bits (kept rows are beyond near > 0)
        return np.argsort(depth, kind="stable")
    return _radix_order(depth.view(np.int64))


@njit(cache=True, nogil=True)
def _radix_order(keys):
    """Stable argsort of non-negative int64 keys (positive float64 bit patterns order like the floats): LSD radix
    sort, four passes of 16 bits, each a counting sort (count, prefix sum, scatter in order). ~4x faster than
    numpy's stable argsort at 10^5 rows."""
    n = keys.shape[0]
    order = np.arange(n)
    tmp = np.empty(n, np.int64)
    count = np.empty(65537, np.int64)
    for shift in range(0, 64, 16):
        count[:] = 0
        for i in range(n):
            count[((keys[order[i]] >> shift) & 0xFFFF) + 1] += 1
        if count[1:].max() == n:  # every key has this digit: the pass would not move anything
            continue
        for d in range(65536):
            count[d + 1] += count[d]
        for i in range(n):
            d = (keys[order[i]] >> shift) & 0xFFFF
            tmp[count[d]] = order[i]
            count[d] += 1
        order, tmp = tmp, order
    return order


@njit(cache=True, nogil=True)
def _bin(boxes, tile, tiles_x, n_tiles):
    """boxes (G, 4) int32 pixel boxes in depth order -> (tile_start (n_tiles + 1,) int64, entries (E,) int32 depth
    ranks sorted by (tile, rank)): a counting sort."""
    g_count = boxes.shape[0]
    tile_start = np.zeros(n_tiles + 1, np.int64)
    for g in range(g_count):
        for ty in range(boxes[g, 2] // tile, boxes[g, 3] // tile + 1):
            for tx in range(boxes[g, 0] // tile, boxes[g, 1] // tile + 1):
                tile_start[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        tile_start[t + 1] += tile_start[t]
    fill = tile_start[:-1].copy()
    entries = np.empty(tile_start[n_tiles], np.int32)
    for g in range(g_count):  # ranks in increasing order: every list is filled front to back
        for ty in range(boxes[g, 2] // tile, boxes[g, 3] // tile + 1):
            for tx in range(boxes[g, 0] // tile, boxes[g, 1] // tile + 1):
                t = ty * tiles_x + tx
                entries[fill[t]] = g
                fill[t] += 1
    return tile_start, entries


@njit(parallel=True, cache=True, nogil=True)
def _composite(params, colors, boxes, entries, tile_start, bg, width, height, tiles_x, tile, n_assets, out_c,
               out_mask, out_z, out_inst, amodal, out_amodal):
    """Run under ``numba.set_parallel_chunksize(CHUNK_TILES)`` (``rasterize``): tiles handed out dynamically.
    ``out_inst`` (HW,) int32 must hold 0 on entry (tiles without Gaussians are not written). The instance: per
    pixel a small per-asset accumulator w[a] (``n_assets`` entries, allocated per tile, reset per pixel), then the
    first maximum; with one asset only the sum of the weights (the same additions in the same order).

    ``amodal`` (``rasterize_amodal``): also each asset's pixels as it would be alone, into ``out_amodal``
    (n_tiles, n_assets) int64, zero on entry. Per pixel and asset a the alone pass's state (its transmittance
    T_a, weight W_a, stopped) follows a's entries of the tile list, which are the alone render's list in the same
    order with the same numbers (the same rows, depth ranks and tile): the same operations give the same floats,
    without the points' depth and the other assets. W_a only grows and T_a only falls, so once W_a > T_a (the
    alone instance rule) the pixel is a's whatever follows: a's walk ends there, or at its stop, or after its last
    entry in the tile. Where the frame's own walk ends early (behind the pixel's point, or saturated) the alone
    walks still open go on from there, alone."""
    n_tiles = len(tile_start) - 1
    for t in prange(n_tiles):
        first, last = tile_start[t], tile_start[t + 1]
        if first == last:
            continue
        tx0, ty0 = (t % tiles_x) * tile, (t // tiles_x) * tile
        # the tile's list copied once into a small contiguous buffer that every pixel of the tile then reads
        n = last - first
        loc = np.empty((n, 10), np.float64)
        loc_box = np.empty((n, 4), np.int32)
        loc_asset = np.empty(n, np.int32)  # 0-based asset of each entry
        w_asset = np.empty(n_assets, np.float64)
        for j in range(n):
            k = entries[first + j]
            loc_asset[j] = np.int32(params[k, _ASSET]) - 1
            loc[j, 0] = params[k, _DEPTH]
            loc[j, 1] = params[k, _MX] - tx0  # relative to the tile, in float64 as tiles.kernel_inputs does
            loc[j, 2] = params[k, _MY] - ty0
            loc[j, 3], loc[j, 4], loc[j, 5] = params[k, _CA], params[k, _CB], params[k, _CC]
            loc[j, 6] = params[k, _OPACITY]
            loc[j, 7], loc[j, 8], loc[j, 9] = colors[k, 0], colors[k, 1], colors[k, 2]
            for c in range(4):
                loc_box[j, c] = boxes[k, c]
        # the alone passes: per asset its last entry in this tile (-1: none) and, per pixel, T_a, W_a and its state
        # (0 open, 1 stopped, 2 decided (W_a > T_a), 3 past its last entry)
        n_alone = n_assets if amodal else 0
        last = np.full(n_alone, -1, np.int64)
        t_alone = np.empty(n_alone, np.float64)
        w_alone = np.empty(n_alone, np.float64)
        state = np.empty(n_alone, np.int8)
        for j in range(n if amodal else 0):
            last[loc_asset[j]] = j
        for py in range(ty0, min(ty0 + tile, height)):
            for px in range(tx0, min(tx0 + tile, width)):
                pix = py * width + px
                trans, r, g, b, z, w_sum = 1.0, 0.0, 0.0, 0.0, np.inf, 0.0
                if n_assets > 1:
                    w_asset[:] = 0.0
                fx, fy = px - tx0 + 0.5, py - ty0 + 0.5  # tile-relative, as the means are
                zbg = bg[pix]
                n_open = 0
                for a in range(n_alone):
                    t_alone[a], w_alone[a] = 1.0, 0.0
                    state[a] = 0 if last[a] >= 0 else 3
                    n_open += last[a] >= 0
                stop = n  # the first entry the frame's walk did not take
                for e in range(n):
                    if loc[e, 0] >= zbg:
                        stop = e
                        break  # depth order: this and every later Gaussian are behind the pixel's point
                    if px < loc_box[e, 0] or px > loc_box[e, 1] or py < loc_box[e, 2] or py > loc_box[e, 3]:
                        continue
                    dx, dy = fx - loc[e, 1], fy - loc[e, 2]
                    power = -0.5 * (loc[e, 3] * dx * dx + 2.0 * loc[e, 4] * dx * dy + loc[e, 5] * dy * dy)
                    if power > 0.0:
                        continue
                    alpha = min(ALPHA_MAX, loc[e, 6] * math.exp(power))
                    if alpha < ALPHA_MIN:
                        continue
                    if amodal:
                        n_open -= _alone_step(loc_asset[e], alpha, t_alone, w_alone, state)
                    trans_next = trans * (1.0 - alpha)
                    if trans_next < TRANSMITTANCE_MIN:
                        stop = e + 1
                        break
                    w = alpha * trans
                    r += w * loc[e, 7]
                    g += w * loc[e, 8]
                    b += w * loc[e, 9]
                    if n_assets > 1:
                        w_asset[loc_asset[e]] += w
                    else:
                        w_sum += w
                    if trans > 0.5 and trans_next <= 0.5:
                        z = loc[e, 0]
                    trans = trans_next
                out_c[pix, 0], out_c[pix, 1], out_c[pix, 2] = r, g, b
                out_mask[pix] = 1.0 - trans
                out_z[pix] = z
                if n_assets > 1:
                    best = 0
                    for a in range(1, n_assets):
                        if w_asset[a] > w_asset[best]:  # strictly greater: ties keep the lower id
                            best = a
                    if w_asset[best] > trans:
                        out_inst[pix] = best + 1
                elif w_sum > trans:
                    out_inst[pix] = 1
                if not amodal:
                    continue
                for a in range(n_alone):  # open assets with no entry left after the frame's walk: done
                    if state[a] == 0 and last[a] < stop:
                        state[a] = 3
                        n_open -= 1
                for e in range(stop, n):  # the alone walks the frame's walk left open
                    if n_open == 0:
                        break
                    a = loc_asset[e]
                    if state[a] != 0:
                        continue
                    if not (px < loc_box[e, 0] or px > loc_box[e, 1] or py < loc_box[e, 2] or py > loc_box[e, 3]):
                        dx, dy = fx - loc[e, 1], fy - loc[e, 2]
                        power = -0.5 * (loc[e, 3] * dx * dx + 2.0 * loc[e, 4] * dx * dy + loc[e, 5] * dy * dy)
                        if power <= 0.0:
                            alpha = min(ALPHA_MAX, loc[e, 6] * math.exp(power))
                            if alpha >= ALPHA_MIN:
                                n_open -= _alone_step(a, alpha, t_alone, w_alone, state)
                    if state[a] == 0 and e == last[a]:
                        state[a] = 3
                        n_open -= 1
                for a in range(n_alone):
                    if last[a] >= 0 and w_alone[a] > t_alone[a]:
                        out_amodal[t, a] += 1


@njit(cache=True, nogil=True, inline="always")
def _alone_step(a, alpha, t_alone, w_alone, state):
    """One Gaussian of asset ``a`` (its α at the pixel) in a's alone pass, as the kernel composites a single asset
    with no point behind (the same operations in the same order); 1 when it closes a's walk (stopped or decided),
    else 0."""
    if state[a] != 0:
        return 0
    trans_next = t_alone[a] * (1.0 - alpha)
    if trans_next < TRANSMITTANCE_MIN:
        state[a] = 1
        return 1
    w_alone[a] += alpha * t_alone[a]
    t_alone[a] = trans_next
    if w_alone[a] > t_alone[a]:
        state[a] = 2
        return 1
    return 0


@njit(cache=True, nogil=True)
def _pack(order, depth, mean2d, conic, opacity, color, radius, asset, width, height, params, colors, boxes):
    """Row r of params / colors / boxes = proj row order[r], float64 (one sequential pass: ~1 ms for 10^5
    Gaussians, less than numba's parallel start-up), the asset id (1-based) in column ``_ASSET``. The boxes are
    ``gaussians.pixel_boxes``, the same operations in the same order (``centre_range``, then the clip)."""
    for r in range(order.shape[0]):
        i = order[r]
        params[r, _DEPTH] = depth[i]
        params[r, _MX], params[r, _MY] = mean2d[i, 0], mean2d[i, 1]
        params[r, _CA], params[r, _CB], params[r, _CC] = conic[i, 0], conic[i, 1], conic[i, 2]
        params[r, _OPACITY] = opacity[i]
        params[r, _ASSET] = asset[i]
        colors[r, 0], colors[r, 1], colors[r, 2] = color[i, 0], color[i, 1], color[i, 2]
        x0, x1 = np.ceil(mean2d[i, 0] - radius[i, 0] - 0.5), np.floor(mean2d[i, 0] + radius[i, 0] - 0.5)
        y0, y1 = np.ceil(mean2d[i, 1] - radius[i, 1] - 0.5), np.floor(mean2d[i, 1] + radius[i, 1] - 0.5)
        boxes[r, 0] = min(max(x0, 0.0), width - 1)
        boxes[r, 1] = min(max(x1, 0.0), width - 1)
        boxes[r, 2] = min(max(y0, 0.0), height - 1)
        boxes[r, 3] = min(max(y1, 0.0), height - 1)


def prepare(proj: dict, width: int, height: int, tile: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
            np.ndarray, np.ndarray, int]:
    """The kernels' inputs: (order (G,) proj rows in depth order, params (G, 8) float64 (column 7: the asset id,
    ``gaussians.asset_ids``), colors (G, 3) float64,
    boxes (G, 4) int32, all in depth order; tile_start (tiles + 1,) int64, entries (E,) int32 depth ranks; tiles_x).
    float32 projections are widened exactly to float64, as ``tiles.kernel_inputs`` did for this kernel."""
    order = depth_order(proj)
    G = len(order)
    f64 = lambda k: np.ascontiguousarray(proj[k].numpy(), dtype=np.float64)  # noqa: E731  (no copy if float64)
    params = np.empty((G, 8), np.float64)
    colors = np.empty((G, 3), np.float64)
    boxes = np.empty((G, 4), np.int32)
    asset = gs.asset_ids(proj).numpy().astype(np.float64)
    _pack(order, f64("depth"), f64("mean2d"), f64("conic"), f64("opacity"), f64("color"), f64("radius"), asset,
          width, height, params, colors, boxes)
    if proj["mean2d"].dtype != torch.float64:  # the boxes in the projection's own arithmetic, as pixel_boxes has them
        boxes[:] = pixel_boxes(proj, width, height).numpy()[order]
    tiles_x, tiles_y = -(-width // tile), -(-height // tile)
    tile_start, entries = _bin(boxes, tile, tiles_x, tiles_x * tiles_y)
    return order, params, colors, boxes, tile_start, entries, tiles_x


def bin_tiles(proj: dict, width: int, height: int, tile: int) -> dict:
    """``tiles.bin_tiles``' lists from the counting sort (for tests and the CPU path's callers): ``entries`` as rows
    of ``proj``, ``entry_tile``, ``tile_start``, ``tiles_x``, ``tiles_y``, ``tile``."""
    order, _, _, _, tile_start, entries, tiles_x = prepare(proj, width, height, tile)
    n_tiles = len(tile_start) - 1
    return {"entries": torch.from_numpy(order[entries].astype(np.int32)),
            "entry_tile": torch.from_numpy(np.repeat(np.arange(n_tiles, dtype=np.int64), np.diff(tile_start))),
            "tile_start": torch.from_numpy(tile_start), "tiles_x": tiles_x, "tiles_y": -(-height // tile),
            "tile": tile}


def rasterize(proj: dict, width: int, height: int, background_depth: torch.Tensor | None,
              tile: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``tiles.rasterize`` on CPU tensors: (color (HW, 3), asset_mask (HW) = 1 - transmittance, depth (HW)) float32
    and instance (HW) int32 (``gaussians.rasterize``' rule; T_rest is the running product of (1 - α))."""
    return _rasterize(proj, width, height, background_depth, tile, False)[:4]


def rasterize_amodal(proj: dict, width: int, height: int, background_depth: torch.Tensor | None,
                     tile: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, np.ndarray]:
    """``rasterize``'s four layers and, from the same walk, amodal (A,) int64, A = the largest asset id: for each
    asset the pixels it would be the instance of if it were rendered alone (no background depth, no other asset),
    i.e. what ``rasterize`` of its own rows of ``proj`` with no background counts as instance > 0 with the same
    ``tile``: exactly the same count (the same numbers in the same order, see ``_composite``), without rendering
    it again (``frames.amodal_pixels`` renders each asset alone)."""
    return _rasterize(proj, width, height, background_depth, tile, True)


def _rasterize(proj, width, height, background_depth, tile, amodal):
    _, params, colors, boxes, tile_start, entries, tiles_x = prepare(proj, width, height, tile)
    n_assets = int(params[:, _ASSET].max()) if len(params) else 1
    bg = (np.full(height * width, np.inf) if background_depth is None
          else np.ascontiguousarray(background_depth.reshape(-1).numpy(), dtype=np.float64))
    out_c = torch.zeros((height * width, 3), dtype=torch.float32)
    out_mask = torch.zeros(height * width, dtype=torch.float32)
    out_z = torch.full((height * width,), float("inf"), dtype=torch.float32)
    out_inst = torch.zeros(height * width, dtype=torch.int32)
    # per tile and asset (summed after): the tiles run in parallel, each writes only its own row
    out_amodal = np.zeros((len(tile_start) - 1 if amodal else 0, n_assets), np.int64)
    # dynamic scheduling: an asset fills a few neighbouring tiles, which static halves would leave to one thread
    previous = set_parallel_chunksize(CHUNK_TILES)
    try:
        _composite(params, colors, boxes, entries, tile_start, bg, width, height, tiles_x, tile, n_assets,
                   out_c.numpy(), out_mask.numpy(), out_z.numpy(), out_inst.numpy(), amodal, out_amodal)
    finally:
        set_parallel_chunksize(previous)
    return out_c, out_mask, out_z, out_inst, out_amodal.sum(0)
