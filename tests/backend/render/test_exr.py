"""backend.render.exr: our writer, read back by itself and by Blender's own OpenEXR loader."""

import numpy as np
import pytest

from backend.render import exr


def layers(H=7, W=11, seed=0):
    rng = np.random.default_rng(seed)
    z = rng.uniform(1, 50, (H, W)).astype(np.float32)
    z[0, 0] = np.inf
    return {"R": rng.random((H, W)), "G": rng.random((H, W)), "B": rng.random((H, W)),
            "hole": (rng.random((H, W)) > 0.5).astype(np.float32), "asset_mask": rng.random((H, W)), "Z": z}


def test_round_trip(tmp_path):
    ch = layers()
    exr.write(tmp_path / "f.exr", ch)
    back = exr.read(tmp_path / "f.exr")
    assert sorted(back) == ["B", "G", "R", "Z", "asset_mask", "hole"]
    for k, v in ch.items():
        assert np.array_equal(back[k], np.asarray(v, np.float32)), k
    assert not list(tmp_path.glob("*.tmp"))


def test_blender_reads_it(tmp_path):
    """An independent reader: Blender's OpenEXR loader sees the same R, G, B (rows bottom-up in Blender)."""
    import bpy

    ch = layers(H=5, W=9, seed=1)
    exr.write(tmp_path / "b.exr", ch)
    img = bpy.data.images.load(str(tmp_path / "b.exr"))
    assert tuple(img.size) == (9, 5)
    px = np.empty(9 * 5 * 4, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(5, 9, 4)[::-1]
    for i, c in enumerate("RGB"):
        assert np.allclose(px[..., i], ch[c], atol=1e-6), c
    bpy.data.images.remove(img)


def test_bad_input(tmp_path):
    with pytest.raises(ValueError):
        exr.write(tmp_path / "x.exr", {})
    with pytest.raises(ValueError):
        exr.write(tmp_path / "x.exr", {"R": np.zeros((2, 2)), "G": np.zeros((2, 3))})
    (tmp_path / "not.exr").write_bytes(b"hello")
    with pytest.raises(exr.ExrError, match="not.exr"):
        exr.read(tmp_path / "not.exr")


def test_damaged_files_are_input_errors_naming_the_file(tmp_path):
    """A truncated or damaged EXR (an output folder someone edited) is an ExrError naming the file, never an
    allocation from a forged size or an IndexError."""
    path = tmp_path / "frame.exr"
    exr.write(path, layers())
    data = path.read_bytes()
    header_end = data.index(b"\0\0", data.index(b"screenWindowWidth"))
    cases = {"truncated.exr": data[:len(data) // 2], "no_rows.exr": data[:header_end + 20],
             "cut_header.exr": data[:40]}
    i = data.index(b"dataWindow") + len(b"dataWindow\0box2i\0") + 4  # the box's x1, y1: a 2**31-pixel window
    cases["forged.exr"] = data[:i + 8] + np.array([2 ** 31 - 2, 2 ** 31 - 2], "<i4").tobytes() + data[i + 16:]
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(exr.ExrError) as e:
            exr.read(tmp_path / name)
        assert e.value.path == str(tmp_path / name) and name in str(e.value) and e.value.hint
    with pytest.raises(exr.ExrError, match="not found"):
        exr.read(tmp_path / "missing.exr")
