"""Validators for the fields of a JSON document (a job, a training clip): each checks one value and returns it in
the form the code uses, or raises ``error(path, field, message)`` naming the file and the field.

``error`` is the caller's InputError subclass (``job.JobError``, the clip reader's ``ClipError``), so one set of
rules serves every document and each reports as its own kind. No bpy, no torch.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputError

if TYPE_CHECKING:
    import os
    from collections.abc import Callable

#: A path or a name longer than this (or holding NUL) is not one
MAX_STRING = 4096
#: Every integer field lies within int64 (numpy's integers), whatever narrower bounds its own rule gives: a
#: 310-digit integer is refused by name here, not by an OverflowError deep in numpy.
INT_BOUNDS = (-2 ** 63, 2 ** 63 - 1)
#: Every entry of a matrix field (metres, pixels) is at most this in size: far beyond any street or image, and
#: far from float64's overflow when the renderer multiplies and squares them (``-1e308`` is refused by name).
MAX_MATRIX_ENTRY = 1e9


def short(value: object) -> str:
    """``repr(value)``, cut to 60 characters: what an error message quotes of a bad value (an integer of more
    digits than Python turns into text, 4,300, by its digit count)."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 1000:
        return f"an integer of about {int(value.bit_length() * 0.30103)} digits"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def matrix(value: object, path: str | os.PathLike, field: str, shape: tuple[int, int],
           error: Callable[..., Exception] = InputError) -> np.ndarray:
    """A finite float64 matrix of exactly ``shape`` (rows, columns) from nested lists, every entry at most
    ``MAX_MATRIX_ENTRY`` in size."""
    try:
        m = np.array(value, dtype=np.float64)
    except OverflowError:  # a JSON integer beyond float64 (310 digits)
        raise error(path, field, f"holds a number beyond ±{MAX_MATRIX_ENTRY:g}") from None
    except (TypeError, ValueError):
        raise error(path, field, f"expected a {shape[0]}x{shape[1]} matrix of numbers") from None
    if m.shape != shape:
        raise error(path, field, f"expected a {shape[0]}x{shape[1]} matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise error(path, field, "contains NaN or infinity")
    if np.abs(m).max() > MAX_MATRIX_ENTRY:
        raise error(path, field, f"holds a number beyond ±{MAX_MATRIX_ENTRY:g}")
    return m


def rigid(value: object, path: str | os.PathLike, field: str,
          error: Callable[..., Exception] = InputError) -> np.ndarray:
    """A 4x4 rotation + translation (rotation orthonormal to 1e-4, det > 0, last row [0, 0, 0, 1])."""
    m = matrix(value, path, field, (4, 4), error)
    R = m[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0 or np.any(m[3] != [0, 0, 0, 1]):
        raise error(path, field, "is not a rotation + translation (no scale, shear or reflection)")
    return m


def affine(value: object, path: str | os.PathLike, field: str,
           error: Callable[..., Exception] = InputError) -> np.ndarray:
    """An invertible 4x4 affine transform (|det| of the 3x3 part ≥ 1e-12, last row [0, 0, 0, 1])."""
    m = matrix(value, path, field, (4, 4), error)
    with np.errstate(over="ignore"):  # a huge scale's determinant overflows to inf: invertible all the same
        singular = abs(np.linalg.det(m[:3, :3])) < 1e-12
    if np.any(m[3] != [0, 0, 0, 1]) or singular:
        raise error(path, field, "is not an invertible affine transform (last row [0, 0, 0, 1])")
    return m


def integer(value: object, path: str | os.PathLike, field: str, lo: int | None = None, hi: int | None = None,
            error: Callable[..., Exception] = InputError) -> int:
    """A JSON integer (not a boolean, not a float) within [lo, hi] where given, and always within ``INT_BOUNDS``."""
    if isinstance(value, bool) or not isinstance(value, int) or not INT_BOUNDS[0] <= value <= INT_BOUNDS[1] or \
            (lo is not None and value < lo) or (hi is not None and value > hi):
        raise error(path, field, f"expected an integer{_within(lo, hi)}, got {short(value)}")
    return value


def _within(lo, hi) -> str:
    return "" if lo is None and hi is None else f" >= {lo}" if hi is None else f" <= {hi}" if lo is None else \
        f" in [{lo}, {hi}]"


def number(value: object, path: str | os.PathLike, field: str, lo: float | None = None, hi: float | None = None,
           error: Callable[..., Exception] = InputError) -> float:
    """A finite JSON number (not a boolean) within [lo, hi] where given, as a float (an integer beyond float64,
    310 digits, is refused like infinity)."""
    try:
        finite = isinstance(value, (int, float)) and math.isfinite(value)
    except OverflowError:  # math.isfinite converts an int to a float first
        finite = False
    if isinstance(value, bool) or not finite or (lo is not None and value < lo) or (hi is not None and value > hi):
        raise error(path, field, f"expected a number in [{lo}, {hi}], got {short(value)}")
    return float(value)


def string(value: object, path: str | os.PathLike, field: str, error: Callable[..., Exception] = InputError) -> str:
    """A non-empty string usable as a path or a name (at most ``MAX_STRING`` characters, no NUL)."""
    if not isinstance(value, str) or not value:
        raise error(path, field, f"expected a non-empty string, got {short(value)}")
    if len(value) > MAX_STRING or "\0" in value:
        raise error(path, field, f"is not a usable path or name (longer than {MAX_STRING} characters or a NUL byte)")
    return value
