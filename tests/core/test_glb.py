"""core.glb: the GLB container as the glTF 2.0 specification lays it out (header, chunks, 4-byte padding), its damage
reported as values (a truncated header, a header length past the file's end, chunks past it, a BIN chunk out of
order); and both readers built on it, the splat glTF reader (``gltf_splats.read_tree``, ``peek_tree``) and the mesh
checks (``checks._glb``), accepting and refusing those files exactly as they did before they shared it (the
expected outcomes below are what the code before ``core.glb`` gave, message, field and hint)."""

import json
import struct
from itertools import islice

import pytest

from backend.mesh import checks
from scpainter_blender.core import glb
from scpainter_blender.core.splats import gltf_splats
from scpainter_blender.core.splats.gaussians import SplatsError

TREE = {"asset": {"version": "2.0"}, "buffers": [{"byteLength": 8}]}
TEXT = json.dumps(TREE).encode()  # 61 bytes: 3 short of a 4-byte boundary
BINARY = bytes(range(8))


def _chunk(kind: int, payload: bytes, pad: bool = True, length: int | None = None) -> bytes:
    """A chunk's header and data; ``pad``: up to 4 bytes as the specification pads (JSON: spaces, else zeros)."""
    if pad:
        payload += (b" " if kind == glb.JSON_CHUNK else b"\0") * (-len(payload) % 4)
    return struct.pack("<II", len(payload) if length is None else length, kind) + payload


def _glb(*chunks: bytes, version: int = 2, length: int | None = None) -> bytes:
    body = b"".join(chunks)
    return b"glTF" + struct.pack("<II", version, 12 + len(body) if length is None else length) + body


JSON_PADDED = _chunk(glb.JSON_CHUNK, TEXT)  # 8 + 64 bytes
VALID = _glb(JSON_PADDED, _chunk(glb.BIN_CHUNK, BINARY))
UNPADDED_TEXT = TEXT + b"    "  # 65 bytes: valid JSON whose length is no multiple of 4


def test_the_specification_layout():
    g = glb.Glb(VALID)
    assert (g.size, g.version, g.length, g.problems) == (len(VALID), 2, len(VALID), ())
    json_chunk, bin_chunk = chunks = list(g.chunks())
    assert json_chunk == glb.Chunk(12, 64, glb.JSON_CHUNK) and (json_chunk.data_at, json_chunk.end) == (20, 84)
    assert bin_chunk == glb.Chunk(84, 8, glb.BIN_CHUNK) and bin_chunk.end == len(VALID) == 100
    assert g.data_of(json_chunk) == TEXT + b"   " and g.data_of(bin_chunk) == BINARY
    assert [g.problem(c) for c in chunks] == [None, None] and glb.order_problems(chunks) == []
    assert g.next_chunk(bin_chunk) is None and g.chunk_at(len(VALID) - 7) is None  # no room for a header
    assert (glb.MAGIC, glb.JSON_CHUNK, glb.BIN_CHUNK) == (b"glTF", *struct.unpack("<II", b"JSONBIN\0"))
    assert glb.MIN_BYTES == 20


def test_padding_places_the_next_chunk_on_a_4_byte_boundary():
    padded = _chunk(glb.JSON_CHUNK, UNPADDED_TEXT)  # 65 bytes padded to 68 with spaces, inside its length
    assert struct.unpack_from("<I", padded)[0] == 68 and padded.endswith(b"    ")
    # a length that is no multiple of 4 (outside the specification), then 3 bytes of padding, then BIN
    data = _glb(struct.pack("<II", 65, glb.JSON_CHUNK) + UNPADDED_TEXT + b"\0\0\0", _chunk(glb.BIN_CHUNK, BINARY))
    g = glb.Glb(data)
    first = g.next_chunk()
    assert (first.length, first.end, first.next_at) == (65, 85, 88)
    assert g.next_chunk(first) == glb.Chunk(88, 8, glb.BIN_CHUNK)  # aligned, as the specification places it
    # trimesh's place: the padding and the BIN header, read as a chunk header
    assert g.next_chunk(first, aligned=False) == glb.Chunk(85, 0x08000000, 0x42000000)
    assert [c.at for c in g.chunks()] == [12, 88]


@pytest.mark.parametrize("data, problems", [
    (b"", [(glb.NOT_GLB, 0, None, None), (glb.SHORT, 0, 0, 20)]),
    (b"glTF", [(glb.SHORT, 0, 4, 20)]),
    (VALID[:19], [(glb.SHORT, 0, 19, 20)]),
    (b"glTX" + VALID[4:], [(glb.NOT_GLB, 0, None, None)]),
    (_glb(JSON_PADDED, version=1, length=200), [(glb.BAD_VERSION, 4, 1, 2), (glb.LENGTH_PAST_END, 8, 200, 84)]),
])
def test_the_header_problems(data, problems):
    g = glb.Glb(data)
    assert g.problems == tuple(glb.Problem(*p) for p in problems)
    if len(data) < 20:
        assert list(g.chunks()) == []


def test_a_header_length_past_the_end_and_chunks_past_the_end_or_the_length():
    data = _glb(JSON_PADDED, _chunk(glb.BIN_CHUNK, BINARY, length=4000), length=5000)
    g = glb.Glb(data)
    assert g.problems == (glb.Problem(glb.LENGTH_PAST_END, 8, 5000, 100),)
    json_chunk, bin_chunk = g.chunks()  # walked up to the file's end
    assert g.problem(json_chunk) is None
    assert g.problem(bin_chunk) == glb.Problem(glb.CHUNK_PAST_END, 84, 4000, 8)
    assert g.data_of(bin_chunk) == BINARY  # cut at the file's end
    short = glb.Glb(_glb(JSON_PADDED, _chunk(glb.BIN_CHUNK, BINARY), length=96))  # the BIN chunk past the length
    assert short.problems == () and short.problem(short.chunk_at(84)) == glb.Problem(glb.CHUNK_PAST_LENGTH, 84, 8, 4)
    # a header length that ends inside the BIN chunk's header: the walk stops at the JSON chunk
    assert [c.at for c in glb.Glb(_glb(JSON_PADDED, _chunk(glb.BIN_CHUNK, BINARY), length=90)).chunks()] == [12]


def test_a_bin_chunk_out_of_order():
    other = _chunk(0x1234, b"abcd")
    third = glb.Glb(_glb(JSON_PADDED, other, _chunk(glb.BIN_CHUNK, BINARY)))
    assert [c.kind for c in third.chunks()] == [glb.JSON_CHUNK, 0x1234, glb.BIN_CHUNK]
    assert glb.order_problems(list(third.chunks())) == [glb.Problem(glb.BIN_OUT_OF_ORDER, 96, 2)]
    first = glb.Glb(_glb(_chunk(glb.BIN_CHUNK, BINARY), JSON_PADDED))
    assert glb.order_problems(list(first.chunks())) == [glb.Problem(glb.NO_JSON_FIRST, 12, glb.BIN_CHUNK),
                                                        glb.Problem(glb.BIN_OUT_OF_ORDER, 12, 0)]
    assert glb.order_problems([]) == [glb.Problem(glb.NO_JSON_FIRST, 12, None)]


def test_chunks_are_read_on_demand():
    """A file of a million empty chunks: two of them cost two reads, not a walk of the file."""
    data = _glb(JSON_PADDED, _chunk(0x99, b"") * 1_000_000)
    walk = glb.Glb(data).chunks()
    assert [c.at for c in islice(walk, 3)] == [12, 84, 92]


# -- both callers, before and after: what the code before core.glb gave on these files ---------------------------

MESH_HINT_GLB, MESH_HINT_COPY = "export the car again as GLB", "copy or export the file again"
CASES = {
    "valid": VALID,
    "truncated header": VALID[:19],
    "length past the end": _glb(JSON_PADDED, _chunk(glb.BIN_CHUNK, BINARY), length=5000),
    "length below 20": _glb(JSON_PADDED, _chunk(glb.BIN_CHUNK, BINARY), length=12),
    "BIN past the end": _glb(JSON_PADDED, _chunk(glb.BIN_CHUNK, BINARY, length=4000)),
    "BIN past the length": _glb(JSON_PADDED, _chunk(glb.BIN_CHUNK, BINARY), length=96),
    "BIN third": _glb(JSON_PADDED, _chunk(0x1234, b"abcd"), _chunk(glb.BIN_CHUNK, BINARY)),
    "BIN first": _glb(_chunk(glb.BIN_CHUNK, BINARY), JSON_PADDED),
    "version 1": _glb(JSON_PADDED, version=1),
    "JSON unpadded, BIN at its end": _glb(_chunk(glb.JSON_CHUNK, UNPADDED_TEXT, pad=False),
                                          _chunk(glb.BIN_CHUNK, BINARY)),
    "JSON unpadded, BIN aligned": _glb(struct.pack("<II", 65, glb.JSON_CHUNK) + UNPADDED_TEXT + b"\0\0\0",
                                       _chunk(glb.BIN_CHUNK, BINARY)),
}
#: gltf_splats.read_tree: ("ok", BIN chunk) or (message, field); peek_tree gives the same tree or error except where
#: PEEK says otherwise (it reads the JSON chunk alone)
SPLAT = {
    "valid": ("ok", BINARY),
    "truncated header": ("a GLB shorter than its 20-byte header: truncated", "header"),
    "length past the end": ("ok", BINARY),
    "length below 20": ("a GLB without its JSON chunk first", "chunks"),
    "BIN past the end": ("GLB chunk at byte 84 claims 4,000 bytes, the file ends at 100: truncated", "chunks"),
    "BIN past the length": ("ok", BINARY),
    "BIN third": ("ok", BINARY),
    "BIN first": ("a GLB without its JSON chunk first", "chunks"),
    "version 1": ("GLB version 1: only glTF 2.0 is read", "header"),
    "JSON unpadded, BIN at its end": ("GLB chunk at byte 88 claims 1,313,423,872 bytes, the file ends at 101: "
                                      "truncated", "chunks"),
    "JSON unpadded, BIN aligned": ("ok", BINARY),
}
PEEK = {"BIN past the end": "ok", "JSON unpadded, BIN at its end": "ok"}
#: checks._glb: ("ok", BIN length, BIN offset) or (field, message, hint)
MESH = {
    "valid": ("ok", 8, 92),
    "truncated header": ("(file)", "is not a GLB file (no 'glTF' header)", MESH_HINT_GLB),
    "length past the end": ("(file)", "the GLB header promises 5,000 bytes but the file has 100: truncated",
                            MESH_HINT_COPY),
    "length below 20": ("(file)", "the GLB's first chunk is not a JSON chunk of 64 bytes within the file",
                        MESH_HINT_GLB),
    "BIN past the end": ("(file)", "the GLB's BIN chunk promises 4,000 bytes but only 8 follow: truncated",
                         MESH_HINT_COPY),
    "BIN past the length": ("(file)", "the GLB's BIN chunk promises 8 bytes but only 4 follow: truncated",
                            MESH_HINT_COPY),
    "BIN third": ("ok", None, None),
    "BIN first": ("(file)", "the GLB's first chunk is not a JSON chunk of 8 bytes within the file", MESH_HINT_GLB),
    "version 1": ("(file)", "is GLB version 1; only glTF 2.0 is read", "export the car again as glTF 2.0"),
    "JSON unpadded, BIN at its end": ("ok", 8, 93),
    "JSON unpadded, BIN aligned": ("ok", None, None),
}


class _MeshError(Exception):
    pass


def _splat_outcome(fn):
    try:
        tree, bin_chunk = fn()
    except SplatsError as e:
        return e.message, e.field
    assert tree == TREE
    return "ok", bin_chunk


@pytest.mark.parametrize("name", CASES)
def test_the_splat_reader_reads_each_file_as_before(name, tmp_path):
    path = tmp_path / "car.glb"
    path.write_bytes(CASES[name])
    assert _splat_outcome(lambda: gltf_splats.read_tree(path, CASES[name])) == SPLAT[name]
    assert _splat_outcome(lambda: gltf_splats.read_tree(path)) == SPLAT[name]
    peeked = _splat_outcome(lambda: (gltf_splats.peek_tree(path), None))
    assert peeked == (("ok", None) if PEEK.get(name, SPLAT[name][0]) == "ok" else SPLAT[name])


@pytest.mark.parametrize("name", CASES)
def test_the_mesh_checks_read_each_file_as_before(name):
    try:
        tree, bin_len, bin_at = checks._glb("car.glb", CASES[name], lambda *a: _MeshError(*a))
    except _MeshError as e:
        assert e.args == MESH[name]
    else:
        assert tree == TREE and ("ok", bin_len, bin_at) == MESH[name]
        if bin_len is not None:
            assert CASES[name][bin_at:bin_at + bin_len] == BINARY
