"""core.splats.reader: one entry point (read/load by content, .splat by extension), meshes told apart, other files
naming the accepted formats, FIFOs and folders refused at once, real files, and a fuzz test."""

import os
import re
import time

import numpy as np
import pytest

from tests.core.splats import splat_fixtures as F
from tests_support import realdata
from scpainter_blender.core.splats import (
    ply_format,
    gaussians as splats,
    compressed as splats_compressed,
    inria as splats_inria,
    reader as splats_io,
    trellis,
)


def test_read_dispatches_by_content(tmp_path):
    src = F.random_ply(N=30, degree=2)
    splats_inria.write_ply(tmp_path / "scene.bin", src)  # a PLY under another name is still a PLY
    assert splats_io.read(tmp_path / "scene.bin").format == "inria"
    F.assert_raw_equal(splats_io.read(tmp_path / "scene.bin"), src)
    F.write_compressed(tmp_path / "c.ply", F.random_gaussians(30, 0, seed=1))
    assert splats_io.read(tmp_path / "c.ply").format == "supersplat_compressed"
    splats_compressed.write_splat(tmp_path / "s.splat", splats.decode(F.random_gaussians(30, 0, seed=1)))
    assert splats_io.read(tmp_path / "s.splat").format == "splat"
    assert set(splats.FORMAT_NAMES) == {"inria", "inria_half", "supersplat_compressed", "splat", "spz", "ksplat",
                                        "gltf_splats", "sog"}
    with pytest.raises(splats.SplatsError, match="not found"):
        splats_io.read(tmp_path / "nope.splat")


def test_mesh_ply_is_told_to_import_as_a_mesh(tmp_path):
    xyz = np.random.default_rng(0).normal(0, 1, (4, 3))
    F.write_typed_ply(tmp_path / "mesh.ply", [(k, "double", xyz[:, i]) for i, k in enumerate("xyz")],
                      faces=[[0, 1, 2], [0, 2, 3]])
    with pytest.raises(splats.SplatsError, match=r"mesh\.ply: looks like a mesh without Gaussian properties.*2 faces"
                                                 r".*import it as a mesh asset \(\.glb/\.obj/\.ply mesh\)"):
        splats_io.read(tmp_path / "mesh.ply")
    assert splats_io.is_mesh_ply(tmp_path / "mesh.ply")
    splats_inria.write_ply(tmp_path / "g.ply", F.random_ply(N=5))
    assert not splats_io.is_mesh_ply(tmp_path / "g.ply") and not splats_io.is_mesh_ply(tmp_path / "nope.ply")
    F.write_typed_ply(tmp_path / "points.ply", [(k, "float", xyz[:, i]) for i, k in enumerate("xyz")]
                      + [(c, "uchar", np.zeros(4, np.uint8)) for c in ("red", "green", "blue")])
    with pytest.raises(splats.SplatsError, match="looks like a mesh without Gaussian properties"):
        splats_io.read(tmp_path / "points.ply")
    assert not splats_io.is_mesh_ply(tmp_path / "points.ply")  # no faces: nothing to convert
    ascii_mesh = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    (tmp_path / "ascii_mesh.ply").write_text(ascii_mesh)
    assert splats_io.is_mesh_ply(tmp_path / "ascii_mesh.ply")
    with pytest.raises(splats.SplatsError, match=r"ascii_mesh\.ply: looks like a mesh.*1 faces"):
        splats_io.read(tmp_path / "ascii_mesh.ply")


def test_real_trellis_mesh_ply_and_glb():
    mesh = realdata("trellis/trellis_assets_T_mesh.ply")
    with pytest.raises(splats.SplatsError, match=r"trellis_assets_T_mesh\.ply: looks like a mesh .*53789 vertices "
                                                 r"\(x y z\) and 61402 faces.*import it as a mesh asset"):
        splats_io.load(mesh)
    assert splats_io.is_mesh_ply(mesh)
    glb = realdata("trellis/uanu2002_trellis_sample.glb")
    with pytest.raises(splats.SplatsError,
                       match=r"uanu2002_trellis_sample\.glb: a mesh \(\.glb\).*mesh-asset.*accepted are"):
        splats_io.read(glb)


def test_other_files_name_the_accepted_formats(tmp_path):
    (tmp_path / "model.glb").write_bytes(b"glTF\x02\x00\x00\x00" + bytes(100))
    # a damaged GLB says what is wrong with it (not "a mesh")
    with pytest.raises(splats.SplatsError, match=r"model\.glb: its glTF cannot be read \(a GLB without its JSON "
                                                 r"chunk first\): a damaged or truncated file"):
        splats_io.read(tmp_path / "model.glb")
    (tmp_path / "car.fbx").write_bytes(b"Kaydara FBX Binary  \x00" + bytes(100))  # not read at all: say so
    with pytest.raises(splats.SplatsError, match=r"car\.fbx: \.fbx files are not read: export the car as GLB"):
        splats_io.read(tmp_path / "car.fbx")
    (tmp_path / "scene.spz").write_bytes(bytes(100))
    with pytest.raises(splats.SplatsError, match=r"scene\.spz: named \.spz but its content is not that format"):
        splats_io.read(tmp_path / "scene.spz")
    (tmp_path / "noise.bin").write_bytes(bytes(range(256)))
    with pytest.raises(splats.SplatsError, match=r"noise\.bin: not a PLY file.*accepted are .*SuperSplat compressed"):
        splats_io.load(tmp_path / "noise.bin")
    with pytest.raises(splats.SplatsError, match="not a PLY file"):
        splats_io.read_ply(tmp_path / "noise.bin")


def test_real_inria_files_read_as_inria():
    for rel, n, degree in (("3dgs/loadersgl_train-1000.ply", 1000, 3), ("3dgs/gshairlod_donut_fused.ply", 45624, 0),
                           ("3dgs/supersplat_fruit_drops_minimal.ply", 4721, 3)):
        ply = splats_io.read(realdata(rel))
        assert (len(ply), ply.sh_degree, ply.format) == (n, degree, "inria"), rel
        assert trellis.detect_axes(ply)[0] == "NONE"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
@pytest.mark.parametrize("name", ["pipe.ply", "pipe.splat", "pipe.compressed.ply"])
def test_fifo_and_directory_are_refused_at_once(tmp_path, name):
    """A FIFO given as an asset once blocked the reader for minutes (ignoring SIGTERM); now it is refused."""
    os.mkfifo(tmp_path / name)
    t = time.perf_counter()
    readers = (splats_io.read, splats_io.load, splats_io.read_ply, splats_compressed.read_splat,
               ply_format.read_ply_header)
    for fn in readers:
        with pytest.raises(splats.SplatsError,
                           match=rf"{re.escape(name)}: is a FIFO \(named pipe\), not a regular file"):
            fn(tmp_path / name)
    assert not splats_io.is_mesh_ply(tmp_path / name)
    assert time.perf_counter() - t < 1.0
    (tmp_path / "folder.ply").mkdir()
    with pytest.raises(splats.SplatsError, match="folder.ply: is a directory") as e:
        splats_io.read(tmp_path / "folder.ply")
    assert e.value.field == "(file)"


# -- fuzzing -------------------------------------------------------------------------------------------------------

def _corrupt(data: bytes, rng) -> bytes:
    head_end = data.find(b"end_header") + 11
    kind = rng.integers(0, 10)
    b = bytearray(data)
    if kind == 0:                                   # truncation anywhere
        return bytes(b[: rng.integers(0, len(b))])
    if kind == 1:                                   # flipped bytes in the header
        for _ in range(rng.integers(1, 4)):
            i = rng.integers(0, head_end)
            b[i] ^= 1 << int(rng.integers(0, 8))
        return bytes(b)
    if kind == 2:                                   # wrong vertex count
        n = int(rng.choice([0, 1, 2, 10**6, 10**15, -5, int(rng.integers(0, 200))]))
        return re.sub(rb"element vertex \d+", b"element vertex %d" % n, data)
    if kind == 3:                                   # garbage inserted
        i = rng.integers(0, len(b))
        return bytes(b[:i]) + rng.bytes(int(rng.integers(1, 64))) + bytes(b[i:])
    if kind == 4:                                   # garbage over the body (NaNs, infs, anything)
        i = rng.integers(head_end, len(b))
        n = int(rng.integers(1, 256))
        b[i:i + n] = rng.bytes(len(b[i:i + n]))
        return bytes(b)
    if kind == 5:                                   # a header line deleted or duplicated
        lines = data[:head_end].split(b"\n")
        j = int(rng.integers(1, len(lines) - 1))
        lines.insert(j, lines[j]) if rng.random() < 0.5 else lines.pop(j)
        return b"\n".join(lines) + data[head_end:]
    if kind == 6:                                   # types and formats swapped
        swaps = [(b"float", b"double"), (b"float", b"uchar"), (b"binary_little_endian", b"binary_big_endian"),
                 (b"binary_little_endian", b"ascii"), (b"vertex", b"face"), (b"property", b"propertx")]
        a, c = swaps[int(rng.integers(0, len(swaps)))]
        return data.replace(a, c, int(rng.integers(1, 3)))
    if kind == 7:                                   # pure noise, sometimes with a PLY magic
        noise = rng.bytes(int(rng.integers(0, 2000)))
        return (b"ply\n" + noise) if rng.random() < 0.5 else noise
    if kind == 8:                                   # a list property or an element before the vertices
        return data.replace(b"element vertex", b"element junk 3\nproperty list uchar int idx\nelement vertex", 1)
    return data.replace(b"end_header\n", b"end_header", 1)  # header glued to the body


def test_fuzz_corruptions_end_in_error_or_valid_asset(tmp_path):
    sources = []
    F.trellis_like_file(tmp_path / "trellis.ply", N=60)
    sources.append((tmp_path / "trellis.ply").read_bytes())
    splats_inria.write_ply(tmp_path / "inria.ply", F.random_ply(N=60, degree=3))
    sources.append((tmp_path / "inria.ply").read_bytes())
    splats_inria.write_ply(tmp_path / "be.ply", F.random_ply(N=30, degree=1), byte_order=">")
    sources.append((tmp_path / "be.ply").read_bytes())
    F.write_compressed(tmp_path / "compressed.ply", F.random_gaussians(300, 1, seed=7))  # 2 chunks, SH element
    sources.append((tmp_path / "compressed.ply").read_bytes())
    rng = np.random.default_rng(12345)
    outcomes = {"error": 0, "valid": 0}
    slowest = 0.0
    target = tmp_path / "fuzz.ply"
    for case in range(1200):
        target.write_bytes(_corrupt(sources[case % len(sources)], rng))
        t = time.process_time()   # CPU: another busy process on the machine does not make a case slow
        try:
            g = splats_io.load(target)
        except splats.SplatsError as e:
            assert "fuzz.ply" in str(e)
            outcomes["error"] += 1
        else:
            for arr in (g.means, g.scales, g.quats, g.opacities, g.sh):
                assert np.all(np.isfinite(arr)), case
            assert np.allclose(np.linalg.norm(g.quats, axis=1), 1, atol=1e-5) if len(g) else True
            outcomes["valid"] += 1
        slowest = max(slowest, time.process_time() - t)
    assert outcomes["error"] > 300 and outcomes["valid"] > 100, outcomes
    assert slowest < 1.0, slowest
    print(f"fuzz: {outcomes}, slowest case {slowest * 1e3:.1f} ms")
    os.remove(target)


def test_formats_are_detected_by_content_whatever_the_name(tmp_path):
    """reader.detect: a SOG bundle (zip with meta.json) or its meta.json is "sog" under any name; a zip without
    meta.json and a JSON that is neither glTF nor SOG are refused by name."""
    import json
    import zipfile
    meta = {"version": 2, "count": 1, "means": {"mins": [0, 0, 0], "maxs": [1, 1, 1], "files": ["means_l.webp"]},
            "scales": {"files": ["scales.webp"]}, "quats": {"files": ["quats.webp"]}}
    with zipfile.ZipFile(tmp_path / "scene.splat", "w") as z:
        z.writestr("meta.json", json.dumps(meta))
    assert splats_io.detect(tmp_path / "scene.splat") == "sog"
    (tmp_path / "meta.json").write_text(json.dumps(meta))
    assert splats_io.detect(tmp_path / "meta.json") == "sog"
    with zipfile.ZipFile(tmp_path / "other.sog", "w") as z:
        z.writestr("readme.txt", "x")
    with pytest.raises(splats.SplatsError, match=r"other\.sog: a zip without meta\.json"):
        splats_io.read(tmp_path / "other.sog")
    (tmp_path / "x.json").write_text('{"a": 1}')
    with pytest.raises(splats.SplatsError, match=r"x\.json: a JSON file that is neither a glTF nor a SOG meta\.json"):
        splats_io.read(tmp_path / "x.json")
    assert {".spz", ".ksplat", ".sog", ".glb", ".gltf"} <= set(splats_io.ASSET_EXTENSIONS)


def _splat_records(tmp_path, n=1000):
    """A valid antimatter15 .splat of n Gaussians, as its 32-byte records (``compressed.SPLAT_RECORD``)."""
    path = tmp_path / "car.splat"
    splats_compressed.write_splat(path, splats.decode(F.random_gaussians(n, 0, seed=3)))
    return np.fromfile(path, splats_compressed.SPLAT_RECORD)


def test_a_splat_with_some_absurd_records_drops_them_and_says_why(tmp_path):
    """A minority of garbage records (NaN, positions of 1e30 m, σ of 1e38 m: what a damaged file or a converter's
    bad output holds) is dropped and counted on load, by reason; before, the 1e30 and 1e38 rows were kept (an import
    of dimensions (inf, inf, inf), Gaussians covering every frame)."""
    rec = _splat_records(tmp_path)
    rec["xyz"][:100] = np.nan
    rec["xyz"][100:200, 1] = 1e30
    rec["scale"][200:300, 2] = 1e38
    rec.tofile(tmp_path / "some_bad.splat")
    g = splats_io.load(tmp_path / "some_bad.splat")
    assert len(g) == 700 and g.dropped == {"non_finite": 100, "absurd": 200}
    assert np.abs(g.means).max() < 10 and g.scales.max() < 10
    verdict = splats.asset_verdict(1000, g.dropped)
    assert verdict is None  # 30 %: a warning only past MOSTLY_INVALID_SHARE
    assert "200 with a position or σ beyond 1e+06 m" in splats.asset_verdict(300, g.dropped).text


def test_a_splat_mostly_of_garbage_is_refused_naming_the_counts(tmp_path):
    rec = _splat_records(tmp_path)
    rec["xyz"][:600] = np.nan
    rec["scale"][600:800] = 1e38
    rec.tofile(tmp_path / "mostly_bad.splat")
    with pytest.raises(splats.SplatsError, match=r"mostly_bad\.splat: 800 of its 1,000 32-byte records are no valid "
                                                 r"Gaussians \(600 with NaN or infinite values, 200 with a position "
                                                 r"or σ beyond 1e\+06 m\): more than 50%"):
        splats_io.read(tmp_path / "mostly_bad.splat")


@pytest.mark.parametrize("name", ["car.spz", "car.ply", "car.splat", "car.glb", "car.sog", "car"])
def test_an_empty_file_is_called_empty_whatever_its_name(tmp_path, name):
    (tmp_path / name).write_bytes(b"")
    with pytest.raises(splats.SplatsError, match=re.escape(name) + r": the file is empty \(0 bytes\)"):
        splats_io.read(tmp_path / name)
