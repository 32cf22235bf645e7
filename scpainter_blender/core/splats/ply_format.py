"""The PLY format as a container: the header (format, elements, typed properties), and reading elements' rows without
trusting the header's counts. The Gaussian readers (``core.splats.reader``, ``core.splats.inria``,
``core.splats.compressed``) and the mesh import's pre-check (``backend.mesh.load``) build on it.

The header ends at the first line whose only word is ``end_header`` (PLY's rule; surrounding spaces, tabs and a CR
of CRLF files are allowed, as plyfile allows them); ``comment`` and ``obj_info`` lines are free text, never
parsed, so words in them can never shift the data. Headers are read from the first ``MAX_HEADER`` bytes, at most
``MAX_HEADER_LINES`` lines. An element's rows are read only once the file is known to hold them (counts are
claims: nothing is allocated from them). Problems raise ``core.splats.gaussians.SplatsError`` naming the file and the
header line, element or property at fault.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import os
import re
from typing import TYPE_CHECKING

import numpy as np

from .gaussians import ACCEPTED, SplatsError, open_file

if TYPE_CHECKING:
    from collections.abc import Iterable
    from typing import BinaryIO

MAX_HEADER = 1 << 16        # bytes: a degree-3 INRIA header is ~1.5 KB
MAX_HEADER_LINES = 4096     # an INRIA header has 62 property lines at most; more is not a splat file
#: PLY property type -> numpy type code (both spellings PLY allows).
TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
         "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
         "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
#: numpy type code -> the PLY type name written (and named in messages).
PLY_TYPE = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint", "f4": "float",
            "f8": "double"}


def _line_error(path, n: int, message: str) -> SplatsError:
    """A header problem, named by its line (``field`` "header line N", as the message has always said)."""
    e = SplatsError(path, f"header line {n}: {message}", f"header line {n}")
    e.message = message
    return e


def _header_lines(raw: bytes, path):
    """(header lines as bytes without their line ends, offset of the first data byte).

    The header ends at the first line whose only word is ``end_header`` (PLY's rule; surrounding spaces, tabs and
    a CR of CRLF files are allowed, as plyfile allows them): a ``comment`` or ``obj_info`` line that merely
    contains the words does not end it, so it can never shift the data."""
    if raw.split(b"\n", 1)[0].strip(b" \t\r") != b"ply":
        raise SplatsError(path, f"not a PLY file (its first line is not 'ply'); accepted are {ACCEPTED}")
    lines, pos = [], 0
    while True:
        nl = raw.find(b"\n", pos)
        if nl < 0:
            if raw[pos:].strip(b" \t\r") == b"end_header":
                raise SplatsError(path, "the header ends without a newline after 'end_header' (truncated file?)")
            if len(raw) >= MAX_HEADER:
                raise SplatsError(path, f"no 'end_header' line in the first {MAX_HEADER} bytes: the header is too "
                                        "long, or this is not a PLY file")
            raise SplatsError(path, "the header has no 'end_header' line: the file is truncated or not a PLY file")
        line = raw[pos:nl]
        pos = nl + 1
        if line.split() == [b"end_header"]:
            return lines, pos
        lines.append(line)
        if len(lines) > MAX_HEADER_LINES:
            raise SplatsError(path, f"the header has more than {MAX_HEADER_LINES} lines: not a splat file")


def parse_header(raw: bytes, path: str | os.PathLike, binary_only: bool = True) -> tuple[str, list, int]:
    """(format, [[element name, count, [(property, numpy type code or None for a list)]]], data offset) of the
    header at the start of ``raw``; SplatsError naming the header line for anything malformed."""
    lines, start = _header_lines(raw, path)
    fmt, elements = None, []
    for n, raw_line in enumerate(lines[1:], start=2):
        words = raw_line.split()
        if not words or words[0] in (b"comment", b"obj_info"):
            continue  # free text: any bytes (UTF-8 names), never parsed
        try:
            line = raw_line.decode("ascii").rstrip("\r")
        except UnicodeDecodeError as e:
            raise _line_error(path, n, f"is not ASCII text (byte {e.start}: {raw_line[:60]!r})") from None
        words = line.split()
        if words[0] == "format":
            if len(words) != 3:
                raise _line_error(path, n, f"malformed format line {line!r}")
            if fmt is not None:
                raise _line_error(path, n, "a second format line")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not re.fullmatch(r"\d{1,15}", words[2]):
                raise _line_error(path, n, f"malformed element line {line!r}")
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property":
            if not elements:
                raise _line_error(path, n, "property before any element")
            if len(words) >= 2 and words[1] == "list":
                if len(words) != 5 or words[2] not in TYPES or words[3] not in TYPES:
                    raise _line_error(path, n, f"malformed list property {line!r} (expected 'property list "
                                               "<count type> <item type> <name>')")
                elements[-1][2].append((words[-1], None))
                continue
            if len(words) != 3 or words[1] not in TYPES:
                raise _line_error(path, n, f"unknown property {line!r}")
            names = [p[0] for p in elements[-1][2]]
            if words[2] in names:
                raise _line_error(path, n, f"property {words[2]!r} appears twice")
            elements[-1][2].append((words[2], TYPES[words[1]]))
        else:
            raise _line_error(path, n, f"unexpected {words[0]!r}")
    if binary_only:
        check_binary(fmt, path)
    return fmt, elements, start


def read_ply_header(path: str | os.PathLike) -> tuple[str, list, int]:
    """(format, elements, data offset) of a PLY file's header (see ``parse_header``; ASCII files included), read
    from a regular file only; SplatsError naming the file (and the header line) otherwise. For callers that only
    need to know what a PLY holds (the mesh import)."""
    path = os.fspath(path)
    try:
        with open_file(path) as f:
            raw = f.read(MAX_HEADER)
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None
    return parse_header(raw, path, binary_only=False)


def check_binary(fmt: str, path: str | os.PathLike) -> None:
    """SplatsError unless ``fmt`` (the header's format) is binary little- or big-endian."""
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        raise SplatsError(path, f"format {fmt!r} is not supported: expected binary_little_endian or "
                                "binary_big_endian (ASCII splat files are not used in practice)", "format")


def element(elements: list, name: str) -> tuple[int, list] | None:
    """The first element called ``name`` as (count, [(property, type)]), or None."""
    for e in elements:
        if e[0] == name:
            return e[1], e[2]
    return None


def read_elements(f: BinaryIO, path: str | os.PathLike, size: int, order: str, elements: list, start: int,
                  wanted: Iterable[str]) -> dict:
    """{name: structured array} of the ``wanted`` elements (first of each name) of the open binary file ``f``
    (``size`` bytes, data from byte ``start``, byte order ``order`` "<" or ">"), skipping the ones before them;
    SplatsError naming the element for list properties on the way or rows the file does not hold."""
    noun = {"vertex": "Gaussians", "chunk": "chunks", "sh": "SH rows"}
    last = max(i for i, e in enumerate(elements) if e[0] in wanted)
    out, offset = {}, start
    for name, count, props in elements[:last + 1]:
        if any(t is None for _, t in props):
            if name in wanted and name not in out:
                raise SplatsError(path, f"the {name!r} element has list properties", name)
            raise SplatsError(path, f"element {name!r} before {elements[last][0]!r} has list properties", name)
        dtype = np.dtype([(p, order + t) for p, t in props])
        need = count * dtype.itemsize
        if name in wanted and name not in out:
            if not props:
                raise SplatsError(path, f"the {name!r} element has no properties", name)
            if offset + need > size:  # checked before anything is allocated: counts are claims
                raise SplatsError(path, f"truncated: the header promises {count} {noun.get(name, name + ' rows')} "
                                        f"({need} bytes from byte {offset}) but the file has {size} bytes", name)
            f.seek(offset)
            buf = _read_exactly(f, need)
            if len(buf) != need:  # the file shrank while being read
                raise SplatsError(path, f"truncated: {len(buf)} of the {need} bytes of the {name!r} element could be "
                                        "read", name)
            out[name] = np.frombuffer(buf, dtype=dtype, count=count)
        offset += need
    return out


def _read_exactly(f, n: int) -> np.ndarray:
    """Up to ``n`` bytes of ``f`` from where it stands, as a writable uint8 array (shorter only at the end of the
    file). Read into one array rather than ``f.read(n)``: a 250 MB element reads ~6x faster this way (no bytes
    object grown and copied; bench/ply_load.py)."""
    buf = np.empty(n, np.uint8)
    got = 0
    while got < n:
        k = f.readinto(memoryview(buf)[got:])
        if not k:
            break
        got += k
    return buf[:got]


def type_name(dt: np.dtype) -> str:
    """A numpy type as messages name it: its PLY name and numpy's, e.g. "ushort (uint16)"."""
    code = dt.str[1:]
    return f"{PLY_TYPE.get(code, code)} ({dt.name})"
