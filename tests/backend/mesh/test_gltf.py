"""glTF as today's tools write it (issue 31): the base-colour texture's ``KHR_texture_transform`` and ``texCoord``,
normalized integer accessors (core glTF 2.0 texture coordinates, ``KHR_mesh_quantization``), Draco
(``KHR_draco_mesh_compression``, encoded here with DracoPy), required extensions not read here (refused by name),
and external textures (missing, unreadable, percent-encoded names). Every input is written here: a unit quad whose
texture is a 4 x 4 grid of coloured cells, so the colour of each Gaussian says which texel it was read from; the
expected texel is computed here from the Gaussian's position by the extension's own formula."""

import json
import math
import os
import struct
import sys

import numpy as np
import pytest
from PIL import Image

from tests.backend.mesh import mesh_fixtures as MF
from backend.mesh import asset as ma
from backend.mesh import gltf as mesh_gltf, load as mesh_load
from scpainter_blender.core.splats import reader as splats_io
from tests_support import realdata, run_backend_here

CELL, GRID = 16, 4                     # texture: GRID x GRID cells of CELL px (64 x 64)
COLOURS = np.array([[(i * 80 + 15), (j * 80 + 15), 230 - 12 * (i + GRID * j)]
                    for j in range(GRID) for i in range(GRID)], np.uint8)   # cell (i, j): COLOURS[i + GRID j]
QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)   # glTF frame, facing +z
QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)


def base_uv(x, y):
    """The quad's texture coordinates (glTF convention: origin top-left, v down) at glTF position (x, y): the
    texture upright on the quad, a margin of 0.1 left around it."""
    return np.stack([0.1 + 0.8 * np.asarray(x), 0.1 + 0.8 * (1 - np.asarray(y))], axis=-1)


def transform_uv(uv, offset=(0, 0), rotation=0.0, scale=(1, 1)):
    """KHR_texture_transform written out from its README: uv' = T R S uv, with the README's GLSL matrices read
    column-major and the example ("offset [0, 1], rotation pi/2, scale 0.5: the lower left quadrant, rotated
    clockwise") holding: u' = ox + c sx u + s sy v, v' = oy - s sx u + c sy v."""
    u, v = uv[..., 0], uv[..., 1]
    c, s = math.cos(rotation), math.sin(rotation)
    return np.stack([offset[0] + c * scale[0] * u + s * scale[1] * v,
                     offset[1] - s * scale[0] * u + c * scale[1] * v], axis=-1)


def grid_png():
    img = np.zeros((GRID * CELL, GRID * CELL, 3), np.uint8)
    for j in range(GRID):
        for i in range(GRID):
            img[j * CELL:(j + 1) * CELL, i * CELL:(i + 1) * CELL] = COLOURS[i + GRID * j]
    import io

    out = io.BytesIO()
    Image.fromarray(img).save(out, format="PNG")
    return out.getvalue()


def _pad(blob):
    return blob + b"\0" * (-len(blob) % 4)


def quad_gltf(folder, name="quad.glb", *, uv_sets=None, uv_type=5126, tex_info=None, positions="float",
              node=None, normals=False, colours=None, draco=False, meshopt=False, required=(), image="embedded",
              image_bytes=None, sampler=None, material_name=None):
    """A textured unit quad written by hand as glTF 2.0 (``name`` .glb: one BIN chunk; .gltf: ``quad.bin``).

    ``uv_sets``: {set index: (4, 2) UVs, glTF convention} (default {0: ``base_uv`` of the corners});
    ``uv_type``: their componentType (5126 float; 5121 / 5123: UNSIGNED_BYTE / SHORT, normalized); ``tex_info``:
    more members of the baseColorTexture textureInfo (``texCoord``, ``extensions``); ``positions``: "float",
    "short_norm" (SHORT normalized, half size, node scale 2 undoes it), "short" (SHORT in mm, node scale 0.001);
    ``normals``: BYTE normalized normals; ``colours``: (4, 4) RGBA COLOR_0 as UNSIGNED_SHORT normalized (no
    texture then); ``draco``: positions, first UV set and indices in a KHR_draco_mesh_compression buffer (DracoPy);
    ``required``: more ``extensionsRequired``; ``image``: "embedded" (a bufferView), a URI (the file written as
    the URI names it, percent-decoded, unless ``image_bytes`` is b"" ) or None (no texture); ``sampler``: the
    texture's sampler (a ``samplers`` entry: wrapS / wrapT); ``material_name``: the material's ``name``."""
    from urllib.parse import unquote

    uv_sets = {0: base_uv(QUAD[:, 0], QUAD[:, 1])} if uv_sets is None else uv_sets
    blob, views, accessors, attrs, used = b"", [], [], {}, set(required)

    def add_view(data, stride=None):
        nonlocal blob
        blob = _pad(blob)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        if stride:
            views[-1]["byteStride"] = stride
        blob += data
        return len(views) - 1

    def add_accessor(data, ctype, kind, count, normalized=False, stride=None, **more):
        a = {"componentType": ctype, "type": kind, "count": count, **more}
        if data is not None:
            a["bufferView"] = add_view(data, stride)
        if normalized:
            a["normalized"] = True
        accessors.append(a)
        return len(accessors) - 1

    def strided(arr, width):  # rows padded to ``width`` bytes (vertex attributes are 4-byte aligned)
        rows = arr.reshape(len(arr), -1).view(np.uint8)
        out = np.zeros((len(arr), width), np.uint8)
        out[:, :rows.shape[1]] = rows
        return out.tobytes()

    node = dict(node or {})
    if draco:
        import DracoPy

        buf = DracoPy.encode(QUAD.astype(np.float32), QUAD_FACES, preserve_order=True, quantization_bits=16,
                             tex_coord=np.asarray(uv_sets[0], np.float64))
        ids = {a["attribute_type"]: a["unique_id"] for a in DracoPy.decode(buf).attributes}
        attrs["POSITION"] = add_accessor(None, 5126, "VEC3", 4, min=[0, 0, 0], max=[1, 1, 0])
        attrs["TEXCOORD_0"] = add_accessor(None, 5126, "VEC2", 4)
        indices = add_accessor(None, 5125, "SCALAR", 6)
        ext = {"bufferView": add_view(buf), "attributes": {"POSITION": ids[DracoPy.AttributeType.POSITION],
                                                           "TEXCOORD_0": ids[DracoPy.AttributeType.TEX_COORD]}}
        used |= {"KHR_draco_mesh_compression"}
        required = (*required, "KHR_draco_mesh_compression")
    else:
        if positions == "float":
            attrs["POSITION"] = add_accessor(QUAD.astype(np.float32).tobytes(), 5126, "VEC3", 4,
                                             min=[0, 0, 0], max=[1, 1, 0])
        elif positions == "short_norm":
            q = np.round(QUAD / 2 * 32767).astype(np.int16)
            attrs["POSITION"] = add_accessor(strided(q, 8), 5122, "VEC3", 4, normalized=True, stride=8,
                                             min=q.min(0).tolist(), max=q.max(0).tolist())
            node.setdefault("scale", [2, 2, 2])
            used |= {"KHR_mesh_quantization"}
        else:
            q = np.round(QUAD * 1000).astype(np.int16)
            attrs["POSITION"] = add_accessor(strided(q, 8), 5122, "VEC3", 4, stride=8,
                                             min=q.min(0).tolist(), max=q.max(0).tolist())
            node.setdefault("scale", [0.001] * 3)
            used |= {"KHR_mesh_quantization"}
        for k, uv in sorted(uv_sets.items()):
            uv = np.asarray(uv, np.float64)
            if uv_type == 5126:
                attrs[f"TEXCOORD_{k}"] = add_accessor(uv.astype(np.float32).tobytes(), 5126, "VEC2", 4)
            else:
                dt, top = (np.uint8, 255) if uv_type == 5121 else (np.uint16, 65535)
                q = np.round(uv * top).astype(dt)
                attrs[f"TEXCOORD_{k}"] = add_accessor(strided(q, 4), uv_type, "VEC2", 4, normalized=True, stride=4)
        indices = add_accessor(QUAD_FACES.tobytes(), 5125, "SCALAR", 6)
        ext = None
    if normals:
        attrs["NORMAL"] = add_accessor(strided(np.tile(np.array([0, 0, 127], np.int8), (4, 1)), 4), 5120, "VEC3",
                                       4, normalized=True, stride=4)
    if colours is not None:
        q = np.round(np.asarray(colours) * 65535).astype(np.uint16)
        attrs["COLOR_0"] = add_accessor(q.tobytes(), 5123, "VEC4", 4, normalized=True)
    prim = {"attributes": attrs, "indices": indices}
    if ext is not None:
        prim["extensions"] = {"KHR_draco_mesh_compression": ext}
    gltf = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, **node}],
            "meshes": [{"primitives": [prim]}], "accessors": accessors, "bufferViews": views}
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    if image is not None and colours is None:
        png = grid_png()
        if image == "embedded":
            gltf["images"] = [{"bufferView": add_view(png), "mimeType": "image/png"}]
        else:
            gltf["images"] = [{"uri": image}]
            if image_bytes != b"":
                with open(os.path.join(folder, unquote(image)), "wb") as f:
                    f.write(png if image_bytes is None else image_bytes)
        info = {"index": 0, **(tex_info or {})}
        for e in info.get("extensions", {}):
            used.add(e)
        gltf["textures"] = [{"source": 0}]
        gltf["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": info}}]
        if sampler is not None:
            gltf["samplers"] = [sampler]
            gltf["textures"][0]["sampler"] = 0
        if material_name is not None:
            gltf["materials"][0]["name"] = material_name
        prim["material"] = 0
    if used:
        gltf["extensionsUsed"] = sorted(used)
    if required:
        gltf["extensionsRequired"] = sorted(set(required))
    path = os.path.join(folder, name)
    blob = _pad(blob)
    if meshopt:
        for v in views:
            v["extensions"] = {"EXT_meshopt_compression": {"buffer": 0, "byteOffset": v["byteOffset"],
                                                           "byteLength": v["byteLength"], "byteStride": 4,
                                                           "count": v["byteLength"] // 4, "mode": "ATTRIBUTES"}}
            v["buffer"] = 1
        gltf["extensionsUsed"] = sorted(used | {"EXT_meshopt_compression"})
        gltf["extensionsRequired"] = sorted({*required, "EXT_meshopt_compression"})
    fallback = [{"byteLength": len(blob), "extensions": {"EXT_meshopt_fallback": {"fallback": True}}}] * meshopt
    if name.endswith(".glb"):
        gltf["buffers"] = [{"byteLength": len(blob)}, *fallback]
        with open(path, "wb") as f:
            f.write(MF.glb_bytes(gltf, blob))
    else:
        gltf["buffers"] = [{"uri": "quad.bin", "byteLength": len(blob)}, *fallback]
        with open(os.path.join(folder, "quad.bin"), "wb") as f:
            f.write(blob)
        with open(path, "w") as f:
            json.dump(gltf, f)
    return path


def expected_cells(means, **transform):
    """(cell index or -1, (N,)) the texel cell each Gaussian (Z-up means (N, 3); glTF x = x, y = z) must take its
    colour from, by ``transform_uv`` of ``base_uv``; -1 within one texel of a cell border (bilinear mixes there)."""
    uv = transform_uv(base_uv(means[:, 0], means[:, 2]), **transform) % 1.0
    px = uv * GRID * CELL                             # glTF: u right, v down from the image's top-left corner
    cell = np.floor(px / CELL).astype(int)
    edge = np.abs(px - CELL * np.round(px / CELL)).min(axis=1) < 1.0
    return np.where(edge, -1, cell[:, 0] + GRID * cell[:, 1])


def assert_texture_read_as_viewers_do(result, ply, **transform):
    """Every Gaussian away from a cell border has its cell's colour (exactly, up to float32 SH)."""
    g = splats_io.load(ply)
    cells = expected_cells(g.means.astype(np.float64), **transform)
    inner = cells >= 0
    assert inner.mean() > 0.5
    got = MF.rgb_of(g)[inner]
    want = COLOURS[cells[inner]].astype(np.float64) / 255
    bad = np.abs(got - want).max(axis=1) > 2e-3
    assert not bad.any(), f"{bad.sum()} of {inner.sum()} Gaussians have another texel's colour"
    assert result["colour_source"] == "texture"


def convert(path, tmp_path, count=1500):
    out = os.path.join(os.fspath(tmp_path), "out.gaussians.ply")
    return ma.convert(path, out, count=count, warn=lambda *a: None), out


# -- KHR_texture_transform and texCoord ----------------------------------------------------------------------------

TRANSFORMS = {
    "offset_scale": {"offset": [0.5, 0.5], "scale": [0.5, 0.5]},                      # one quadrant
    "readme_example": {"offset": [0, 1], "rotation": math.pi / 2, "scale": [0.5, 0.5]},  # lower left, rotated
    "all": {"offset": [0.3, -0.2], "rotation": 0.4, "scale": [0.7, 1.3]},
}


@pytest.mark.parametrize("name", sorted(TRANSFORMS))
def test_texture_transform_is_applied(tmp_path, name):
    t = TRANSFORMS[name]
    path = quad_gltf(tmp_path, tex_info={"extensions": {"KHR_texture_transform": t}})
    assert_texture_read_as_viewers_do(*convert(path, tmp_path), **t)


def test_texture_transform_rotation_turns_the_uvs_counter_clockwise_in_uv_space(tmp_path):
    """The README's example: offset (0, 1), rotation pi/2, scale 0.5 reads the lower-left quadrant (cells with
    i < 2, j >= 2); the opposite rotation would read the upper-right one."""
    t = TRANSFORMS["readme_example"]
    res, out = convert(quad_gltf(tmp_path, tex_info={"extensions": {"KHR_texture_transform": t}}), tmp_path)
    cells = expected_cells(splats_io.load(out).means.astype(np.float64), **t)
    cells = cells[cells >= 0]
    assert np.all(cells % GRID < 2) and np.all(cells // GRID >= 2)
    assert_texture_read_as_viewers_do(res, out, **t)


def test_texcoord_selects_the_uv_set(tmp_path):
    """textureInfo.texCoord = 1 reads TEXCOORD_1 (TEXCOORD_0 holds other UVs); the extension's texCoord overrides
    the textureInfo's."""
    real = base_uv(QUAD[:, 0], QUAD[:, 1])
    wrong = np.full((4, 2), 0.05)
    path = quad_gltf(tmp_path / "a", uv_sets={0: wrong, 1: real}, tex_info={"texCoord": 1})
    assert_texture_read_as_viewers_do(*convert(path, tmp_path / "a"))
    t = TRANSFORMS["offset_scale"]
    path = quad_gltf(tmp_path / "b", uv_sets={0: wrong, 1: real},
                     tex_info={"texCoord": 0, "extensions": {"KHR_texture_transform": {**t, "texCoord": 1}}})
    assert_texture_read_as_viewers_do(*convert(path, tmp_path / "b"), **t)


def test_a_texcoord_the_primitive_lacks_is_refused_naming_it(tmp_path):
    path = quad_gltf(tmp_path, tex_info={"texCoord": 2})
    with pytest.raises(mesh_load.MeshAssetError, match="TEXCOORD_2") as e:
        mesh_load.load_mesh(path)
    assert "quad.glb" in str(e.value)


def test_texture_transform_in_a_gltf_with_external_files(tmp_path):
    t = TRANSFORMS["all"]
    path = quad_gltf(tmp_path, "quad.gltf", image="car%20paint.png", tex_info={"extensions": {
        "KHR_texture_transform": t}}, required=("KHR_texture_transform",))
    assert_texture_read_as_viewers_do(*convert(path, tmp_path), **t)


# -- normalized and quantized accessors ------------------------------------------------------------------------------

@pytest.mark.parametrize("uv_type", [5121, 5123])
def test_normalized_integer_texture_coordinates(tmp_path, uv_type):
    path = quad_gltf(tmp_path, uv_type=uv_type)
    assert_texture_read_as_viewers_do(*convert(path, tmp_path))


@pytest.mark.parametrize("positions", ["short_norm", "short"])
def test_quantized_positions_with_their_node_transform(tmp_path, positions):
    """KHR_mesh_quantization: SHORT positions (normalized or not) that the node's scale turns into metres, BYTE
    normalized normals, UNSIGNED_SHORT normalized UVs with a texture transform (what gltfpack writes)."""
    t = TRANSFORMS["offset_scale"]
    path = quad_gltf(tmp_path, positions=positions, normals=True, uv_type=5123, required=("KHR_mesh_quantization",),
                     tex_info={"extensions": {"KHR_texture_transform": t}})
    res, out = convert(path, tmp_path)
    np.testing.assert_allclose(res["bounds"], [[0, 0, 0], [1, 0, 1]], atol=1e-4)
    assert_texture_read_as_viewers_do(res, out, **t)


@pytest.mark.parametrize("positions", ["float", "short_norm"])
def test_normalized_unsigned_short_vertex_colours(tmp_path, positions):
    """COLOR_0 as UNSIGNED_SHORT normalized, as trimesh reads it and as the plain GLB holds it (float32)."""
    rgba = np.array([[1, 0, 0, 1], [1, 0, 0, 1], [0, 0, 1, 1], [0, 0, 1, 1]], np.float64)
    res, out = convert(quad_gltf(tmp_path, colours=rgba, positions=positions), tmp_path)
    assert res["colour_source"] == "vertex"
    g = splats_io.load(out)
    rgb = MF.rgb_of(g)
    lo = g.means[:, 2] < 0.01                          # y = 0 edge: the red corners
    assert lo.any() and np.all(rgb[lo, 0] > 0.95) and np.all(rgb[lo, 2] < 0.2)
    assert rgb.max() <= 1 + 1e-3 and rgb.min() >= -1e-3


def test_normalize_values():
    """c / 255, c / 65535, max(c / 127, -1), max(c / 32767, -1) (glTF 2.0, 3.11)."""
    f = mesh_gltf.dequantize
    np.testing.assert_allclose(f(np.array([0, 255], np.uint8), True), [0, 1])
    np.testing.assert_allclose(f(np.array([0, 65535], np.uint16), True), [0, 1])
    np.testing.assert_allclose(f(np.array([-128, -127, 127], np.int8), True), [-1, -1, 1])
    np.testing.assert_allclose(f(np.array([-32768, 32767], np.int16), True), [-1, 1])
    np.testing.assert_allclose(f(np.array([-5, 7], np.int16), False), [-5, 7])


# -- Draco ---------------------------------------------------------------------------------------------------------

def test_draco_compressed_quad_loads_with_its_geometry_and_colours(tmp_path):
    res, out = convert(quad_gltf(tmp_path, draco=True), tmp_path)
    np.testing.assert_allclose(res["bounds"], [[0, 0, 0], [1, 0, 1]], atol=1e-4)
    assert res["faces"] == 2
    assert_texture_read_as_viewers_do(res, out)


def test_draco_with_a_texture_transform(tmp_path):
    t = TRANSFORMS["all"]
    path = quad_gltf(tmp_path, draco=True, tex_info={"extensions": {"KHR_texture_transform": t}})
    assert_texture_read_as_viewers_do(*convert(path, tmp_path), **t)


def test_draco_data_that_does_not_match_its_accessors_is_refused(tmp_path):
    path = quad_gltf(tmp_path, "quad.gltf", draco=True)
    with open(path) as f:
        tree = json.load(f)
    for a in tree["accessors"][:2]:                     # POSITION and TEXCOORD_0 claim 5 vertices; Draco holds 4
        a["count"] = 5
    with open(path, "w") as f:
        json.dump(tree, f)
    with pytest.raises(mesh_load.MeshAssetError, match="Draco data holds 4 POSITION values but accessors.0. "
                                                       "declares 5"):
        mesh_load.load_mesh(path)
    view = tree["bufferViews"][tree["meshes"][0]["primitives"][0]["extensions"][mesh_gltf.DRACO]["bufferView"]]
    data = bytearray((tmp_path / "quad.bin").read_bytes())
    data[view["byteOffset"]:view["byteOffset"] + view["byteLength"]] = bytes(view["byteLength"])  # not Draco
    (tmp_path / "quad.bin").write_bytes(bytes(data))
    for a in tree["accessors"][:2]:
        a["count"] = 4
    with open(path, "w") as f:
        json.dump(tree, f)
    with pytest.raises(mesh_load.MeshAssetError, match="Draco-compressed data cannot be decoded"):
        mesh_load.load_mesh(path)


def test_damaged_draco_is_refused_naming_the_extension_and_primitive(tmp_path):
    """Issue 42: Draco data that decodes into the wrong shape was reported as "trimesh cannot read it as a mesh
    (ValueError: cannot reshape array of size 8 into shape (4,3))", a missing attribute as "the car is 0 units
    across", a damaged face index as "its faces name vertices 0 to 255" — none naming Draco. Each now names
    KHR_draco_mesh_compression, the primitive and the attribute."""
    path = quad_gltf(tmp_path, "quad.gltf", draco=True)
    with open(path) as f:
        tree = json.load(f)
    ext = tree["meshes"][0]["primitives"][0]["extensions"][mesh_gltf.DRACO]
    ids = dict(ext["attributes"])
    where = r"meshes\[0\]\.primitives\[0\]: KHR_draco_mesh_compression: "
    for attributes, message, field in (
            ({"POSITION": ids["TEXCOORD_0"], "TEXCOORD_0": ids["POSITION"]},
             r"its Draco data gives POSITION 2 components per vertex, accessors\[0\] \(VEC3\) 3", "POSITION"),
            ({"POSITION": 7, "TEXCOORD_0": ids["TEXCOORD_0"]},
             "its Draco data has no attribute 7, which the extension names for POSITION", "POSITION")):
        ext["attributes"] = attributes
        with open(path, "w") as f:
            json.dump(tree, f)
        with pytest.raises(mesh_load.MeshAssetError, match=where + message) as e:
            mesh_load.load_mesh(path)
        assert e.value.field == f"meshes[0].primitives[0].extensions.KHR_draco_mesh_compression.attributes.{field}"
        assert "Draco" in e.value.hint
    ext["attributes"] = ids
    with open(path, "w") as f:
        json.dump(tree, f)
    view = tree["bufferViews"][ext["bufferView"]]
    data = bytearray((tmp_path / "quad.bin").read_bytes())
    payload = data[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]
    at = view["byteOffset"] + payload.find(QUAD_FACES.astype(np.uint8).tobytes())  # stored in order, one byte each
    data[at + 5] = 0xFF                                                               # the last index: 3 -> 255
    (tmp_path / "quad.bin").write_bytes(bytes(data))
    with pytest.raises(mesh_load.MeshAssetError, match=where + "its Draco data's faces name vertex 255, it decodes "
                                                               "4 vertices: a damaged payload"):
        mesh_load.load_mesh(path)


def test_draco_without_dracopy_is_refused_naming_the_fix(tmp_path, monkeypatch):
    path = quad_gltf(tmp_path, draco=True)
    monkeypatch.setitem(sys.modules, "DracoPy", None)   # an environment without DracoPy: import fails
    with pytest.raises(mesh_load.MeshAssetError, match="KHR_draco_mesh_compression") as e:
        mesh_load.load_mesh(path)
    assert "pip install DracoPy==2.2.0" in str(e.value.hint) and e.value.field == "extensionsRequired"


# -- required extensions not read here -------------------------------------------------------------------------------

def test_unsupported_required_extensions_are_refused_by_name(tmp_path):
    path = quad_gltf(tmp_path, meshopt=True, required=("EXT_mesh_gpu_instancing",))
    code, events, err = run_backend_here("mesh-asset", path, "--out", tmp_path / "o.ply", "--count", 100)
    assert code == 2 and "Traceback" not in err
    msg, hint = events[-1]["message"], events[-1]["hint"]
    assert "EXT_meshopt_compression" in msg and "EXT_mesh_gpu_instancing" in msg and "quad.glb" in msg
    assert events[-1]["field"] == "extensionsRequired" and "no uri" not in msg
    assert "gltfpack -i" in hint and "gltf-transform uninstance" in hint
    assert not (tmp_path / "o.ply").exists()


def test_supported_required_extensions_pass(tmp_path):
    path = quad_gltf(tmp_path, required=("KHR_materials_unlit", "KHR_texture_transform"),
                     tex_info={"extensions": {"KHR_texture_transform": {}}})
    assert_texture_read_as_viewers_do(*convert(path, tmp_path))


# -- sampler wrap modes ------------------------------------------------------------------------------------------------

REPEAT, CLAMP, MIRROR = 10497, 33071, 33648      # glTF 2.0 sampler.wrapS / wrapT (the OpenGL enums)


def wrapped_cell(t, mode):
    """(cell along one axis, near a cell border?) of texture coordinates ``t`` (N,) wrapped as the glTF
    specification's sampler says (OpenGL): REPEAT the fraction, CLAMP_TO_EDGE the edge texels beyond [0, 1],
    MIRRORED_REPEAT every other unit mirrored."""
    if mode == CLAMP:
        px = np.clip(t, 0.0, 1.0) * GRID * CELL        # beyond the image: its edge texels alone
    else:
        m = t % 2.0 if mode == MIRROR else t % 1.0
        px = np.where(m > 1.0, 2.0 - m, m) * GRID * CELL
    near = np.abs(px - CELL * np.round(px / CELL)) < 1.0
    on_edge = (mode == CLAMP) & ((px <= 0) | (px >= GRID * CELL))
    return np.floor(px / CELL).astype(int).clip(0, GRID - 1), near & ~on_edge


@pytest.mark.parametrize("wrap_s, wrap_t", [(CLAMP, CLAMP), (MIRROR, MIRROR), (REPEAT, REPEAT), (None, None),
                                            (CLAMP, MIRROR), (MIRROR, REPEAT)])
def test_sampler_wrap_modes_are_applied_to_each_sample(tmp_path, wrap_s, wrap_t):
    """UVs in [1.01, 1.99] (the texture's second copy): CLAMP_TO_EDGE reads the edge texels, MIRRORED_REPEAT the
    mirrored image, REPEAT (or no wrap given) the image as it is; wrapS for u, wrapT for v."""
    lo, span = 1.01, 0.98
    uv = np.stack([lo + span * QUAD[:, 0], lo + span * (1 - QUAD[:, 1])], axis=1)
    sampler = {k: v for k, v in (("wrapS", wrap_s), ("wrapT", wrap_t)) if v is not None}
    path = quad_gltf(tmp_path, uv_sets={0: uv}, sampler=sampler, material_name="paint")
    res, out = convert(path, tmp_path, count=3000)
    g = splats_io.load(out)
    x, y = g.means[:, 0].astype(np.float64), g.means[:, 2].astype(np.float64)   # glTF x, y
    (i, edge_i), (j, edge_j) = (wrapped_cell(lo + span * x, wrap_s or REPEAT),
                                wrapped_cell(lo + span * (1 - y), wrap_t or REPEAT))
    inner = ~(edge_i | edge_j)
    assert inner.mean() > 0.5 and res["colour_source"] == "texture"
    got = MF.rgb_of(g)[inner]
    want = COLOURS[(i + GRID * j)[inner]].astype(np.float64) / 255
    bad = np.abs(got - want).max(axis=1) > 2e-3
    assert not bad.any(), f"{bad.sum()} of {inner.sum()} Gaussians have another texel's colour"
    if wrap_s == CLAMP and wrap_t == CLAMP:  # all one colour: the corner texel at u = v = 1
        assert np.abs(MF.rgb_of(g) - COLOURS[GRID * GRID - 1] / 255).max() < 2e-3
    asset = mesh_load.load_mesh(path)
    assert asset.parts[0].visual.material.name == "paint"   # the marker plain_glb gives it is taken off again
    assert asset.wraps in ([], [(wrap_s or REPEAT, wrap_t or REPEAT)])


def _edited(tmp_path, edit):
    """The quad as .gltf with ``edit(gltf JSON)`` applied."""
    path = quad_gltf(tmp_path, "quad.gltf", sampler={"wrapS": CLAMP})
    with open(path) as f:
        tree = json.load(f)
    edit(tree)
    with open(path, "w") as f:
        json.dump(tree, f)
    return path


@pytest.mark.parametrize("field, edit", [
    ("materials[0].pbrMetallicRoughness.baseColorTexture.index",
     lambda t: t["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"].update(index=5)),
    ("textures[0].source", lambda t: t["textures"][0].update(source=1)),
    ("textures[0].sampler", lambda t: t["textures"][0].update(sampler=3)),
    ("samplers[0].wrapS", lambda t: t["samplers"][0].update(wrapS=9729)),
])
def test_texture_indices_out_of_range_exit_2_naming_the_field(tmp_path, field, edit):
    """A base-colour texture, image or sampler index the file does not have: trimesh went on with a log line
    and a white car (exit 0); a missing texture file is an error, so is this."""
    path = _edited(tmp_path, edit)
    code, events, err = run_backend_here("mesh-asset", path, "--out", tmp_path / "o.ply", "--count", 100)
    assert code == 2 and "Traceback" not in err
    assert events[-1]["event"] == "error" and events[-1]["field"] == field and field in events[-1]["message"]
    assert not (tmp_path / "o.ply").exists()


# -- external textures -------------------------------------------------------------------------------------------------

def test_percent_encoded_texture_name_is_read(tmp_path):
    path = quad_gltf(tmp_path, "quad.gltf", image="car%20paint.png")
    assert os.path.exists(tmp_path / "car paint.png")
    assert_texture_read_as_viewers_do(*convert(path, tmp_path))


@pytest.mark.parametrize("uri, data, what", [("tex.png", b"", "not found"),
                                            ("car%20paint.png", b"not a png", "cannot be read as an image"),
                                            ("%2E%2E/outside.png", None, "outside the mesh's folder")])
def test_texture_problems_exit_2_naming_the_file(tmp_path, uri, data, what):
    folder = tmp_path / "car"
    folder.mkdir()
    if data is None:  # the file exists, one folder up
        (tmp_path / "outside.png").write_bytes(grid_png())
        data = b""
    path = quad_gltf(folder, "quad.gltf", image=uri, image_bytes=data)
    code, events, err = run_backend_here("mesh-asset", path, "--out", tmp_path / "o.ply", "--count", 100)
    assert code == 2 and "Traceback" not in err
    assert events[-1]["event"] == "error" and uri in events[-1]["message"] and what in events[-1]["message"]
    assert not (tmp_path / "o.ply").exists()


@pytest.mark.parametrize("uri", ["file:///tmp/paint.png", "FILE:paint.png"])
def test_file_uri_texture_is_refused_as_a_file_uri(tmp_path, uri):
    """A ``file://`` URI (an absolute path, which the model's folder rule does not allow) is said to be one, not
    "not found"."""
    path = quad_gltf(tmp_path, "quad.gltf", image=uri, image_bytes=b"")
    code, events, err = run_backend_here("mesh-asset", path, "--out", tmp_path / "o.ply", "--count", 100)
    assert code == 2 and "Traceback" not in err
    message = events[-1]["message"]
    assert uri in message and "file:// URI" in message and "not found" not in message
    assert "relative to the mesh" in events[-1]["hint"]


# -- a real file -----------------------------------------------------------------------------------------------------

def test_real_trellis_glb_still_converts(tmp_path):
    path = realdata("trellis/uanu2002_trellis_sample.glb")
    res, out = convert(path, tmp_path, count=2000)
    assert res["colour_source"] == "texture" and res["count"] == 2000


@pytest.mark.parametrize("t, said", [({"offset": ["a", "b"]}, r"offset is \['a', 'b'\], not 2 finite numbers"),
                                     ({"scale": [1e400, 1]}, r"scale is \[inf, 1\], not 2 finite numbers"),
                                     ({"rotation": "1"}, "rotation is 1, not a finite number")])
def test_malformed_texture_transform_is_refused_by_field(tmp_path, t, said):
    """Fuzz finding (tests/fuzz_surfaces.py ``gltf paths``, issue 31): strings in KHR_texture_transform were a
    ValueError traceback; non-finite values now name the extension, not the UVs they would give."""
    path = quad_gltf(tmp_path, tex_info={"extensions": {"KHR_texture_transform": t}})
    with pytest.raises(mesh_load.MeshAssetError, match=r"meshes\[0\]\.primitives\[0\]: its base-colour texture's "
                                                       r"KHR_texture_transform: " + said) as e:
        mesh_load.load_mesh(path)
    assert "quad.glb" in str(e.value) and e.value.field.endswith("baseColorTexture.extensions.KHR_texture_transform")
