"""3D Gaussian splats as values: the raw numbers a file holds (``GaussianPly``), the decoded Gaussians
(``Gaussians``), decoding and encoding between them, and their view-dependent colour (SH 0-3).

``GaussianPly`` holds what an INRIA file would (graphdeco-inria/gaussian-splatting ``scene/gaussian_model.py``,
``save_ply``), whatever layout it was read from, so decoding and everything downstream is one path:

* ``opacity`` is a logit (decoded with a sigmoid), ``scale`` are natural logs (decoded with exp),
* ``rot`` is a quaternion (w, x, y, z), not necessarily unit (decoded by normalising),
* ``f_rest`` holds SH degree d >= 1 coefficients channel-major: M = 3 ((d+1)^2 - 1), first all of red's
  coefficients 1..K-1, then green's, then blue's. Colour = max(0.5 + Σ_k SH_k(dir) c_k, 0), dir = normalise(mean -
  camera centre) (``sh_to_rgb``; the constants and the basis are ``core.splats.sh``'s).

Raw values are kept apart from decoded ones so that write -> read is bit-exact. Rows with NaN/inf, zero
quaternions or scales that overflow are dropped on decoding and counted, never passed on.

The files (``GaussianPly.format`` says which layout a file had, ``FORMAT_NAMES`` its human name):

* ``core.splats.formats``: one record per file format (key, names, extensions, reader), whence ``FORMAT_NAMES``
  and ``ACCEPTED``;
* ``core.splats.reader``: ``read(path)`` for any accepted file (by content, or ``.splat`` by extension),
  ``load(path) = decode(read(path))``, ``read_ply``, and telling mesh files from Gaussian ones (``is_mesh``);
* ``core.splats.ply_format``: the PLY container (header, elements, property types) every PLY reader here uses;
* ``core.splats.inria``: the INRIA layout (float, double or half floats; TRELLIS/Amodal3R too) and ``write_ply``;
* ``core.splats.compressed``: SuperSplat compressed PLY and antimatter15 ``.splat`` (``write_splat``);
* ``core.splats.spz``, ``core.splats.ksplat``, ``core.splats.gltf_splats``: Niantic SPZ, GaussianSplats3D
  ``.ksplat``, glTF ``KHR_gaussian_splatting``;
* ``core.splats.trellis``: TRELLIS/Amodal3R files: their axes (``ZUP_TO_TRELLIS_FILE``) and ``detect_axes``.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .. import errors, files
from . import formats as _formats, sh as _sh

if TYPE_CHECKING:
    from typing import BinaryIO

# Human names of ``GaussianPly.format`` values (import reports) and what the readers accept (messages): made from
# the format records (core.splats.formats), kept importable from here.
FORMAT_NAMES, ACCEPTED = _formats.FORMAT_NAMES, _formats.ACCEPTED


class SplatsError(errors.InputError):
    """A Gaussian file that cannot be used; the message names the file and what is wrong. ``field``: the property,
    element or "header line N" at fault ("(file)" for the file as a whole)."""

    def __init__(self, path: str | os.PathLike, message: str, field: str | None = None,
                 hint: str | None = None) -> None:
        errors.InputError.__init__(self, path, field, message, hint)
        self.args = (f"{os.path.basename(self.path)}: {message} ({self.path})",)  # the text it has always had


def num_sh_coefficients(degree: int) -> int:
    """Coefficients per colour channel of SH degree ``degree``: (degree + 1)²."""
    return (degree + 1) ** 2


@dataclass
class GaussianPly:
    """Raw per-Gaussian values as an INRIA file holds them (float32), N rows.

    ``f_rest`` is (N, 3, K - 1): channel-major, as in the file. ``extra`` keeps any other vertex properties
    (normals, per-splat labels...) in file order so a rewrite loses nothing; decoding ignores them.
    ``format`` is the layout the values came from (a key of ``FORMAT_NAMES``); ``properties`` the file's vertex
    property names in file order (empty when not read from a PLY vertex element).
    """

    xyz: np.ndarray
    f_dc: np.ndarray
    f_rest: np.ndarray
    opacity: np.ndarray
    scale: np.ndarray
    rot: np.ndarray
    extra: dict = field(default_factory=dict)
    format: str = "inria"
    properties: tuple = ()

    def __len__(self):
        return len(self.xyz)

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.f_rest.shape[2] + 1))) - 1


@dataclass
class Gaussians:
    """Decoded Gaussians in the file's object frame.

    ``means`` (N, 3); ``scales`` (N, 3) standard deviations along the local axes; ``quats`` (N, 4) unit (w, x, y, z);
    ``opacities`` (N,) in [0, 1]; ``sh`` (N, K, 3) coefficient-major (``sh[:, 0]`` is the DC term). All float32.
    ``dropped`` counts the rows left out on decoding, by reason.
    """

    means: np.ndarray
    scales: np.ndarray
    quats: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    dropped: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.means)

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.sh.shape[1]))) - 1

    def base_colors(self) -> np.ndarray:
        """View-independent colour (the DC term only), (N, 3) in [0, ...)."""
        return dc_colors(self.sh[:, 0])

    def extents(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (min (3,), max (3,)) of the means; zeros for an empty set."""
        if not len(self):
            return np.zeros(3), np.zeros(3)
        return self.means.min(axis=0).astype(np.float64), self.means.max(axis=0).astype(np.float64)


def _file_error(path, field, message):
    """``files``' error callback: its "not found" / "is a FIFO ..." messages as SplatsError."""
    return SplatsError(path, "file not found" if message == "not found" else message, field)


def open_file(path: str | os.PathLike) -> BinaryIO:
    """``path`` opened for binary reading if it is a regular file (a FIFO or a directory is refused at once, not
    waited on); SplatsError naming the file otherwise."""
    return files.open_regular(path, _file_error)


def read_bytes(path: str | os.PathLike) -> bytes:
    """The whole of a regular file (``open_file``'s checks); SplatsError naming the file if it cannot be read. For
    the formats read whole (SPZ's gzip stream, ``.ksplat``, glTF): their headers size everything else."""
    try:
        with open_file(path) as f:
            return f.read()
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None


# --------------------------------------------------------------------------------------------------------------
# Decoding and encoding
# --------------------------------------------------------------------------------------------------------------

# The activations, one formula each: decode uses them, and so does the Blender import (scene/gaussians.py), which
# keeps the raw values beside the decoded ones.

def opacities_from_logits(logit: np.ndarray) -> np.ndarray:
    """Opacities in [0, 1] (float64) of raw logits (N,): the sigmoid."""
    return 1.0 / (1.0 + np.exp(-np.asarray(logit).astype(np.float64)))


def scales_from_logs(log_scale: np.ndarray) -> np.ndarray:
    """Standard deviations (float64) of raw natural-log scales (N, 3): exp."""
    return np.exp(np.asarray(log_scale).astype(np.float64))


def unit_quaternions(rot: np.ndarray) -> np.ndarray:
    """Unit (w, x, y, z) quaternions (N, 4) float64 of raw ones; a zero quaternion gives NaN (decode drops it)."""
    q = np.asarray(rot).astype(np.float64)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def sh_coefficients(f_dc: np.ndarray, f_rest: np.ndarray) -> np.ndarray:
    """SH coefficients (N, K, 3) coefficient-major (``[:, 0]`` is the DC term) of raw f_dc (N, 3) and channel-major
    f_rest (N, 3, K - 1); the input dtype is kept."""
    return np.concatenate([np.asarray(f_dc)[:, None, :], np.swapaxes(f_rest, 1, 2)], axis=1)


def dc_colors(f_dc: np.ndarray) -> np.ndarray:
    """View-independent colour (N, 3) float32 in [0, ...) of DC coefficients (N, 3): max(SH_C0 · f_dc + 0.5, 0)."""
    return np.maximum(_sh.SH_C0 * np.asarray(f_dc) + 0.5, 0.0).astype(np.float32)


def decode(ply: GaussianPly) -> Gaussians:
    """Activate raw values: exp scales, sigmoid opacity, normalised quaternions; drop and count bad rows.

    A row is dropped for any NaN/inf among its used values ("non_finite"), a quaternion shorter than 1e-12
    ("zero_quaternion"), a scale whose exp overflows float32 ("scale_overflow"), or a position or σ beyond
    ``ABSURD_M`` ("absurd": bytes of something else read as floats, 1e30 m, not a car).
    """
    with np.errstate(invalid="ignore", over="ignore"):  # bad rows are expected here: they are counted below
        return _decode(ply)


def valid_rows(ply: GaussianPly) -> tuple[np.ndarray, dict]:
    """(keep mask (N,), dropped counts by reason) — the rows decode() keeps."""
    keep, dropped, _, _ = _checked(ply)
    return keep, dropped


#: metres: a Gaussian whose |position| (any axis) or σ exceeds this is no part of a car or a street but bytes of
#: something else read as floats (a header, compressed data, a converter's garbage): ``decode`` drops it
#: ("absurd"), as it drops NaN rows, rather than drawing a Gaussian that covers every frame. Far beyond any scene
#: the project takes (coordinates to 1e5 m are tested).
ABSURD_M = 1e6

#: The opacity below which the renderer skips a Gaussian (gsplat's 1/255: a Gaussian culled before projection, and
#: a pixel's alpha below it not composited; ``backend.render.gaussians`` imports it): here so that the input check
#: counts the Gaussians that would never be drawn with the renderer's own cut.
ALPHA_MIN = 1.0 / 255.0

#: An asset of which more than this share of Gaussians is dropped on decoding (``decode``'s reasons), or more than
#: this share is never drawn (opacity below ``ALPHA_MIN``), is used with a ``warning`` event (code
#: ``INVALID_GAUSSIANS``, ``TRANSPARENT_ASSET``): what is left is likely a broken car (a converter's bad output);
#: none left to draw is refused (``asset_verdict``).
MOSTLY_INVALID_SHARE = 0.5
#: The ``warning`` event's code for an asset mostly made of invalid Gaussians.
INVALID_GAUSSIANS = "invalid_gaussians"
#: The ``warning`` event's code for an asset mostly made of Gaussians below ``ALPHA_MIN`` (never drawn).
TRANSPARENT_ASSET = "transparent_asset"
#: How the reasons ``decode`` counts read in a message.
DROPPED_REASONS = {"non_finite": "with NaN or infinite values", "zero_quaternion": "with a zero quaternion",
                    "scale_overflow": "with a scale beyond float32",
                    "absurd": f"with a position or σ beyond {ABSURD_M:g} m"}
#: What to do about a file of invalid Gaussians.
INVALID_HINT = ("export or convert the asset again (its Gaussians must have finite values, non-zero quaternions and "
                "scales within float32), or point the job at another file")
#: What to do about a file whose Gaussians are (nearly) all too transparent to be drawn.
TRANSPARENT_HINT = ("export or convert the asset again with its opacities (a file holds them as logits: the opacity "
                    "drawn is sigmoid(opacity), and one below 1/255 is never drawn), or point the job at another file")


def transparent_rows(ply: GaussianPly, keep: np.ndarray) -> int:
    """How many of the rows ``keep`` (``valid_rows``' mask) have an opacity the renderer never draws: sigmoid of the
    logit, in float32 as ``decode`` gives it, below ``ALPHA_MIN``."""
    with np.errstate(over="ignore"):  # exp(-logit) of a very negative logit overflows to inf: opacity 0, as decoded
        opacity = opacities_from_logits(np.asarray(ply.opacity)[keep]).astype(np.float32)
    return int(np.count_nonzero(opacity < ALPHA_MIN))


@dataclass
class AssetVerdict:
    """What an asset's Gaussians mean for a render (``asset_verdict``): ``refused`` (nothing would be drawn) or a
    warning; ``text`` says how many and why, ``code`` the warning event's code, ``hint`` what to do."""
    refused: bool
    text: str
    code: str
    hint: str


def asset_verdict(total: int, dropped: dict, transparent: int = 0) -> AssetVerdict | None:
    """What an asset's Gaussians mean for a render, from ``total`` rows, ``valid_rows``' (or ``Gaussians.dropped``'s)
    counts by reason and ``transparent``: how many valid rows are below ``ALPHA_MIN`` (``transparent_rows``).
    None when at most ``MOSTLY_INVALID_SHARE`` is dropped and at most that share is transparent. Refused when
    nothing would be drawn: an empty file, none valid ("none of its 300 Gaussians is valid (300 with a zero
    quaternion)"), or every valid one transparent ("none of its 300 Gaussians would be drawn (300 with an opacity
    below 1/255)"); a warning (``INVALID_GAUSSIANS`` before ``TRANSPARENT_ASSET``) when more than the share is."""
    bad = sum(dropped.values())
    if total == 0:
        return AssetVerdict(True, "holds no Gaussians", INVALID_GAUSSIANS, INVALID_HINT)
    why = ", ".join(f"{n:,} {DROPPED_REASONS.get(k, k)}" for k, n in dropped.items())
    if bad == total:
        return AssetVerdict(True, f"none of its {total:,} Gaussians is valid ({why})", INVALID_GAUSSIANS,
                            INVALID_HINT)
    below = f"{transparent:,} with an opacity below 1/255, which the renderer never draws"
    if bad + transparent == total:
        return AssetVerdict(True, f"none of its {total:,} Gaussians would be drawn ({below}"
                                  f"{', ' + why if why else ''}): the car would be invisible",
                            TRANSPARENT_ASSET, TRANSPARENT_HINT)
    left = f"the car is drawn from the {total - bad - transparent:,} left"
    if bad > MOSTLY_INVALID_SHARE * total:
        return AssetVerdict(False, f"{bad:,} of its {total:,} Gaussians are invalid ({why}) and left out: more than "
                                   f"{MOSTLY_INVALID_SHARE:.0%}; {left}", INVALID_GAUSSIANS, INVALID_HINT)
    if transparent > MOSTLY_INVALID_SHARE * total:
        return AssetVerdict(False, f"{transparent:,} of its {total:,} Gaussians have an opacity below 1/255 and are "
                                   f"never drawn: more than {MOSTLY_INVALID_SHARE:.0%}; {left}",
                            TRANSPARENT_ASSET, TRANSPARENT_HINT)
    return None


def _finite_rows(a) -> np.ndarray | None:
    """Rows of ``a`` (N, ...) without NaN/inf; None when every row is finite.

    Checked first with one float32 sum over the whole array: a finite sum proves every term finite (NaN and inf
    never give a finite sum again), in a fraction of the per-row test; a non-finite sum (a bad value, or only an
    overflow of the sum) falls back to the exact per-row test, so the answer never depends on the shortcut."""
    if np.isfinite(np.sum(a, dtype=np.float32)):
        return None
    return np.isfinite(a).reshape(len(a), -1).all(1)


def _checked(ply: GaussianPly):
    """(keep (N,), dropped counts, |rot| (N, 1) float64, exp(scale) (N, 3) float64): the row checks, with the
    quaternion norms and exponentiated scales they compute kept for decoding (the same values ``unit_quaternions``
    and ``scales_from_logs`` give: each row's result depends on that row alone)."""
    with np.errstate(invalid="ignore", over="ignore"):
        finite = np.ones(len(ply), bool)
        for a in (ply.xyz, ply.f_dc, ply.f_rest, ply.opacity, ply.scale, ply.rot):
            rows = _finite_rows(a)
            if rows is not None:
                finite &= rows
        norm = np.linalg.norm(np.asarray(ply.rot).astype(np.float64), axis=1, keepdims=True)
        zero_q = finite & (norm[:, 0] < 1e-12)
        exp_scale = np.exp(np.asarray(ply.scale).astype(np.float64))
        overflow = finite & ~zero_q & ~(exp_scale <= np.finfo(np.float32).max).all(1)
        absurd = finite & ~zero_q & ~overflow & ~_within(np.asarray(ply.xyz), exp_scale)
    dropped = {"non_finite": int(len(ply) - finite.sum()), "zero_quaternion": int(zero_q.sum()),
               "scale_overflow": int(overflow.sum()), "absurd": int(absurd.sum())}
    return finite & ~zero_q & ~overflow & ~absurd, {k: v for k, v in dropped.items() if v}, norm, exp_scale


def _within(xyz, exp_scale) -> np.ndarray:
    """Rows (N,) whose |position| and σ are all within ``ABSURD_M`` (NaN rows count as within: ``_checked`` drops
    them as non-finite). One max per array first: nearly every file is within, and then no per-row test is run (a
    NaN makes the max NaN, which is not within: the per-row test then decides)."""
    if len(xyz) == 0 or (np.abs(xyz).max() <= ABSURD_M and exp_scale.max() <= ABSURD_M):
        return np.ones(len(xyz), bool)
    return ~((np.abs(xyz) > ABSURD_M).any(1) | (exp_scale > ABSURD_M).any(1))


def _decode(ply: GaussianPly) -> Gaussians:
    # The same formulas as opacities_from_logits / scales_from_logs / unit_quaternions / sh_coefficients, computed
    # once over all rows (the checks already needed the norms and exponentials), and rows masked only when some are
    # dropped: the values are the same bits, the time about a third (bench/ply_load.py).
    keep, dropped, norm, exp_scale = _checked(ply)
    xyz, f_dc, f_rest, opacity, rot = ply.xyz, ply.f_dc, ply.f_rest, ply.opacity, ply.rot
    if not keep.all():
        xyz, f_dc, f_rest, opacity, rot = xyz[keep], f_dc[keep], f_rest[keep], opacity[keep], rot[keep]
        norm, exp_scale = norm[keep], exp_scale[keep]
    sh = np.empty((len(f_dc), 1 + f_rest.shape[2], 3), np.float32)
    sh[:, 0] = f_dc
    sh[:, 1:] = np.swapaxes(f_rest, 1, 2)
    return Gaussians(means=xyz if len(xyz) != len(ply) else xyz.copy(), scales=exp_scale.astype(np.float32),
                     quats=(np.asarray(rot).astype(np.float64) / norm).astype(np.float32),
                     opacities=opacities_from_logits(opacity).astype(np.float32), sh=sh, dropped=dropped)


def encode(g: Gaussians, extra: dict | None = None) -> GaussianPly:
    """Raw file values of decoded Gaussians: log scales, logit opacity (clamped to (1e-7, 1 - 1e-7))."""
    o = np.clip(g.opacities.astype(np.float64), 1e-7, 1 - 1e-7)
    return GaussianPly(xyz=g.means.astype(np.float32), f_dc=g.sh[:, 0].astype(np.float32),
                       f_rest=np.swapaxes(g.sh[:, 1:], 1, 2).astype(np.float32),
                       opacity=np.log(o / (1 - o)).astype(np.float32),
                       scale=np.log(np.maximum(g.scales.astype(np.float64), 1e-30)).astype(np.float32),
                       rot=g.quats.astype(np.float32), extra=dict(extra or {}))


# --------------------------------------------------------------------------------------------------------------
# Spherical harmonics
# --------------------------------------------------------------------------------------------------------------

def sh_basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """Real SH basis values (N, (degree+1)^2) at unit directions (N, 3), in the 3DGS ordering and signs."""
    d = np.asarray(dirs, np.float64)
    terms = _sh.basis(d[:, 0], d[:, 1], d[:, 2], degree)  # core.splats.sh: the one formula (the renderer's too)
    return np.stack([np.broadcast_to(np.asarray(t, np.float64), (len(d),)) for t in terms], axis=1)


def sh_to_rgb(sh: np.ndarray, dirs: np.ndarray, degree: int | None = None) -> np.ndarray:
    """Colour (N, 3) = max(0.5 + Σ_k basis_k(dir) sh_k, 0) for unit view directions (N, 3).

    ``dirs`` point from the camera to the Gaussian (normalise(mean - camera centre)), in the Gaussians' frame.
    ``degree`` below the data's own uses only the first coefficients.
    """
    sh = np.asarray(sh)
    degree = int(round(np.sqrt(sh.shape[1]))) - 1 if degree is None else degree
    K = num_sh_coefficients(degree)
    if K > sh.shape[1]:
        raise ValueError(f"SH degree {degree} needs {K} coefficients, the data has {sh.shape[1]}")
    B = sh_basis(dirs, degree)
    return np.maximum(np.einsum("nk,nkc->nc", B, sh[:, :K].astype(np.float64)) + 0.5, 0.0)
