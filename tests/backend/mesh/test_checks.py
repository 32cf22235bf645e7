"""Hostile mesh files (issue 30), each a clean refusal naming the file and field (``MeshAssetError``, an InputError:
exit 2) or an honest acceptance with a warning: face indices outside the vertices, glTF counts beyond the file's
bytes, a truncated OFF, NaN texture coordinates, textures too large to decode, textures missing / outside the
mesh's folder / unreadable, glTF attributes of unequal length, an OBJ face index of 0, an MTL that defines nothing
or a ``map_Kd`` without a file, a missing buffer never replaced by another file of its base name, and what trimesh logs
while it reads (never printed as a traceback); then (second round) a car too large for float32 or too small for
any unit, the textures' total pixels, one decode per texture, backslashes and MTL options in texture names, a
texture that fails to decode, exact pixel counts, numpy's warnings from trimesh. The command-level halves (exit codes, events, a killed run's
temporary) are in test_asset.py."""

import json
import logging
import os
import tracemalloc

import numpy as np
import pytest
import trimesh
from PIL import Image

from tests.backend.mesh import mesh_fixtures as MF
from backend.mesh import asset as ma
from backend.mesh import checks, colors as mesh_colors, load as mesh_load


def refused(path, match, field=None):
    """The MeshAssetError ``load_mesh(path)`` raises (its text matching ``match``, its field ``field``)."""
    with pytest.raises(mesh_load.MeshAssetError, match=match) as e:
        mesh_load.load_mesh(path)
    assert os.path.basename(os.fspath(path)) in str(e.value)
    if field is not None:
        assert e.value.field == field, e.value.field
    return e.value


# -- 1. face indices -----------------------------------------------------------------------------------------------

def test_face_indices_outside_the_vertices_are_refused(tmp_path):
    refused(MF.triangle_gltf(tmp_path / "g", indices=(0, 1, 7)), r"faces name vertices 0 to 7, but it has 3",
            "indices")
    refused(MF.triangle_gltf(tmp_path / "b", name="tri.glb", buffer_uri=None, indices=(0, 1, 2 ** 32 - 1)),
            "corrupt face indices", "indices")
    head = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n")
    (tmp_path / "neg.ply").write_text(head + "3 0 1 -1\n")   # trimesh keeps -1: it would wrap to the last vertex
    refused(tmp_path / "neg.ply", r"faces name vertices -1 to 1, but it has 3", "face")
    (tmp_path / "big.ply").write_text(head + "3 0 1 5\n")
    refused(tmp_path / "big.ply", "corrupt face indices", "face")
    (tmp_path / "far.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -7\n")   # OBJ's relative index, too far
    refused(tmp_path / "far.obj", "a face names a vertex that does not exist", "f")
    (tmp_path / "rel.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n")  # relative indices are fine
    np.testing.assert_array_equal(mesh_load.load_mesh(tmp_path / "rel.obj").faces, [[0, 1, 2]])


# -- 2. glTF counts ------------------------------------------------------------------------------------------------

def test_gltf_counts_are_bounded_by_the_bytes_behind_them(tmp_path):
    huge = {"componentType": 5126, "count": 10 ** 9, "type": "VEC3"}   # no bufferView: trimesh made 12 GB of zeros
    for name, uri in (("tri.gltf", "tri.bin"), ("tri.glb", None)):
        e = refused(MF.triangle_gltf(tmp_path / name, name=name, buffer_uri=uri, accessors=[huge]),
                    r"accessors\[3\] has no bufferView and declares 1,000,000,000 elements", "accessors[3].count")
        assert "could fill" in e.message
    # a bufferView-less accessor the file could hold (an extension's placeholder) is read
    small = {"componentType": 5126, "count": 3, "type": "VEC3"}
    assert len(mesh_load.load_mesh(MF.triangle_gltf(tmp_path / "ok", accessors=[small])).faces) == 1
    # an accessor larger than its bufferView
    refused(MF.triangle_gltf(tmp_path / "v", accessors=[{"bufferView": 0, "componentType": 5126, "count": 4,
                                                        "type": "VEC3"}]),
            r"accessors\[3\] declares 4 elements \(48 bytes\) but bufferViews\[0\] has 36", "accessors[3]")
    # a buffer file shorter than its byteLength, a GLB cut short
    path = MF.triangle_gltf(tmp_path / "short")
    with open(os.path.join(os.path.dirname(path), "tri.bin"), "r+b") as f:
        f.truncate(40)
    refused(path, r"buffers\[0\] declares 72 bytes but 'tri.bin' holds 40", "buffers[0]")
    glb = MF.triangle_gltf(tmp_path / "cut", name="tri.glb", buffer_uri=None)
    data = open(glb, "rb").read()
    open(glb, "wb").write(data[:-20])
    refused(glb, "truncated", "(file)")
    # a count that is not a non-negative integer
    refused(MF.triangle_gltf(tmp_path / "n", accessors=[{"componentType": 5126, "count": -1, "type": "VEC3"}]),
            r"accessors\[3\]\.count = -1 is not an integer", "accessors[3].count")


# -- 3. OFF --------------------------------------------------------------------------------------------------------

def test_truncated_off_is_refused(tmp_path):
    (tmp_path / "t.off").write_text("OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n")  # 4 faces promised, 1 there
    refused(tmp_path / "t.off", r"promises 4 vertices and 4 faces \(8 lines\) but 5 lines follow: truncated",
            "(header)")
    (tmp_path / "ok.off").write_text("OFF\n# a comment\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n")
    assert len(mesh_load.load_mesh(tmp_path / "ok.off").faces) == 2
    (tmp_path / "big.off").write_text("OFF\n1000000000 1 0\n0 0 0\n")
    refused(tmp_path / "big.off", "truncated", "(header)")


# -- 4. NaN texture coordinates ------------------------------------------------------------------------------------

def test_nan_texture_coordinates_are_refused_naming_the_field(tmp_path):
    Image.new("RGB", (8, 8), (200, 0, 0)).save(tmp_path / "tex.png")
    nan = [[np.nan, 0], [0.5, np.nan], [0, 1]]
    e = refused(MF.triangle_gltf(tmp_path, image_uri="tex.png", uv=nan),
                "2 of the 3 texture coordinates its faces use are not finite", "TEXCOORD_0")
    assert "UVs" in e.hint
    # without a texture the UVs are not used: no reason to refuse
    assert len(mesh_load.load_mesh(MF.triangle_gltf(tmp_path / "plain", uv=nan)).faces) == 1


# -- 5. textures too large to decode -------------------------------------------------------------------------------

def _bomb(path):
    """A real, decodable PNG of 8200 × 8200 (67 Mpx, just over the bound) of a few kB: 1-bit, one colour."""
    Image.new("1", (8200, 8200)).save(path)
    assert os.path.getsize(path) < 100_000
    return path


def test_textures_beyond_the_pixel_bound_are_refused_from_their_header(tmp_path):
    assert checks.MAX_TEXTURE_PIXELS == 8192 * 8192 < 8200 * 8200
    os.makedirs(tmp_path / "uri")
    png = _bomb(tmp_path / "uri" / "big.png").read_bytes()
    e = refused(MF.triangle_gltf(tmp_path / "uri", image_uri="big.png"), r"'big.png' is 8200 × 8200 = 67,240,000 pixels",
                "big.png")
    assert "8192" in e.hint
    # embedded in a GLB's BIN chunk (images[0].bufferView)
    refused(MF.triangle_gltf(tmp_path / "glb", name="tri.glb", buffer_uri=None, image_bytes=png), "8200 × 8200",
            "images[0] (bufferViews[3])")
    # an OBJ's map_Kd, and a texture with no image extension that trimesh opens itself (PIL's bound, set to ours)
    for tex in ("big.png", "big_texture"):
        folder = tmp_path / f"obj_{tex}"
        folder.mkdir()
        (folder / tex).write_bytes(png)
        (folder / "car.mtl").write_text(f"newmtl m\nKd 1 1 1\nmap_Kd {tex}\n")
        (folder / "car.obj").write_text("mtllib car.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                                        "usemtl m\nf 1/1 2/2 3/3\n")
        refused(folder / "car.obj", "8200 × 8200" if tex.endswith(".png") else "larger than 67,108,864 pixels")


def test_texture_sampling_makes_no_float_copy_of_the_image():
    img = Image.new("RGB", (2048, 2048), (10, 20, 30))        # 12 MB as uint8; 100 MB as float64
    uv = np.random.default_rng(0).random((1000, 2))
    tracemalloc.start()
    rgb = mesh_colors.sample_texture(img, uv)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    np.testing.assert_allclose(rgb, np.tile([10 / 255, 20 / 255, 30 / 255], (1000, 1)), atol=1e-12)
    assert peak < 3 * 2048 * 2048 * 3, peak   # PIL's bytes and the uint8 array; a float64 copy is 8 times that


# -- 6. textures missing, outside the folder, unreadable -----------------------------------------------------------

def test_textures_that_cannot_be_read_are_refused_naming_them(tmp_path):
    Image.new("RGB", (4, 4), (1, 2, 3)).save(tmp_path / "outside.png")
    e = refused(MF.triangle_gltf(tmp_path / "a", image_uri="missing.png"), r"'missing.png' \(named by the mesh\) not "
                                                                          "found", "missing.png")
    assert "fix the name" in e.hint
    e = refused(MF.triangle_gltf(tmp_path / "b", image_uri="../outside.png"), "lies outside the mesh's folder",
                "../outside.png")
    assert "copy the file next to the mesh" in e.hint
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "bad.png").write_bytes(b"not a png at all")
    refused(MF.triangle_gltf(tmp_path / "c", image_uri="bad.png"), "'bad.png' cannot be read as an image", "bad.png")
    # OBJ: its MTL missing, its map_Kd missing; a PLY's TextureFile missing or not an image
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "car.obj").write_text("mtllib car.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    refused(tmp_path / "o" / "car.obj", r"'car.mtl' \(named by the mesh\) not found", "car.mtl")
    (tmp_path / "o" / "car.mtl").write_text("newmtl m\nmap_Kd gone.jpg\n")
    refused(tmp_path / "o" / "car.obj", r"'gone.jpg' \(named by the mesh\) not found", "gone.jpg")
    head = ("ply\nformat ascii 1.0\ncomment TextureFile {}\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nproperty float texture_u\nproperty float texture_v\nelement face 1\n"
            "property list uchar int vertex_indices\nend_header\n0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2\n")
    (tmp_path / "p").mkdir()
    (tmp_path / "p" / "a.ply").write_text(head.format("lost.png"))     # trimesh printed a traceback, then exit 0
    refused(tmp_path / "p" / "a.ply", r"'lost.png' \(named by the mesh\) not found", "lost.png")
    (tmp_path / "p" / "tex.dat").write_bytes(b"garbage")
    (tmp_path / "p" / "b.ply").write_text(head.format("tex.dat"))
    refused(tmp_path / "p" / "b.ply", "a texture it names cannot be read as an image", "(texture)")
    # a KTX2 texture (trimesh skips it without a word)
    refused(MF.triangle_gltf(tmp_path / "k", images=[{"uri": "t.ktx2", "mimeType": "image/ktx2"}]), "KTX2",
            "images[0]")


# -- 7. exactly the file named -------------------------------------------------------------------------------------

def test_a_missing_buffer_is_never_replaced_by_another_file_of_its_name(tmp_path):
    folder = tmp_path / "car"
    path = MF.triangle_gltf(folder, buffer_uri="sub/box.bin", write_buffer=False)
    # a 40 m triangle under the same base name, beside the mesh: trimesh's resolver took it
    blob = (np.array([[0, 0, 0], [40, 0, 0], [0, 40, 0]], np.float32).tobytes() + np.zeros(6, np.float32).tobytes()
            + np.array([0, 1, 2], np.uint32).tobytes())
    (folder / "box.bin").write_bytes(blob)
    refused(path, r"'sub/box.bin' \(named by the mesh\) not found", "sub/box.bin")
    os.makedirs(folder / "sub")
    os.replace(folder / "box.bin", folder / "sub" / "box.bin")
    assert mesh_load.load_mesh(path).vertices.max() == 40.0   # the file named, once it is there
    # a percent-encoded URI names the decoded file (glTF: URIs are RFC 3986)
    spaced = MF.triangle_gltf(tmp_path / "sp", buffer_uri="my box.bin")
    text = open(spaced).read().replace("my box.bin", "my%20box.bin")
    open(spaced, "w").write(text)
    assert len(mesh_load.load_mesh(spaced).faces) == 1


# -- 8. trimesh's log ----------------------------------------------------------------------------------------------

def test_what_trimesh_goes_on_past_is_a_warning_not_a_printed_traceback(tmp_path, capfd):
    path = MF.triangle_gltf(tmp_path)
    tree = json.load(open(path))
    tree["materials"] = [{"extensions": {"KHR_materials_pbrSpecularGlossiness": {"diffuseFactor": "red"}}}]
    tree["meshes"][0]["primitives"][0]["material"] = 0
    json.dump(tree, open(path, "w"))
    asset = mesh_load.load_mesh(path)
    assert [w["code"] for w in asset.warnings] == [mesh_load.READER_WARNING]
    assert "specular-glossiness" in asset.warnings[0]["message"] and "'red'" in asset.warnings[0]["message"]
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    # nothing is left attached to trimesh's logger
    assert not any(type(h).__name__ == "Keep" for h in logging.getLogger("trimesh").handlers)
    assert logging.getLogger("trimesh").propagate


def test_faces_with_non_finite_corners_are_a_warning(tmp_path):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nan, 0, 0]], float)
    mesh = trimesh.Trimesh(V, [[0, 1, 2], [0, 1, 3]], process=False, validate=False)
    asset = mesh_load.load_mesh(MF.export(mesh, tmp_path / "nan.ply"))
    assert [w["code"] for w in asset.warnings] == [mesh_load.NONFINITE_FACES]
    assert "1 of 2 faces" in asset.warnings[0]["message"]
    assert len(ma.sample_gaussians(asset, 100).gaussians) == 100


# -- 9. what the fuzzer found after the first round (issue 30) ------------------------------------------------------

def test_an_attribute_whose_count_differs_from_position_is_refused(tmp_path):
    # a TEXCOORD_0 without a bufferView (zeros) one longer than POSITION: trimesh read a car with every UV at 0
    path = MF.triangle_gltf(tmp_path / "z", accessors=[{"componentType": 5126, "count": 4, "type": "VEC2"}])
    tree = json.load(open(path))
    tree["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = 3
    json.dump(tree, open(path, "w"))
    refused(path, r"TEXCOORD_0 \(accessors\[3\]\) has 4 elements but POSITION \(accessors\[0\]\) has 3",
            "meshes[0].primitives[0].attributes.TEXCOORD_0")
    # one shorter, with a bufferView
    path = MF.triangle_gltf(tmp_path / "s")
    tree = json.load(open(path))
    tree["accessors"][1]["count"] = 2
    json.dump(tree, open(path, "w"))
    refused(path, r"TEXCOORD_0 \(accessors\[1\]\) has 2 elements but POSITION \(accessors\[0\]\) has 3",
            "meshes[0].primitives[0].attributes.TEXCOORD_0")


def test_an_accessor_must_end_within_its_view_counting_the_stride(tmp_path):
    # VEC2 float (8 bytes) every 16 bytes: 3 elements need 2 × 16 + 8 = 40 bytes of the view, not 3 × 16 = 48
    def strided(folder, length):
        path = MF.triangle_gltf(folder, accessors=[{"bufferView": 3, "componentType": 5126, "count": 3,
                                                    "type": "VEC2"}])
        tree = json.load(open(path))
        tree["bufferViews"].append({"buffer": 0, "byteOffset": 0, "byteLength": length, "byteStride": 16})
        json.dump(tree, open(path, "w"))
        return path

    assert len(mesh_load.load_mesh(strided(tmp_path / "fits", 40)).faces) == 1
    refused(strided(tmp_path / "short", 39), r"accessors\[3\] declares 3 elements \(40 bytes\) but bufferViews\[3\] "
                                             "has 39", "accessors[3]")


def test_an_obj_face_index_of_zero_is_refused(tmp_path):
    body = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
    (tmp_path / "z.obj").write_text(body + "f 0 2 3\n")   # OBJ counts from 1: trimesh read 0 as the first vertex
    refused(tmp_path / "z.obj", r"line 7: face index 0", "f")
    (tmp_path / "t.obj").write_text(body + "f 1/1 2/0 3/3\n")   # a texture-coordinate index of 0
    refused(tmp_path / "t.obj", r"line 7: face index 0", "f")
    (tmp_path / "c.obj").write_text(body + "# f 0 1 2\nf 1/1 2/2 3/3\nf -3 -2 -1\n")  # a comment, relative: fine
    assert len(mesh_load.load_mesh(tmp_path / "c.obj").faces) == 2


def _textured_obj(folder, mtl: bytes, texture="tex.png"):
    os.makedirs(folder / os.path.dirname(texture))
    Image.new("RGB", (4, 4), (200, 0, 0)).save(folder / texture)
    (folder / "car.mtl").write_bytes(mtl)
    (folder / "car.obj").write_text("mtllib car.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                                    "usemtl m\nf 1/1 2/2 3/3\n")
    return folder / "car.obj"


@pytest.mark.parametrize("clamp", [b"on", b"off", None])
def test_mtl_clamp_on_reads_the_edge_texels_beyond_the_unit_square(tmp_path, clamp):
    """An MTL ``map_Kd -clamp on``: texture coordinates in [1.01, 1.99] read the texel at u = v = 1 (the top-right
    of the image, OBJ's v counting up); off (the default): the texture repeats, all four texels are read."""
    from backend.mesh import colors as mesh_colors

    folder = tmp_path / "c"
    folder.mkdir()
    texels = np.array([[(255, 0, 0), (0, 255, 0)], [(0, 0, 255), (255, 255, 0)]], np.uint8)  # rows top to bottom
    Image.fromarray(texels).save(folder / "tex.png")
    option = b"" if clamp is None else b"-clamp " + clamp + b" "
    (folder / "car.mtl").write_bytes(b"newmtl paint\nKd 1 1 1\nmap_Kd " + option + b"tex.png\n")
    (folder / "car.obj").write_text("mtllib car.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 1.01 1.01\nvt 1.99 1.01\n"
                                    "vt 1.99 1.99\nvt 1.01 1.99\nusemtl paint\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    asset = mesh_load.load_mesh(folder / "car.obj")
    assert asset.warnings == []
    g = ma.sample_gaussians(asset, 400, seed=3)
    rgb = MF.rgb_of(g.gaussians)
    if clamp == b"on":
        assert asset.wraps == [(mesh_colors.CLAMP_TO_EDGE, mesh_colors.CLAMP_TO_EDGE)]
        np.testing.assert_allclose(rgb, np.tile([0.0, 1.0, 0.0], (len(rgb), 1)), atol=2e-3)
    else:
        assert asset.wraps == []
        assert np.ptp(rgb, axis=0).max() > 0.5     # repeated: the colours vary across the quad


def test_an_mtl_that_defines_no_material_is_refused_naming_it(tmp_path):
    import random

    for name, data in (("garbage", random.Random(7).randbytes(200)), ("empty", b""),
                       ("comments", b"# exported by hand\n\n")):
        e = refused(_textured_obj(tmp_path / name, data), r"'car.mtl' \(named by the mesh\) defines no material",
                    "car.mtl")
        assert "newmtl" in e.message and "export" in e.hint
    assert len(mesh_load.load_mesh(_textured_obj(tmp_path / "ok", b"newmtl m\nKd 1 1 1\nmap_Kd tex.png\n")).faces) == 1


def test_an_mtl_map_kd_without_a_file_name_is_refused(tmp_path):
    e = refused(_textured_obj(tmp_path / "e", b"newmtl m\nKd 1 1 1\nmap_Kd \n"),
                r"'car.mtl' \(named by the mesh\) line 3: map_Kd names no file", "map_Kd")
    assert "texture" in e.message
    refused(_textured_obj(tmp_path / "u", b"newmtl m\r\nMAP_KD\r\n"), "line 2: map_Kd names no file", "map_Kd")


# -- 10. what a fresh tester found (issue 30, second round) --------------------------------------------------------

def _scaled_gltf(folder, scale):
    path = MF.triangle_gltf(folder)
    tree = json.load(open(path))
    tree["nodes"] = [{"children": [1]}, {"mesh": 0, "scale": [scale] * 3}]
    json.dump(tree, open(path, "w"))
    return path


def _flat_ply(path, size):
    """A flat rectangle ``size`` × ``size`` / 2 (two triangles) written by trimesh (format by extension)."""
    V = np.array([[0, 0, 0], [size, 0, 0], [size, size / 2, 0], [0, size / 2, 0]], float)
    return MF.export(trimesh.Trimesh(V, [[0, 1, 2], [0, 2, 3]], process=False), path)


def test_a_car_absurdly_large_or_small_is_refused_naming_the_scale(tmp_path):
    # a node scale of 1e39: beyond float32 (the PLY held inf positions, exit 0)
    e = refused(_scaled_gltf(tmp_path / "huge", 1e39), "extent", "nodes[1].scale")
    assert f"{checks.MAX_EXTENT:g}" in e.message and "scale" in e.hint
    e = refused(_scaled_gltf(tmp_path / "tiny", 1e-30), "extent", "nodes[1].scale")
    assert f"{checks.MIN_EXTENT:g}" in e.message
    # without a node to blame: the extent itself
    refused(_flat_ply(tmp_path / "far.ply", 10 * checks.MAX_EXTENT), "extent", "(extent)")
    refused(_flat_ply(tmp_path / "dust.ply", checks.MIN_EXTENT / 10), "extent", "(extent)")
    # a car in millimetres, and a scale within the bounds, are read
    assert mesh_load.load_mesh(_flat_ply(tmp_path / "mm.ply", 4500.0)).vertices.max() == 4500.0
    assert mesh_load.load_mesh(_scaled_gltf(tmp_path / "ok", 4.0)).vertices.max() == pytest.approx(4.0)


def _obj_with_textures(folder, sizes, mode="1"):
    """An OBJ of one triangle per texture, each its own material (``map_Kd t<k>.png``), the textures cheap 1-bit
    PNGs of the given (w, h)."""
    folder.mkdir()
    mtl, obj = "", "mtllib car.mtl\nvt 0 0\nvt 1 0\nvt 0 1\n"
    for k, size in enumerate(sizes):
        Image.new(mode, size).save(folder / f"t{k}.png")
        mtl += f"newmtl m{k}\nKd 1 1 1\nmap_Kd t{k}.png\n"
        obj += f"v {k} 0 0\nv {k + 1} 0 0\nv {k} 1 0\nusemtl m{k}\nf {3 * k + 1}/1 {3 * k + 2}/2 {3 * k + 3}/3\n"
    (folder / "car.mtl").write_text(mtl)
    (folder / "car.obj").write_text(obj)
    return folder / "car.obj"


def test_the_total_texture_pixels_of_a_mesh_are_bounded_from_the_headers(tmp_path):
    assert checks.MAX_TOTAL_TEXTURE_PIXELS == 2 * checks.MAX_TEXTURE_PIXELS
    side = 8192
    e = refused(_obj_with_textures(tmp_path / "obj", [(side, side)] * 3), "3 textures", "(textures)")
    assert "t0.png" in e.message and "t2.png" in e.message and f"{3 * side * side:,}" in e.message
    # glTF: every image counts
    os.makedirs(tmp_path / "g")
    for k in range(3):
        Image.new("1", (side, side)).save(tmp_path / "g" / f"i{k}.png")
    refused(MF.triangle_gltf(tmp_path / "g", images=[{"uri": f"i{k}.png"} for k in range(3)]), "3 textures",
            "(textures)")
    # two at the bound are read
    assert len(mesh_load.load_mesh(_obj_with_textures(tmp_path / "two", [(64, 64)] * 2)).faces) == 2


# the peak resident memory of this process image (VmHWM: getrusage's ru_maxrss also counts the parent before exec)
_PEAK_SCRIPT = """
import sys
from backend.mesh import asset
import trimesh

def peak():
    return int(next(l for l in open("/proc/self/status") if l.startswith("VmHWM:")).split()[1]) * 1024

base = peak()
asset.convert(sys.argv[1], sys.argv[2], count=2000, warn=lambda *a: None)
print(peak() - base)
"""


def test_a_texture_is_decoded_once_without_copies(tmp_path):
    import subprocess
    import sys

    side = 4096
    path = _obj_with_textures(tmp_path / "o", [(side, side)], mode="RGB")
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    out = subprocess.run([sys.executable, "-c", _PEAK_SCRIPT, str(path), str(tmp_path / "o.ply")], cwd=root,
                         capture_output=True, text=True, check=True)
    grown = int(out.stdout.split()[-1])
    # PIL's decoded image (4 bytes a pixel) and one uint8 RGB array of it; trimesh's copies made it 4-5 times RGB
    assert grown < 3 * side * side * 3, grown / (side * side * 3)


def test_backslashes_in_texture_names_are_path_separators(tmp_path):
    # Windows-made files: textures\tex.png
    path = _textured_obj(tmp_path / "o", b"newmtl m\nKd 1 1 1\nmap_Kd textures\\tex.png\n", "textures/tex.png")
    r = ma.sample_gaussians(mesh_load.load_mesh(path), 50)
    assert r.colour_source == "texture" and MF.rgb_of(r.gaussians)[:, 0].min() > 0.7
    os.makedirs(tmp_path / "g" / "textures")
    Image.new("RGB", (4, 4), (200, 0, 0)).save(tmp_path / "g" / "textures" / "tex.png")
    r = ma.sample_gaussians(mesh_load.load_mesh(MF.triangle_gltf(tmp_path / "g", image_uri="textures\\tex.png")), 50)
    assert r.colour_source == "texture"
    # still confined to the mesh's folder
    Image.new("RGB", (4, 4)).save(tmp_path / "out.png")
    (tmp_path / "x").mkdir()
    refused(MF.triangle_gltf(tmp_path / "x", image_uri="..\\out.png"), "lies outside the mesh's folder", "..\\out.png")


def test_mtl_texture_options_are_read_as_options(tmp_path):
    ok = _textured_obj(tmp_path / "o", b"newmtl m\nKd 1 1 1\nmap_Kd -s 1 1 1 -o 0 0 0 -blendu on tex.png\n")
    asset = mesh_load.load_mesh(ok)
    assert asset.warnings == []                                  # options that change nothing: no word
    assert ma.sample_gaussians(asset, 50).colour_source == "texture"
    # options not applied (an offset, a scale): read, with a warning naming them; -clamp on is applied, unnamed
    asset = mesh_load.load_mesh(_textured_obj(tmp_path / "w", b"newmtl m\nmap_Kd -o 0.5 0 -clamp on tex.png\n"))
    assert [w["code"] for w in asset.warnings] == [mesh_load.TEXTURE_OPTIONS_IGNORED]
    assert "-o 0.5 0" in asset.warnings[0]["message"] and "-clamp" not in asset.warnings[0]["message"]
    # options without a file name; an option missing its value
    refused(_textured_obj(tmp_path / "n", b"newmtl m\nmap_Kd -s 1 1 1\n"), "map_Kd names no file", "map_Kd")
    refused(_textured_obj(tmp_path / "v", b"newmtl m\nmap_Kd -mm 0.1\n"), "map_Kd names no file", "map_Kd")
    # a file name with spaces after the options
    f = tmp_path / "sp"
    f.mkdir()
    Image.new("RGB", (4, 4), (200, 0, 0)).save(f / "my tex.png")
    (f / "car.mtl").write_text("newmtl m\nmap_Kd -bm 1 my tex.png\n")
    (f / "car.obj").write_text("mtllib car.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl m\n"
                               "f 1/1 2/2 3/3\n")
    assert ma.sample_gaussians(mesh_load.load_mesh(f / "car.obj"), 50).colour_source == "texture"


def test_a_texture_that_fails_to_decode_is_named(tmp_path):
    # a PNG whose header says 4 × 4 but holds 8 × 8 rows: only decoding finds it
    import struct
    import zlib

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xffffffff)

    raw = b"".join(b"\0" + b"\xc8\x00\x00" * 8 for _ in range(8))
    lying = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 4, 8, 2, 0, 0, 0))
             + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
    path = _textured_obj(tmp_path / "o", b"newmtl m\nKd 1 1 1\nmap_Kd tex.png\n")
    (tmp_path / "o" / "tex.png").write_bytes(lying)
    e = refused(path, "'tex.png' cannot be decoded", "tex.png")
    assert "trimesh cannot read it as a mesh" not in e.message


def test_pixel_counts_in_messages_are_exact(tmp_path):
    folder = tmp_path / "o"
    folder.mkdir()
    Image.new("1", (8193, 8192)).save(folder / "tex.png")
    (folder / "car.mtl").write_text("newmtl m\nmap_Kd tex.png\n")
    (folder / "car.obj").write_text("mtllib car.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    refused(folder / "car.obj", r"8193 × 8192 = 67,117,056 pixels, more than the 67,108,864", "tex.png")


def test_numpy_warnings_from_trimesh_are_not_printed(tmp_path):
    import warnings

    for ext in ("ply", "off"):   # flat: trimesh's mass properties divide by a zero volume
        events = []
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ma.convert(_flat_ply(tmp_path / f"flat.{ext}", 4.0), tmp_path / f"o_{ext}.ply", count=100,
                       warn=lambda *a: events.append(a))
        assert events == [] and [str(w.message) for w in caught] == []
