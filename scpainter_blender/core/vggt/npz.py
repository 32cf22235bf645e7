"""Reading and writing VGGT predictions files: every layout VGGT's demo (and tools around it) write, validated.

``load_predictions`` reads the named keys only (``allow_pickle=False``; newer demo files also hold
``pose_enc_list = None``, an object array that would need pickle) and returns ``vggt.VGGTPredictions``; what it
decided and dropped is in its ``report`` (``vggt.LoadReport``):

* ``extrinsic`` holding camera-to-world poses (a common mix-up): ``extrinsic_convention="auto"`` checks each
  frame's depth unprojection against ``world_points`` and refuses such a file, saying how to re-import;
  "camera_to_world" inverts on load (``core.vggt.convention``).
* VGGT's "pad" preprocessing adds white borders to make the images square: ``crop="auto"`` finds and removes
  them (or give the pixels), moving the principal point with the crop (``core.vggt.crop``).
* NaN/inf depth, confidence or world-point pixels are dropped (``valid`` masks) and counted; a frame without a
  finite pixel, or a non-finite pose or intrinsic, is refused naming the frame.

Every refusal is a ``vggt.PredictionsError`` (an InputError) naming the file and the key. ``save_predictions``
writes what VGGT's demo writes, atomically.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import os

import numpy as np

from ..geometry import cameras
from .. import files, outputs
from . import predictions as vggt, convention as vggt_convention, crop as vggt_crop
from .predictions import OPTIONAL_KEYS, REQUIRED_KEYS, PredictionsError


def load_predictions(path, world_points: bool = True, *, extrinsic_convention: str = "world_to_camera",
                     crop="none", metres_per_unit: float | None = None) -> vggt.VGGTPredictions:
    """Load and validate a VGGT ``predictions.npz``; raises PredictionsError naming the file and key.

    ``world_points=False`` skips the optional point-map arrays (half the file) when they will not be used.
    ``extrinsic_convention``: what ``extrinsic`` holds, "world_to_camera" (VGGT's, the default), "camera_to_world"
    (inverted on load), or "auto": check each frame's depth unprojection against ``world_points`` (read for the
    check even with ``world_points=False``) and refuse a file whose poses are camera-to-world or do not fit at all
    (see vggt_convention.check_extrinsic_convention). ``crop``: "none", "auto" (VGGT's white pad borders, see
    vggt_crop.detect_padding) or (left, top, right, bottom) pixels cut from every per-pixel array, the principal
    point moved with them; a bad crop is a vggt_crop.CropError. ``metres_per_unit`` (when known) only turns
    disagreements in refusals into metres.
    Pixels with NaN/inf depth, confidence or world point are dropped (``valid`` masks), counted in ``report``.
    """
    path = os.fspath(path)
    _check_convention(extrinsic_convention)
    crop = vggt_crop.parse_crop(crop, path)
    read_wp = world_points or extrinsic_convention == "auto"
    # only the named keys are read (newer demo files also hold pose_enc_list = None, a pickle: never touched);
    # read_npz refuses FIFOs and directories, pickles, broken headers and corrupt members, naming file and key
    arrays = files.read_npz(path, REQUIRED_KEYS, OPTIONAL_KEYS if read_wp else (), error=_npz_error)
    return predictions_from_arrays(arrays, path, extrinsic_convention=extrinsic_convention, crop=crop,
                                   metres_per_unit=metres_per_unit, keep_world_points=world_points)


def predictions_from_arrays(arrays, path="<arrays>", *, extrinsic_convention: str = "world_to_camera",
                            crop="none", metres_per_unit: float | None = None,
                            keep_world_points: bool = True) -> vggt.VGGTPredictions:
    """Validate a mapping of VGGT arrays (as in the .npz) into VGGTPredictions (see load_predictions)."""
    _check_convention(extrinsic_convention)
    crop = vggt_crop.parse_crop(crop, path)
    report = vggt.LoadReport(convention_requested=extrinsic_convention)
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise PredictionsError(path, missing[0], f"missing key(s) {missing}; the arrays are {sorted(arrays)}")
    arrays = {k: vggt.numeric(v, path, k) for k, v in arrays.items() if k in REQUIRED_KEYS + OPTIONAL_KEYS}
    images = _images_to_hwc(arrays["images"], path)
    S, H, W, _ = images.shape
    depth = _fit_shape(arrays["depth"], path, "depth", (S, H, W), "(S, H, W[, 1])").astype(np.float32)
    conf = _fit_shape(arrays["depth_conf"], path, "depth_conf", (S, H, W), "(S, H, W)")
    conf = conf.astype(np.float32)

    ext = _per_frame_matrices(arrays["extrinsic"], path, "extrinsic", S, ((3, 4), (4, 4)))
    _check_finite(ext, path, "extrinsic")
    ext = cameras.as_matrix4(ext)
    problem = cameras.rigid_problem(ext)
    if problem is not None:
        raise PredictionsError(path, "extrinsic", problem[1])

    intr = _per_frame_matrices(arrays["intrinsic"], path, "intrinsic", S, ((3, 3),)).copy()
    _check_finite(intr, path, "intrinsic")
    if np.any(intr[:, 0, 0] <= 0) or np.any(intr[:, 1, 1] <= 0):
        raise PredictionsError(path, "intrinsic", "focal lengths must be positive")

    skewed = ((np.abs(intr[:, 0, 1]) > 1e-9 * intr[:, 0, 0]) | (intr[:, 1, 0] != 0)
              | np.any(intr[:, 2] != [0.0, 0.0, 1.0], axis=1))
    if np.any(skewed):  # unprojection and Blender's cameras both assume none: refused, not silently ignored
        i = int(np.argmax(skewed))
        raise PredictionsError(path, "intrinsic", f"frame {i} is not [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (got "
                                                  f"{np.round(intr[i], 6).tolist()}): VGGT's intrinsics have no "
                                                  "skew, and neither have Blender's cameras")

    wp = wpc = None
    if "world_points" in arrays:
        wp = _fit_shape(arrays["world_points"], path, "world_points", (S, H, W, 3), "(S, H, W, 3)")
        wp = wp.astype(np.float32)
    if "world_points_conf" in arrays:
        wpc = _fit_shape(arrays["world_points_conf"], path, "world_points_conf", (S, H, W),
                         "(S, H, W)").astype(np.float32)

    # crop: every per-pixel array, and the principal point with them
    per_pixel = {"images": images, "depth": depth, "depth_conf": conf, "world_points": wp, "world_points_conf": wpc}
    per_pixel = vggt_crop.apply_crop(crop, {k: v for k, v in per_pixel.items() if v is not None}, intr, report,
                                     path)
    images, depth, conf = per_pixel["images"], per_pixel["depth"], per_pixel["depth_conf"]
    wp, wpc = per_pixel.get("world_points"), per_pixel.get("world_points_conf")

    # NaN/inf pixels: dropped (zeroed and masked), counted; a frame without any finite pixel is refused
    valid = _drop_nonfinite(report, path, depth, conf, ("depth", "depth_conf"), S, "depth and confidence",
                            "re-run VGGT on the clip or remove frame {i} from the file")
    wp_valid = None
    if wp is not None:
        wp_valid = _drop_nonfinite(
            report, path, wp, wpc, ("world_points", "world_points_conf"), S, "world point",
            "re-run VGGT on the clip or remove frame {i} from the file; or import with points from depth and an "
            "explicit extrinsic convention, which do not read the point map")
    if valid is not None:
        report.dropped_pixels = [int(n) for n in (~valid).reshape(S, -1).sum(axis=1)]
        report.warnings.append(f"dropped {sum(report.dropped_pixels)} pixels with NaN/inf depth or confidence "
                               f"({_per_frame(report.dropped_pixels)})")
    else:
        report.dropped_pixels = [0] * S
    if wp_valid is not None:
        n = (~wp_valid).reshape(S, -1).sum(axis=1)
        report.warnings.append(f"{int(n.sum())} world_points pixels are NaN/inf: left out of the point map and the "
                               f"convention check ({_per_frame(n)})")

    pred = vggt.VGGTPredictions(path=str(path), images=images, depth=depth, depth_conf=conf, world_to_camera=ext,
                                intrinsic_vggt=intr, world_points=wp, world_points_conf=wpc, valid=valid,
                                world_points_valid=wp_valid, report=report)
    vggt_convention.resolve_convention(pred, extrinsic_convention, metres_per_unit)
    if not keep_world_points:
        pred.world_points = pred.world_points_conf = pred.world_points_valid = None
    return pred


# --------------------------------------------------------------------------------------------------------------


def save_predictions(path, images, depth, depth_conf, extrinsic, intrinsic_vggt, world_points=None,
                     world_points_conf=None) -> None:
    """Write predictions exactly as VGGT's demo does (``np.savez``, float32, no batch axis), atomically.

    ``images`` (S, 3, H, W) or (S, H, W, 3) in [0, 1]; ``depth`` (S, H, W) is saved as (S, H, W, 1);
    ``extrinsic`` (S, 3, 4) world-to-camera; ``intrinsic_vggt`` in VGGT's pixel convention (see vggt.ours_K_to_vggt).
    """
    images = np.asarray(images, np.float32)
    if images.shape[-1] == 3 and images.shape[1] != 3:
        images = np.moveaxis(images, -1, 1)
    depth = np.asarray(depth, np.float32)
    if depth.ndim == 3:
        depth = depth[..., None]
    arrays = {"images": images, "depth": depth, "depth_conf": np.asarray(depth_conf, np.float32),
              "extrinsic": cameras.as_matrix4(extrinsic)[:, :3, :].astype(np.float32),
              "intrinsic": np.asarray(intrinsic_vggt, np.float32)}
    if world_points is not None:
        arrays["world_points"] = np.asarray(world_points, np.float32)
    if world_points_conf is not None:
        arrays["world_points_conf"] = np.asarray(world_points_conf, np.float32)
    with outputs.atomic_write(os.fspath(path)) as f:  # a file object: np.savez would add .npz to a temporary name
        np.savez(f, **arrays)


# -- checks of the arrays as read -----------------------------------------------------------------------------

def _npz_error(path, key, message):
    """``files.read_npz``'s error callback."""
    return PredictionsError(path, key, "file not found" if message == "not found" else message)


def _fit_shape(arr, path, key, target, what):
    """Reshape ``arr`` to ``target`` by dropping a leading batch axis of 1 and/or a trailing axis of 1, or (one
    frame) adding the frame axis that a squeeze of every size-1 axis removed."""
    shape = tuple(arr.shape)
    candidates = [shape]
    if len(shape) >= 1 and shape[0] == 1:
        candidates.append(shape[1:])
    for c in list(candidates):
        if len(c) >= 1 and c[-1] == 1:
            candidates.append(c[:-1])
    if target[0] == 1:
        candidates += [(1,) + c for c in list(candidates)]
    for c in candidates:
        if c == tuple(target):
            return arr.reshape(target)
    raise PredictionsError(path, key, f"expected shape {what} = {tuple(target)} (a batch axis of 1 allowed), "
                                      f"got {shape}")


def _images_to_hwc(arr, path):
    a = arr
    if a.ndim == 5:
        if a.shape[0] != 1:
            raise PredictionsError(path, "images", f"a batch of {a.shape[0]} clips is not supported; "
                                                   f"save one clip per file (shape {a.shape})")
        a = a[0]
    if a.ndim == 3:  # one frame without the frame axis
        a = a[None]
    if a.ndim != 4:
        raise PredictionsError(path, "images", f"expected (S, 3, H, W) or (S, H, W, 3), got shape {arr.shape}")
    if a.shape[-1] == 3:
        hwc = a
    elif a.shape[1] == 3:
        hwc = np.moveaxis(a, 1, -1)
    else:
        raise PredictionsError(path, "images", f"expected 3 colour channels, got shape {arr.shape}")
    if hwc.shape[0] == 0:  # every later step needs a frame: refuse here, naming the key, not in a reduction
        raise PredictionsError(path, "images", f"holds no frames (shape {arr.shape}): VGGT writes at least one")
    if hwc.shape[1] == 0 or hwc.shape[2] == 0:
        raise PredictionsError(path, "images", f"has images of {hwc.shape[2]} x {hwc.shape[1]} pixels (shape "
                                               f"{arr.shape}): nothing to place")
    if hwc.dtype == np.uint8:
        return hwc.astype(np.float32) / np.float32(255.0)
    if not np.issubdtype(hwc.dtype, np.floating):
        raise PredictionsError(path, "images", f"expected float in [0, 1] or uint8, got dtype {hwc.dtype}")
    hwc = hwc.astype(np.float32, copy=False)
    lo, hi = float(hwc.min()), float(hwc.max())
    if not (np.isfinite(lo) and np.isfinite(hi)):  # colours have no stand-in: refuse, naming where
        bad = ~np.isfinite(hwc)
        frames = np.unique(np.nonzero(bad.reshape(len(bad), -1))[0])
        raise PredictionsError(path, "images", f"{int(bad.sum())} colour values are NaN or inf (frames "
                                               f"{frames[:8].tolist()}): the images VGGT saw are finite, so the "
                                               "file was damaged after VGGT; export it again")
    if lo < -1e-3 or hi > 1.0 + 1e-3:
        raise PredictionsError(path, "images", f"float values must lie in [0, 1], found [{lo:g}, {hi:g}] "
                                               "(uint8 images are accepted as they are)")
    return np.clip(hwc, 0.0, 1.0) if lo < 0.0 or hi > 1.0 else hwc


def _check_finite(a, path, key):
    if not _all_finite(a):
        bad = ~np.isfinite(a)
        frames = np.unique(np.nonzero(bad.reshape(bad.shape[0], -1))[0])
        raise PredictionsError(path, key, f"{int(bad.sum())} values are NaN or inf (first in frame "
                                          f"{int(frames[0])}; frames {frames[:8].tolist()}): those frames "
                                          "cannot be placed; re-run VGGT on the clip or remove those frames from "
                                          "the file")


def _all_finite(a) -> bool:
    return bool(np.isfinite(a.min()) and np.isfinite(a.max()))  # NaN propagates through min/max: one cheap pass


def _check_convention(value) -> None:
    """The caller's option (an enum in every user interface): a wrong one is a programming error, ValueError."""
    if value not in ("auto",) + vggt.EXTRINSIC_CONVENTIONS:
        raise ValueError(f"extrinsic_convention must be one of {['auto', *vggt.EXTRINSIC_CONVENTIONS]}, "
                         f"got {value!r}")


def _per_frame(counts) -> str:
    """"frame 3: 12, frame 7: 1" for the frames with a non-zero count (the first 8, then "...")."""
    frames = [f"frame {i}: {int(n)}" for i, n in enumerate(counts) if n]
    return ", ".join(frames[:8]) + (", ..." if len(frames) > 8 else "")


def _per_frame_matrices(arr, path, key, S, shapes):
    a = np.asarray(arr, dtype=np.float64)
    if a.ndim == 4 and a.shape[0] == 1:
        a = a[0]
    if a.ndim == 2 and S == 1:  # one frame saved with every size-1 axis squeezed
        a = a[None]
    if a.ndim != 3 or a.shape[0] != S or a.shape[1:] not in shapes:
        want = " or ".join(f"({S}, {r}, {c})" for r, c in shapes)
        raise PredictionsError(path, key, f"expected {want}, got {np.shape(arr)}")
    return a


def _drop_nonfinite(report, path, values, confs, keys, S, what, hint):
    """Valid-pixel mask (S, H, W) or None when every pixel is finite; zeroes the bad pixels in place, counts them
    per frame in ``report`` and refuses a frame left without any finite pixel."""
    if all(_all_finite(a) for a in (values, confs) if a is not None):
        return None
    bad_v = ~np.isfinite(values)
    if bad_v.ndim == 4:
        bad_v = bad_v.any(axis=-1)
    bad_c = ~np.isfinite(confs) if confs is not None else np.zeros_like(bad_v)
    bad = bad_v | bad_c
    for key, b in zip(keys, (bad_v, bad_c)):
        counts = b.reshape(S, -1).sum(axis=1)
        if counts.any():
            report.nonfinite[key] = [int(c) for c in counts]
    n_px = bad[0].size
    for i in range(S):
        if bad[i].all():
            key = keys[0] if bad_v[i].all() or not bad_c[i].all() else keys[1]
            raise PredictionsError(path, key, f"frame {i} has no pixel with a finite {what} ({int(bad_v[i].sum())} "
                                              f"of its {n_px} {keys[0]} pixels and {int(bad_c[i].sum())} "
                                              f"{keys[1]} values are NaN or inf): {hint.format(i=i)}")
    values[bad] = 0.0
    if confs is not None:
        confs[bad] = 0.0
    return ~bad
