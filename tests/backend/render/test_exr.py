"""backend.render.exr: our writer, read back by itself and by Blender's own OpenEXR loader."""

import numpy as np
import pytest

from backend.render import exr


def layers(H=7, W=11, seed=0):
    rng = np.random.default_rng(seed)
    z = rng.uniform(1, 50, (H, W)).astype(np.float32)
    z[0, 0] = np.inf
    return {"R": rng.random((H, W)), "G": rng.random((H, W)), "B": rng.random((H, W)),
            "hole": (rng.random((H, W)) > 0.5).astype(np.float32), "asset": rng.random((H, W)), "Z": z}


def test_round_trip(tmp_path):
    ch = layers()
    exr.write(tmp_path / "f.exr", ch)
    back = exr.read(tmp_path / "f.exr")
    assert sorted(back) == ["B", "G", "R", "Z", "asset", "hole"]
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
    with pytest.raises(ValueError, match="not.exr"):
        exr.read(tmp_path / "not.exr")
