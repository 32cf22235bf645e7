"""bpy.ops.scpainter.import_gaussians on the procedural car saved as Amodal3R saves, and on edge cases."""

import os

import bpy
import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core import colors, shapes
from scpainter_blender.core.splats import (
    gaussians as splats,
    compressed as splats_compressed,
    inria as splats_inria,
    reader as splats_io,
)
from scpainter_blender.core.splats.sh import SH_C0
from tests_support import evaluated_counts, realdata


@pytest.fixture(scope="module")
def car_file(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("assets") / "car_01.ply")
    g = shapes.procedural_car_gaussians(count=4000, seed=3, paint=(0.8, 0.1, 0.1))
    A = shapes.save_as_amodal3r(path, g)
    return path, g, A


def _attr(obj, name, width):
    a = obj.data.attributes[name]
    prop = {"FLOAT": "value", "FLOAT_VECTOR": "vector", "QUATERNION": "value", "INT": "value"}[a.data_type]
    out = np.empty(len(obj.data.vertices) * width, np.float32 if a.data_type != "INT" else np.int32)
    a.data.foreach_get(prop, out)
    return out.reshape(-1, width) if width > 1 else out


def _evaluated(obj):
    return evaluated_counts(obj)


def test_import_amodal3r_car(empty_scene, car_file):
    path, g, A = car_file
    assert bpy.ops.scpainter.import_gaussians(filepath=path) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj["scpainter_kind"] == "gaussian_asset" and obj["scpainter_axes"] == "TRELLIS"
    assert obj["scpainter_source"] == os.path.abspath(path) and obj["scpainter_dropped"] == 0
    raw = splats_io.read_ply(path)
    N = len(raw)
    assert len(obj.data.vertices) == N == 4000
    # every file value kept, bit for bit
    assert np.array_equal(_attr(obj, "sh_0", 3), raw.f_dc)
    assert np.array_equal(_attr(obj, "opacity", 1), raw.opacity)
    assert np.array_equal(_attr(obj, "scale", 3), raw.scale)
    assert np.array_equal(_attr(obj, "rot", 4), raw.rot)
    assert np.array_equal(_attr(obj, "ply_nx", 1), raw.extra["nx"])
    # data frame: Z up, origin at the bottom centre; file_to_data maps the file onto it
    pos = _attr(obj, "position", 3).astype(np.float64)
    M = np.array(obj["scpainter_file_to_data"]).reshape(4, 4)
    assert np.abs(raw.xyz @ M[:3, :3].T + M[:3, 3] - pos).max() < 1e-6
    lo, hi = pos.min(0), pos.max(0)
    assert abs(lo[2]) < 1e-7 and np.allclose((lo[:2] + hi[:2]) / 2, 0, atol=1e-6)
    # the car's own shape comes back: up is up, its length along Y, scaled to 4.5 m by default
    world = pos * np.array(obj.scale)
    size = world.max(0) - world.min(0)
    assert size[1] == pytest.approx(4.5, rel=1e-5) and size[1] > size[0] and size[2] < size[0]
    s_file = np.cbrt(np.linalg.det(A[:3, :3]))
    expected = (g.means - g.means.min(0) * [0, 0, 1] - ((g.means.min(0) + g.means.max(0)) / 2) * [1, 1, 0])
    assert np.abs(pos - s_file * expected).max() < 1e-5
    # display rotations are the car's own (Z-up) orientations; scales its σ in data units
    q = _attr(obj, "gs_rotation", 4)
    assert np.abs(np.einsum("ij,ij->i", q, g.quats)).min() > 1 - 1e-4
    assert np.allclose(_attr(obj, "gs_scale", 3), s_file * g.scales, rtol=1e-4)
    # preview: sprites by default, one per Gaussian; ellipsoids as instances
    assert _evaluated(obj) == (N, 0)
    mod = obj.modifiers["SCPainter Gaussians"]
    from scpainter_blender.scene import node_groups

    node_groups.set_input(mod, "Ellipsoids", True)
    obj.update_tag()
    assert _evaluated(obj) == (0, N)


def test_render_shows_the_car_in_its_colour(empty_scene, car_file, tmp_path):
    path, _, _ = car_file
    bpy.ops.scpainter.import_gaussians(filepath=path, target_length=4.4)
    scene = empty_scene
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    w2c = np.eye(4)  # looking at the car's side from 8 m along -X, horizontally
    w2c[:3, :3] = [[0, 1, 0], [0, 0, -1], [-1, 0, 0]]
    w2c[:3, 3] = -w2c[:3, :3] @ np.array([8.0, 0.0, 0.7])
    from mathutils import Matrix

    cam.matrix_world = Matrix(C.blender_matrix_world(w2c).tolist())
    r = scene.render
    r.engine, r.resolution_x, r.resolution_y, r.film_transparent = "CYCLES", 64, 40, True
    scene.cycles.samples = 4
    scene.view_settings.view_transform = "Standard"
    r.image_settings.file_format, r.image_settings.color_mode = "PNG", "RGBA"
    r.filepath = str(tmp_path / "car.png")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(r.filepath)
    px = np.array(img.pixels[:], np.float32).reshape(40, 64, 4)
    solid = px[..., 3] > 0.9
    assert solid.mean() > 0.15
    body = px[solid][:, :3]
    red = (body[:, 0] > 0.6) & (body[:, 1] < 0.3) & (body[:, 2] < 0.3)
    assert red.mean() > 0.4  # most of the car's side is its red paint


def test_bad_rows_dropped_and_counted(empty_scene, tmp_path):
    g = shapes.procedural_car_gaussians(count=100, seed=0)
    raw = splats.encode(g)
    raw.rot[:3] = 0.0
    raw.xyz[5, 0] = np.nan
    raw.scale[7] = 200.0
    path = str(tmp_path / "bad_rows.ply")
    splats_inria.write_ply(path, raw)
    assert bpy.ops.scpainter.import_gaussians(filepath=path, axes="NONE") == {"FINISHED"}
    obj = bpy.context.active_object
    assert len(obj.data.vertices) == 95 and obj["scpainter_dropped"] == 5
    assert obj["scpainter_axes"] == "NONE"
    assert np.all(np.isfinite(_attr(obj, "gs_scale", 3)))


def test_bad_files_report_and_create_nothing(empty_scene, tmp_path):
    (tmp_path / "junk.ply").write_bytes(b"ply\nformat ascii 1.0\nend_header\n")
    with pytest.raises(RuntimeError, match="junk.ply.*ascii"):
        bpy.ops.scpainter.import_gaussians(filepath=str(tmp_path / "junk.ply"))
    raw = splats.encode(shapes.procedural_car_gaussians(count=10, seed=0))
    raw.rot[:] = 0.0
    splats_inria.write_ply(tmp_path / "allbad.ply", raw)
    with pytest.raises(RuntimeError, match="no valid Gaussians"):
        bpy.ops.scpainter.import_gaussians(filepath=str(tmp_path / "allbad.ply"))
    assert len(bpy.data.objects) == 0


def test_sh3_file_keeps_all_coefficients(empty_scene, tmp_path):
    rng = np.random.default_rng(0)
    N = 50
    raw = splats.GaussianPly(xyz=rng.normal(0, 1, (N, 3)).astype(np.float32),
                             f_dc=rng.normal(0, 1, (N, 3)).astype(np.float32),
                             f_rest=rng.normal(0, 0.1, (N, 3, 15)).astype(np.float32),
                             opacity=np.zeros(N, np.float32), scale=np.full((N, 3), -3, np.float32),
                             rot=np.tile([1, 0, 0, 0], (N, 1)).astype(np.float32))
    splats_inria.write_ply(tmp_path / "inria.ply", raw)
    assert bpy.ops.scpainter.import_gaussians(filepath=str(tmp_path / "inria.ply")) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj["scpainter_sh_degree"] == 3 and obj["scpainter_axes"] == "NONE"
    for k in range(1, 16):  # coefficient k of red, green, blue = f_rest[:, c, k-1]
        assert np.array_equal(_attr(obj, f"sh_{k}", 3), raw.f_rest[:, :, k - 1])
    assert obj.scale[0] == pytest.approx(1.0)  # file units kept


# -- files as other tools write them ---------------------------------------------------------------------------

def _trellis_car_to_the_cube_edge(path, reach=0.504):
    """A car written as TRELLIS does, its means pushed out to ±``reach``: TRELLIS' decoder lets a Gaussian sit up
    to 0.75 voxel of 64 off its voxel centre, so a car filling the cube reaches about ±0.504."""
    g = shapes.procedural_car_gaussians(count=3000, seed=4)
    shapes.save_as_amodal3r(path, g)
    raw = splats_io.read_ply(path)
    raw.xyz *= np.float32(reach / np.abs(raw.xyz).max())
    splats_inria.write_ply(path, raw)
    return raw


def test_trellis_car_reaching_past_the_unit_cube_stands_upright(empty_scene, tmp_path):
    path = str(tmp_path / "amodal3r_car.ply")
    raw = _trellis_car_to_the_cube_edge(path)
    assert np.abs(raw.xyz).max() > 0.5 + 1e-4  # what the old detection refused
    assert bpy.ops.scpainter.import_gaussians(filepath=path) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj["scpainter_axes"] == "TRELLIS" and "TRELLIS" in obj["scpainter_axes_reason"]
    size = np.array(obj["scpainter_size"])
    assert size[1] > size[0] > size[2]  # length along Y, upright: not lying on its side
    world = size * np.array(obj.scale)
    assert world[1] == pytest.approx(4.5, rel=1e-5)


def test_set_axes_flips_and_restores(empty_scene, tmp_path):
    path = str(tmp_path / "amodal3r_car.ply")
    _trellis_car_to_the_cube_edge(path)
    bpy.ops.scpainter.import_gaussians(filepath=path)
    obj = bpy.context.active_object
    pos0, q0 = _attr(obj, "position", 3).copy(), _attr(obj, "gs_rotation", 4).copy()
    D0, size0 = list(obj["scpainter_file_to_data"]), list(obj["scpainter_size"])
    length0 = max(size0[:2]) * obj.scale[0]
    assert bpy.ops.scpainter.check_assets() == {"FINISHED"} and obj["scpainter_stage1"] == "ok"
    assert bpy.ops.scpainter.set_asset_axes(axes="NONE") == {"FINISHED"}
    assert obj["scpainter_axes"] == "NONE" and "scpainter_stage1" not in obj  # measured on the old axes
    size1 = np.array(obj["scpainter_size"])
    assert size1[2] > size1[0]  # read as stored, the car's length is vertical: on its side
    assert max(size1[:2]) * obj.scale[0] == pytest.approx(length0, rel=1e-5)  # length kept
    raw = splats_io.read_ply(path)  # file_to_data still maps the file onto the new data frame
    M = np.array(obj["scpainter_file_to_data"]).reshape(4, 4)
    assert np.abs(raw.xyz @ M[:3, :3].T + M[:3, 3] - _attr(obj, "position", 3)).max() < 1e-6
    assert bpy.ops.scpainter.set_asset_axes(axes="TRELLIS") == {"FINISHED"}
    assert np.abs(_attr(obj, "position", 3) - pos0).max() < 1e-6
    assert np.abs(np.abs(np.einsum("ij,ij->i", _attr(obj, "gs_rotation", 4), q0)) - 1).max() < 1e-5
    assert np.allclose(obj["scpainter_file_to_data"], D0, atol=1e-7)
    assert np.allclose(obj["scpainter_size"], size0, atol=1e-6)


def test_supersplat_compressed_ply_imports(empty_scene):
    path = realdata("compressed/olgelta_longheadpiece_scene.compressed.ply")
    assert bpy.ops.scpainter.import_gaussians(filepath=path) == {"FINISHED"}
    obj = bpy.context.active_object
    assert len(obj.data.vertices) == 220_315 and obj["scpainter_format"] == "supersplat_compressed"
    assert obj["scpainter_axes"] == "NONE"
    assert np.all(np.isfinite(_attr(obj, "gs_scale", 3))) and np.all(np.isfinite(_attr(obj, "position", 3)))
    q = _attr(obj, "gs_rotation", 4)
    assert np.abs(np.linalg.norm(q, axis=1) - 1).max() < 1e-5


def test_splat_file_imports_like_its_ply(empty_scene, tmp_path):
    g = shapes.procedural_car_gaussians(count=500, seed=2, paint=(0.2, 0.6, 0.2))
    splats_compressed.write_splat(tmp_path / "car.splat", g)
    splats_inria.write_ply(tmp_path / "car.ply", splats.encode(g))
    assert bpy.ops.scpainter.import_gaussians(filepath=str(tmp_path / "car.ply")) == {"FINISHED"}
    from_ply = _attr(bpy.context.active_object, "position", 3).copy()
    assert bpy.ops.scpainter.import_gaussians(filepath=str(tmp_path / "car.splat")) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj["scpainter_format"] == "splat" and len(obj.data.vertices) == 500
    assert np.abs(_attr(obj, "position", 3) - from_ply).max() < 1e-5  # positions are float32 in both


def test_splat_glb_and_spz_import_as_gaussians_not_meshes(empty_scene, tmp_path):
    """A .glb with KHR_gaussian_splatting is Gaussians (decided by content; a .glb mesh goes to the backend), and
    an .spz imports too: both from splat-transform, the real writer."""
    import splat_transform
    from scpainter_blender.scene import gaussians
    g = shapes.procedural_car_gaussians(count=500, seed=3, paint=(0.6, 0.2, 0.2))
    splats_inria.write_ply(tmp_path / "car.ply", splats.encode(g))
    for name, fmt in (("car.glb", "gltf_splats"), ("car.spz", "spz")):
        splat_transform.convert(tmp_path / "car.ply", tmp_path / name)
        assert not gaussians.is_mesh_file(str(tmp_path / name))
        assert bpy.ops.scpainter.import_gaussians(filepath=str(tmp_path / name)) == {"FINISHED"}
        obj = bpy.context.active_object
        assert obj["scpainter_format"] == fmt and len(obj.data.vertices) == 500 and "scpainter_mesh_source" not in obj


def test_mesh_car_imports_through_the_backend_and_stage1_uses_its_oriented_box(empty_scene, tmp_path, monkeypatch):
    """A CAD-style car box, turned 30° about the up axis in its own file, written as a glTF (Y up): it becomes a
    Gaussian asset standing upright, and stage 1 measures it with trimesh's oriented box, not its axis-aligned
    bounds (which are 40 % too wide and would flag it)."""
    trimesh = pytest.importorskip("trimesh")
    from scpainter_blender.scene import placement

    box = trimesh.creation.box(extents=(1.9, 4.5, 1.5))  # width x, length y, height z (Z up)
    box.apply_translation((0.0, 0.0, 0.75))
    box.apply_transform(trimesh.transformations.rotation_matrix(np.radians(30.0), (0, 0, 1)))
    box.visual.vertex_colors = np.tile([200, 30, 30, 255], (len(box.vertices), 1)).astype(np.uint8)
    box.apply_transform(np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], float))  # Z up -> glTF Y up
    path = str(tmp_path / "library" / "cad_car.glb")
    os.makedirs(os.path.dirname(path))
    box.export(path)
    os.chmod(os.path.dirname(path), 0o555)  # asset libraries are often read-only: nothing is written beside them
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))  # the .blend is unsaved: the user's cache
    try:
        assert bpy.ops.scpainter.import_gaussians(filepath=path, mesh_count=4000) == {"FINISHED"}
    finally:
        os.chmod(os.path.dirname(path), 0o755)
    obj = bpy.context.active_object
    assert obj["scpainter_kind"] == "gaussian_asset" and obj["scpainter_mesh_source"] == path
    out = obj["scpainter_source"]
    assert os.path.isfile(out) and out.startswith(str(tmp_path / "cache" / "scpainter" / "assets"))
    assert os.path.basename(out).startswith("cad_car.glb.4000.")
    assert len(obj.data.vertices) == 4000 and obj["scpainter_axes"] == "NONE"
    assert obj["scpainter_axes_reason"] == "a mesh read Y up and turned Z up"
    assert obj.scale[0] == pytest.approx(1.0)  # a metric CAD car keeps its units
    size = np.array(obj["scpainter_size"])
    assert size[2] == pytest.approx(1.5, abs=0.05)  # upright: Y up in the file became Z up
    assert np.allclose(obj["scpainter_obb_size"], (4.5, 1.9, 1.5), atol=0.05)
    assert placement.stage1_check(obj)["status"] == "ok"
    aabb = placement.asset_size(obj)
    assert aabb[1] > 1.3 * 1.9  # what stage 1 would have measured without the oriented box
    colour = _attr(obj, "sh_0", 3) * SH_C0 + 0.5  # display (sRGB-encoded) values, as f_dc colours are
    srgb = colors.linear_to_srgb(np.array([200, 30, 30]) / 255)  # glTF's COLOR_0 is linear by the spec
    assert np.allclose(np.median(colour, axis=0), srgb, atol=0.01)


def test_meshes_of_one_name_never_share_their_gaussians(tmp_path, empty_scene, monkeypatch):
    """car.stl (grey) and car.ply (red) beside each other: each asset gets its own converted file, saved with the
    project once the .blend is saved; a millimetre CAD car is imported but the report says its length is odd."""
    trimesh = pytest.importorskip("trimesh")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    box = trimesh.creation.box(extents=(1.9, 4.5, 1.5))
    box.export(str(tmp_path / "car.stl"))
    box.visual.vertex_colors = np.tile([220, 20, 20, 255], (len(box.vertices), 1)).astype(np.uint8)
    box.export(str(tmp_path / "car.ply"))
    sources = []
    for name in ("car.stl", "car.ply"):
        assert bpy.ops.scpainter.import_gaussians(filepath=str(tmp_path / name), mesh_count=500) == {"FINISHED"}
        sources.append(bpy.context.active_object["scpainter_source"])
    assert sources[0] != sources[1]
    assert all(p.startswith("//scpainter/Scene/assets/") for p in sources)  # relative to the saved .blend (§9)
    sources = [os.path.normpath(bpy.path.abspath(p)) for p in sources]
    assert all(os.path.dirname(p) == str(tmp_path / "scpainter" / "Scene" / "assets") for p in sources)
    red = splats_io.read(sources[1]).f_dc * SH_C0 + 0.5
    grey = splats_io.read(sources[0]).f_dc * SH_C0 + 0.5
    assert red[:, 0].min() > 0.8 and np.allclose(grey, 0.5, atol=1e-6)
    mm = box.copy()
    mm.apply_scale(1000.0)
    mm.export(str(tmp_path / "car_mm.stl"))
    from scpainter_blender.scene import gaussians

    r = gaussians.import_gaussians(bpy.context, str(tmp_path / "car_mm.stl"), mesh_count=500)
    assert r.object.scale[0] == pytest.approx(1.0) and "4.5e+03 m long" in r.warnings[0]


def test_what_the_backend_read_past_in_a_mesh_is_in_the_import_report(tmp_path, empty_scene, monkeypatch):
    """Issue 30: mesh-asset's warnings (here trimesh going past a specular-glossiness material it cannot read)
    reach the import's warnings, which the operator reports, instead of only the backend's log."""
    import json

    trimesh = pytest.importorskip("trimesh")
    from scpainter_blender.scene import gaussians

    box = trimesh.creation.box(extents=(1.9, 4.5, 1.5))
    files = box.export(file_type="gltf")
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    tree = json.loads(files["model.gltf"])
    tree["materials"] = [{"extensions": {"KHR_materials_pbrSpecularGlossiness": {"diffuseFactor": "red"}}}]
    tree["meshes"][0]["primitives"][0]["material"] = 0
    (tmp_path / "model.gltf").write_text(json.dumps(tree))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    r = gaussians.import_gaussians(bpy.context, str(tmp_path / "model.gltf"), mesh_count=500)
    assert len(r.object.data.vertices) == 500
    assert r.warnings == [w["message"] for w in r.mesh["warnings"]] and "specular-glossiness" in r.warnings[0]


def test_the_import_tooltip_names_every_format(empty_scene):
    """The import's tooltip names the Gaussian formats from their records (core/splats/formats.py), those the
    backend converts saying so."""
    from scpainter_blender.core.splats import formats

    tip = bpy.ops.scpainter.import_gaussians.get_rna_type().description
    for f in formats.FORMATS:
        assert f.name + (", converted by the backend" if f.needs_backend else "") in tip, (f.key, tip)
