"""The GLB binary container of glTF 2.0, read into what it holds, its damage reported as values: each reader of
GLBs (``core.splats.gltf_splats``: splat glTFs; ``backend.mesh.checks``: mesh cars) keeps its own policy (what it
refuses, what it tolerates) and its own wording.

The layout (glTF 2.0 specification, §4.4 "GLB File Format Specification"), little-endian:

* a 12-byte header: the magic ``glTF``, uint32 version (2), uint32 length (the whole file's, header included);
* chunks, each an 8-byte header (uint32 length of its data, uint32 type) and its data; every chunk starts and ends
  on a 4-byte boundary (the padding, spaces after JSON and zeros after BIN, counts in its length);
* the first chunk JSON (type ``JSON_CHUNK``, UTF-8), then at most one BIN chunk (``BIN_CHUNK``), second; chunks of
  other types are skipped.

``Glb(data)`` reads the header (``Glb.problems``: what is wrong with it); chunks are read on demand, so that a
caller that looks at two chunks never walks a file of millions: ``chunks`` walks them as the specification lays
them out, ``chunk_at`` and ``next_chunk`` read one, ``problem`` says whether a chunk's data lies within the file and
the header's length, ``order_problems`` whether the JSON chunk is first and a BIN chunk second, ``data_of`` gives a
chunk's bytes. A chunk whose length is not a multiple of 4 is outside the specification; ``next_chunk`` then finds
the next one at the next 4-byte boundary (``aligned``, as the specification places it) or right at its end (as
trimesh reads a GLB).

stdlib only.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import NamedTuple

MAGIC = b"glTF"
VERSION = 2
JSON_CHUNK, BIN_CHUNK = 0x4E4F534A, 0x004E4942  # "JSON", "BIN\0" as little-endian uint32
HEADER_BYTES = 12
CHUNK_HEADER_BYTES = 8
#: The header and the first chunk's header: the fewest bytes of a GLB that holds a chunk.
MIN_BYTES = HEADER_BYTES + CHUNK_HEADER_BYTES

# Problem codes (``Problem.code``); ``claimed`` / ``bound`` say what each carries.
NOT_GLB = "not GLB"  # the file does not start with MAGIC
SHORT = "short"  # fewer than MIN_BYTES: claimed = the file's size, bound = MIN_BYTES; nothing after it is judged
BAD_VERSION = "version"  # claimed = the header's version, bound = VERSION
LENGTH_PAST_END = "length past end"  # claimed = the header's length, bound = the file's size
CHUNK_PAST_END = "chunk past end"  # claimed = the chunk's length, bound = the bytes after its header in the file
CHUNK_PAST_LENGTH = "chunk past length"  # in the file, past the header's length: bound = the bytes up to it
NO_JSON_FIRST = "no JSON first"  # claimed = the first chunk's type (None: no chunk)
BIN_OUT_OF_ORDER = "BIN out of order"  # a BIN chunk elsewhere than second: claimed = its place (0 = first)


class Problem(NamedTuple):
    """One thing wrong with a GLB: ``code`` (the constants above), ``at`` (the byte offset of the header or chunk
    at fault), ``claimed`` (what the file says there) and ``bound`` (what that is held against)."""

    code: str
    at: int = 0
    claimed: int | None = None
    bound: int | None = None


@dataclass(frozen=True)
class Chunk:
    """A chunk's header as the file gives it: ``at`` (byte offset of its 8-byte header), ``length`` (bytes of data it
    claims) and ``kind`` (its type: ``JSON_CHUNK``, ``BIN_CHUNK`` or another)."""

    at: int
    length: int
    kind: int

    @property
    def data_at(self) -> int:
        """Byte offset of its data."""
        return self.at + CHUNK_HEADER_BYTES

    @property
    def end(self) -> int:
        """Byte offset just past its data (as claimed: possibly past the file's end)."""
        return self.data_at + self.length

    @property
    def next_at(self) -> int:
        """Where the next chunk starts by the specification: ``end`` rounded up to a 4-byte boundary."""
        return self.end + (-self.length % 4)


class Glb:
    """A GLB's bytes and its header (module docstring). ``size``: the file's bytes; ``version`` and ``length`` (the
    header's; None when the file is shorter than its header); ``problems``: the header's, in the file's order."""

    def __init__(self, data: bytes) -> None:
        self.data, self.size = data, len(data)
        self.version = self.length = None
        if self.size >= HEADER_BYTES:
            self.version, self.length = struct.unpack_from("<II", data, 4)
        problems = []
        if not data.startswith(MAGIC):
            problems.append(Problem(NOT_GLB))
        if self.size < MIN_BYTES:
            problems.append(Problem(SHORT, 0, self.size, MIN_BYTES))
        else:
            if self.version != VERSION:
                problems.append(Problem(BAD_VERSION, 4, self.version, VERSION))
            if self.length > self.size:
                problems.append(Problem(LENGTH_PAST_END, 8, self.length, self.size))
        self.problems: tuple[Problem, ...] = tuple(problems)

    def chunk_at(self, at: int) -> Chunk | None:
        """The chunk whose header starts at byte ``at``; None when its 8 bytes are not all in the file."""
        if at + CHUNK_HEADER_BYTES > self.size:
            return None
        length, kind = struct.unpack_from("<II", self.data, at)
        return Chunk(at, length, kind)

    def next_chunk(self, chunk: Chunk | None = None, aligned: bool = True) -> Chunk | None:
        """The chunk after ``chunk`` (None: the first, after the header) when its header lies within the header's
        length and the file, else None. ``aligned``: at ``chunk.next_at`` (the specification), else at
        ``chunk.end`` (where trimesh reads on: the two differ only after a length that is no multiple of 4)."""
        at = HEADER_BYTES if chunk is None else chunk.next_at if aligned else chunk.end
        if self.length is None or at + CHUNK_HEADER_BYTES > self.length:
            return None
        return self.chunk_at(at)

    def chunks(self) -> Iterator[Chunk]:
        """Every chunk as the specification lays them out (``next_chunk``, aligned), first to last: each header
        within the header's length and the file (its data may run past either: ``problem``)."""
        chunk = self.next_chunk()
        while chunk is not None:
            yield chunk
            chunk = self.next_chunk(chunk)

    def problem(self, chunk: Chunk) -> Problem | None:
        """``CHUNK_PAST_END`` when ``chunk``'s data runs past the file's end, ``CHUNK_PAST_LENGTH`` when it stays in
        the file but runs past the header's length, else None."""
        if chunk.end > self.size:
            return Problem(CHUNK_PAST_END, chunk.at, chunk.length, self.size - chunk.data_at)
        if self.length is not None and chunk.end > self.length:
            return Problem(CHUNK_PAST_LENGTH, chunk.at, chunk.length, self.length - chunk.data_at)
        return None

    def data_of(self, chunk: Chunk) -> bytes:
        """``chunk``'s data (cut at the file's end)."""
        return self.data[chunk.data_at:chunk.end]


def order_problems(chunks: Sequence[Chunk]) -> list[Problem]:
    """What breaks the chunks' order (``chunks`` as ``Glb.chunks`` walks them): ``NO_JSON_FIRST`` when the first is
    not JSON (or there is none), a ``BIN_OUT_OF_ORDER`` for each BIN chunk that is not second."""
    problems = []
    if not chunks or chunks[0].kind != JSON_CHUNK:
        problems.append(Problem(NO_JSON_FIRST, chunks[0].at if chunks else HEADER_BYTES,
                                chunks[0].kind if chunks else None))
    problems += [Problem(BIN_OUT_OF_ORDER, c.at, i) for i, c in enumerate(chunks) if c.kind == BIN_CHUNK and i != 1]
    return problems
