"""The condition EXR through the ASWF OpenEXR package (backend.render.channels.write/read): bit-exact float32,
the half-float option, the passes Blender's compositor shows and the pixels it reads from each, files re-saved
by other tools, and damaged files as errors naming the file."""

import os

import numpy as np
import OpenEXR
import pytest

from backend.render import channels
from scpainter_blender.core import errors

PASSES = {"image": "RGBA", "hole": "VALUE", "asset_mask": "VALUE", "depth": "VALUE",  # Blender's outputs, types
          "instance": "VALUE"}


def layers(H=5, W=7, seed=0):
    """Random condition layers with float32's awkward values: the largest, the smallest normal, denormals, -0,
    and +inf in Z (an empty pixel); instance ids 0..3 and 2049 (which half cannot hold)."""
    rng = np.random.default_rng(seed)
    out = {c: rng.random((H, W)).astype(np.float32) for c in channels.CHANNELS}
    out["hole"] = (rng.random((H, W)) > 0.5).astype(np.float32)
    out["Z"] = rng.uniform(0.5, 80, (H, W)).astype(np.float32)
    out["Z"][0, 0], out["Z"][0, 1] = np.inf, np.finfo(np.float32).max
    out["instance"] = rng.integers(0, 4, (H, W)).astype(np.float32)
    out["instance"][0, 2] = 2049.0
    out["R"][1, 1], out["G"][1, 2] = np.float32(1e-45), np.finfo(np.float32).tiny  # a denormal, smallest normal
    out["B"][2, 2], out["asset_mask"][2, 3] = np.float32(3e-39), np.float32(-0.0)   # a denormal, negative zero
    return out


def raw(path) -> dict:
    """{file channel name: array} as OpenEXR reads the file, every part."""
    return {n: c.pixels for p in OpenEXR.File(str(path), separate_channels=True).parts for n, c in p.channels.items()}


def bits(a):
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


def test_float32_round_trip_is_bit_exact_and_zip_compressed(tmp_path):
    ch = layers()
    path = tmp_path / "f.exr"
    channels.write(path, ch)
    back = channels.read(path)
    assert sorted(back) == sorted(channels.CHANNELS)
    for k in channels.CHANNELS:
        assert back[k].dtype == np.float32 and np.array_equal(bits(back[k]), bits(ch[k])), k
    f = OpenEXR.File(str(path), separate_channels=True)
    assert f.header()["compression"] == OpenEXR.ZIP_COMPRESSION and f.header()["type"] == OpenEXR.scanlineimage
    assert {n: c.type() for n, c in f.channels().items()} == {
        n: OpenEXR.FLOAT for n in ["image.R", "image.G", "image.B", "hole.Y", "asset_mask.Y", "depth.Z", "instance.Y"]}
    assert sorted(os.listdir(tmp_path)) == ["f.exr"]                      # written through a temporary, renamed


def test_zip_is_smaller_than_raw_on_smooth_layers(tmp_path):
    H, W = 64, 96
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    smooth = {c: np.sin(x / 9 + i) * np.cos(y / 7) for i, c in enumerate(channels.CHANNELS)}
    smooth["hole"] = (x > 50).astype(np.float32)
    channels.write(tmp_path / "zip.exr", smooth)
    channels.write(tmp_path / "half.exr", smooth, half=True)
    raw_bytes = len(channels.CHANNELS) * 4 * H * W
    assert os.path.getsize(tmp_path / "zip.exr") < raw_bytes
    assert os.path.getsize(tmp_path / "half.exr") < os.path.getsize(tmp_path / "zip.exr")


def test_half_float_stores_i_m_ma_as_half_and_z_and_instance_as_float(tmp_path):
    ch = layers(seed=1)
    ch["G"][1, 2] = 0.5  # (the smallest normal float32 is below half's range: it rounds to 0, as documented)
    channels.write(tmp_path / "h.exr", ch, half=True)
    f = OpenEXR.File(str(tmp_path / "h.exr"), separate_channels=True)
    types = {n: c.type() for n, c in f.channels().items()}
    assert types == {"image.R": OpenEXR.HALF, "image.G": OpenEXR.HALF, "image.B": OpenEXR.HALF,
                     "hole.Y": OpenEXR.HALF, "asset_mask.Y": OpenEXR.HALF, "depth.Z": OpenEXR.FLOAT,
                     "instance.Y": OpenEXR.FLOAT}
    back = channels.read(tmp_path / "h.exr")
    for k in channels.HALF_LAYERS:  # exactly numpy's float16 rounding of the float32 values
        assert back[k].dtype == np.float32 and np.array_equal(back[k], ch[k].astype(np.float16).astype(np.float32))
        assert np.abs(back[k] - ch[k]).max() <= 2.0 ** -12       # half's rounding error on [0, 1]
    assert np.array_equal(back["hole"], ch["hole"])               # 0/1 exactly
    assert np.array_equal(bits(back["Z"]), bits(ch["Z"]))         # depth keeps float32, inf included
    assert np.array_equal(bits(back["instance"]), bits(ch["instance"])) and back["instance"][0, 2] == 2049  # exact


def test_writer_refuses_other_keys_and_shapes(tmp_path):
    z = np.zeros((2, 3), np.float32)
    good = {c: z for c in channels.CHANNELS}
    for bad in ({**good, "extra": z}, {c: z for c in channels.CHANNELS if c != "Z"},
                {**good, "Z": np.zeros((2, 4), np.float32)}, {c: np.zeros(3, np.float32) for c in channels.CHANNELS}):
        with pytest.raises(ValueError, match="condition layers"):
            channels.write(tmp_path / "bad.exr", bad)
    assert not os.listdir(tmp_path)


def test_blender_shows_five_passes_and_reads_each_as_written(tmp_path):
    """Blender's own EXR reader: an Image node on the file lists the passes image, hole, asset_mask, depth,
    instance; the
    compositor (bpy 5.0 node-group API) writes each pass to a file of its own (a File Output node), and what
    Blender decoded is what was written, bit for bit (float32 file) or float16's values (half file).

    (``image.pixels`` of a multilayer EXR is empty in bpy 5.0.1, "does not have any image data": the compositor
    is the way to read a pass's pixels from Python.)"""
    import bpy

    H, W = 5, 7
    ch = layers(H, W, seed=2)
    channels.write(tmp_path / "float.exr", ch)
    channels.write(tmp_path / "half.exr", ch, half=True)
    scene = bpy.data.scenes.new("scpainter_exr_test")
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = W, H, 100
    tree = bpy.data.node_groups.new("scpainter_exr_test", "CompositorNodeTree")
    scene.compositing_node_group = tree
    made = []
    try:
        for name, half in (("float", False), ("half", True)):
            img = bpy.data.images.load(str(tmp_path / f"{name}.exr"))
            made.append(img)
            for n in list(tree.nodes):
                tree.nodes.remove(n)
            node = tree.nodes.new("CompositorNodeImage")
            node.image = img
            assert {o.name: o.type for o in node.outputs} == PASSES and img.type == "MULTILAYER"
            out = tree.nodes.new("CompositorNodeOutputFile")
            out.format.media_type, out.format.file_format, out.format.color_depth = "IMAGE", "OPEN_EXR", "32"
            out.directory, out.file_name = str(tmp_path / f"blender_{name}") + os.sep, "pass_"
            for p, kind in PASSES.items():
                out.file_output_items.new("RGBA" if kind == "RGBA" else "FLOAT", p)
                tree.links.new(node.outputs[p], out.inputs[p])
            assert bpy.ops.render.render(scene=scene.name) == {"FINISHED"}
            written = {f.split("pass_")[1].split(".")[0]: raw(tmp_path / f"blender_{name}" / f)
                       for f in os.listdir(tmp_path / f"blender_{name}")}
            assert sorted(written) == sorted(PASSES)

            def want(k):
                v = ch[k]
                return v.astype(np.float16).astype(np.float32) if half and k in channels.HALF_LAYERS else v
            for i, c in enumerate(channels.IMAGE):
                assert np.array_equal(bits(written["image"]["RGB"[i]]), bits(want(c))), (name, c)
            for p, k in (("hole", "hole"), ("asset_mask", "asset_mask"), ("depth", "Z"), ("instance", "instance")):
                assert np.array_equal(bits(written[p]["R"]), bits(want(k))), (name, p)
    finally:
        bpy.data.scenes.remove(scene)
        bpy.data.node_groups.remove(tree)
        for img in made:
            bpy.data.images.remove(img)


def _save(path, named: dict, compression=OpenEXR.ZIP_COMPRESSION, tiles=None, parts=None):
    """``named`` {file channel name: array} as another tool might save it: compression, tiles (x, y, level
    mode), several parts (a list of name lists)."""
    header = {"compression": compression}
    if tiles is not None:
        td = OpenEXR.TileDescription()
        td.xSize, td.ySize, td.mode = tiles
        header.update(type=OpenEXR.tiledimage, tiles=td)
    if parts is None:
        OpenEXR.File(header, dict(named)).write(str(path))
    else:
        OpenEXR.File([OpenEXR.Part(dict(header), {n: named[n] for n in names}, f"part{i}")
                      for i, names in enumerate(parts)]).write(str(path))


def test_reader_takes_files_resaved_by_other_tools(tmp_path):
    ch = layers(H=9, W=13, seed=3)
    ours = {channels.FILE_NAMES[c]: ch[c] for c in channels.CHANNELS}
    exact = {  # lossless: every layer comes back bit for bit
        "piz": dict(compression=OpenEXR.PIZ_COMPRESSION), "rle": dict(compression=OpenEXR.RLE_COMPRESSION),
        "zips": dict(compression=OpenEXR.ZIPS_COMPRESSION), "none": dict(compression=OpenEXR.NO_COMPRESSION),
        "zstd": dict(compression=OpenEXR.ZSTD_COMPRESSION),
        "tiled": dict(tiles=(4, 4, OpenEXR.ONE_LEVEL)),                   # tiles that do not divide the image
        "two_parts": dict(parts=[["depth.Z", "hole.Y"], ["image.B", "image.G", "image.R", "asset_mask.Y",
                                 "instance.Y"]]),
    }
    for name, how in exact.items():
        _save(tmp_path / f"{name}.exr", {n: ours[n] for n in reversed(list(ours))}, **how)
        back = channels.read(tmp_path / f"{name}.exr")
        assert all(np.array_equal(bits(back[k]), bits(ch[k])) for k in channels.CHANNELS), name
    renamed = {  # other names for the same channels
        "blender_prefix": {f"ViewLayer.{n}": v for n, v in ours.items()},
        "other_letters": {"image.R": ch["R"], "image.G": ch["G"], "image.B": ch["B"], "hole.V": ch["hole"],
                          "asset_mask.X": ch["asset_mask"], "Depth.Z": ch["Z"], "Instance.V": ch["instance"]},
        "nuke_colours": {**{n: v for n, v in ours.items() if not n.startswith("image")},
                         "image.red": ch["R"], "image.green": ch["G"], "image.blue": ch["B"]},
        "flat_before": {c: ch[c] for c in channels.CHANNELS},              # the flat names (instance added)
        "flat_asset": {**{c: ch[c] for c in channels.CHANNELS if c != "asset_mask"}, "asset": ch["asset_mask"]},
        "extra_alpha": {**ours, "image.A": np.ones_like(ch["R"]), "notes.Y": np.zeros_like(ch["R"])},
    }
    for name, named in renamed.items():
        _save(tmp_path / f"{name}.exr", named)
        back = channels.read(tmp_path / f"{name}.exr")
        assert sorted(back) == sorted(channels.CHANNELS), name
        assert all(np.array_equal(bits(back[k]), bits(ch[k])) for k in channels.CHANNELS), name
    # pixel types: every channel HALF (Z too: float32's largest becomes half's inf), a UINT hole mask
    with np.errstate(over="ignore"):
        as_half = {k: v.astype(np.float16) for k, v in ch.items()}
    _save(tmp_path / "all_half.exr", {channels.FILE_NAMES[k]: v for k, v in as_half.items()})
    back = channels.read(tmp_path / "all_half.exr")
    assert all(np.array_equal(back[k], as_half[k].astype(np.float32)) for k in channels.CHANNELS)
    _save(tmp_path / "uint.exr", {**ours, "hole.Y": ch["hole"].astype(np.uint32)})
    assert np.array_equal(channels.read(tmp_path / "uint.exr")["hole"], ch["hole"])
    # a lossy compression gives its own values: PXR24 keeps 24 of float's 32 bits (relative error < 2^-15)
    _save(tmp_path / "pxr24.exr", ours, compression=OpenEXR.PXR24_COMPRESSION)
    back = channels.read(tmp_path / "pxr24.exr")
    finite = np.isfinite(ch["Z"]) & (ch["Z"] < 1e30)
    assert np.allclose(back["Z"][finite], ch["Z"][finite], rtol=2.0 ** -15, atol=0)
    assert np.array_equal(back["hole"], ch["hole"])


def test_reader_errors_name_the_file_and_say_render_again(tmp_path):
    """Damaged, truncated, forged and foreign files, and files without the needed channels: an ExrError (an
    InputError) naming the file and the field, with the hint to render again; never an exception from inside
    OpenEXR, and nothing OpenEXR prints reaches standard output (the backend's event stream)."""
    path = tmp_path / "frame.exr"
    channels.write(path, layers())
    data = path.read_bytes()
    i = data.index(b"dataWindow") + len(b"dataWindow\0box2i\0") + 4  # the box's x1, y1
    cases = {"truncated.exr": data[:len(data) // 2], "cut_header.exr": data[:40], "not_exr.exr": b"hello",
             "empty.exr": b"", "no_rows.exr": data[:data.index(b"\0", data.index(b"lineOrder")) + 40],
             "forged.exr": data[:i + 8] + np.array([2 ** 31 - 2, 2 ** 31 - 2], "<i4").tobytes() + data[i + 16:],
             "huge.exr": data[:i + 8] + np.array([40000, 40000], "<i4").tobytes() + data[i + 16:]}
    for n in range(len(data) // 2, len(data), 97):  # flipped bytes in the compressed pixels: zlib's check
        cases[f"flipped_{n}.exr"] = data[:n] + bytes([data[n] ^ 0x55]) + data[n + 1:]
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(channels.ExrError) as e:
            channels.read(tmp_path / name)
        assert isinstance(e.value, errors.InputError) and e.value.path == str(tmp_path / name)
        assert name in str(e.value) and "delete the file and run python -m backend render JOB" in e.value.hint, name
    with pytest.raises(channels.ExrError, match="not found"):
        channels.read(tmp_path / "missing.exr")
    os.mkfifo(tmp_path / "fifo.exr")
    with pytest.raises(channels.ExrError, match="FIFO"):
        channels.read(tmp_path / "fifo.exr")
    _save(tmp_path / "cropped.exr", {channels.FILE_NAMES[c]: v for c, v in layers().items()})
    f = OpenEXR.File(str(tmp_path / "cropped.exr"), separate_channels=True)  # a data window inside the display's
    f.header()["displayWindow"] = (np.array([0, 0], np.int32), np.array([9, 9], np.int32))
    f.write(str(tmp_path / "cropped.exr"))
    with pytest.raises(channels.ExrError) as e:
        channels.read(tmp_path / "cropped.exr")
    assert e.value.field == "dataWindow"
    _save(tmp_path / "two_holes.exr", {"image.R": layers()["R"], "hole.R": layers()["hole"],
                                       "hole.G": layers()["hole"]})
    with pytest.raises(channels.ExrError, match="expected one"):
        channels.read(tmp_path / "two_holes.exr")
    both = {channels.FILE_NAMES[c]: v for c, v in layers().items()}
    _save(tmp_path / "two_images.exr", {**both, "ViewLayer.image.R": both["image.R"], "other.notes.Y": both["hole.Y"]})
    with pytest.raises(channels.ExrError, match="could each be the image pass"):
        channels.read(tmp_path / "two_images.exr")
    _save(tmp_path / "no_mask.exr", {channels.FILE_NAMES[c]: v for c, v in layers().items() if c != "asset_mask"})
    with pytest.raises(channels.ConditionsError) as e:
        channels.read(tmp_path / "no_mask.exr")
    assert e.value.field == "channels" and "asset_mask" in e.value.message and "render" in e.value.hint
    assert set(channels.read(tmp_path / "no_mask.exr", required=("R", "Z"))) == set(channels.CHANNELS) - {
        "asset_mask"}
    # a file written before the instance pass (every other layer, named as now): refused by name by default, read
    # by a caller that does not need the instance (generate)
    _save(tmp_path / "before_instance.exr", {channels.FILE_NAMES[c]: v for c, v in layers().items()
                                             if c != channels.INSTANCE})
    with pytest.raises(channels.ConditionsError) as e:
        channels.read(tmp_path / "before_instance.exr")
    assert e.value.field == "channels" and "['instance']" in e.value.message and "render" in e.value.hint
    need = (*channels.IMAGE, channels.HOLE, channels.ASSET_MASK)
    old = channels.read(tmp_path / "before_instance.exr", required=need)
    assert set(old) == set(channels.CHANNELS) - {channels.INSTANCE}


def test_damage_never_reaches_standard_output(tmp_path, capfd):
    """OpenEXR prints a warning on standard output for some damage: captured, and turned into the error."""
    path = tmp_path / "frame.exr"
    channels.write(path, layers())
    data = path.read_bytes()
    (tmp_path / "t.exr").write_bytes(data[:len(data) - 30])
    capfd.readouterr()
    with pytest.raises(channels.ExrError, match="damaged"):
        channels.read(tmp_path / "t.exr")
    assert capfd.readouterr().out == ""
