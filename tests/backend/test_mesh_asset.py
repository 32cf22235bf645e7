"""Mesh assets (``backend.mesh_asset``, ``python -m backend mesh-asset``): axes, colours, flat Gaussians, the upright
box, the TRELLIS GLB/PLY pose, the mask against the mesh's silhouette, the command, and real TRELLIS files."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from PIL import Image

from backend import mesh_asset as ma
from scpainter_blender.core import cameras, splats
from scpainter_blender.core.colors import linear_to_srgb

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
R_GLTF = ma.Y_UP_TO_Z_UP            # p_zup = R_GLTF @ p_gltf
TRELLIS_GLB = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # to_glb: vertices @ TRELLIS_GLB


def realdata(relpath):
    """A real public file from ``../shared/realdata`` (or ``$SCPAINTER_REALDATA``), or skip saying where it looked.
    These files are never copied into the repository."""
    root = os.environ.get("SCPAINTER_REALDATA") or os.path.join(ROOT, "..", "shared", "realdata")
    path = os.path.join(root, relpath)
    if not os.path.isfile(path):
        pytest.skip(f"real data file {relpath} not found under {os.path.abspath(root)} (set SCPAINTER_REALDATA)")
    return os.path.abspath(path)


def rgb_of(g):
    return splats.SH_C0 * g.sh[:, 0].astype(np.float64) + 0.5


def normals_of(g):
    return cameras.quaternion_to_rotation(g.quats.astype(np.float64))[:, :, 2]


def split_triangles(vertices, faces):
    """Every triangle with its own three vertices (so per-triangle UVs and colours are free)."""
    tri = np.asarray(vertices, float)[np.asarray(faces)]
    return tri.reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3)


def car_like_zup():
    """An asymmetric test object, Z up: a 4 x 2 x 1 body on z = 0 and a mast at its (+x, +y) corner."""
    body = trimesh.creation.box((4.0, 2.0, 1.0), trimesh.transformations.translation_matrix((0, 0, 0.5)))
    mast = trimesh.creation.box((0.4, 0.4, 1.0), trimesh.transformations.translation_matrix((1.6, 0.7, 1.5)))
    return trimesh.util.concatenate([body, mast])


def cell_texture(colours, cell=16):
    """A 3 x 2 grid of uniform cells (uint8 RGB colours (6, 3)), and a function giving UVs inside cell k."""
    img = np.zeros((2 * cell, 3 * cell, 3), np.uint8)
    for k, c in enumerate(colours):
        i, j = k % 3, k // 3
        img[j * cell:(j + 1) * cell, i * cell:(i + 1) * cell] = c

    def uv_in_cell(k, n):  # n points well inside cell k (trimesh's V: v = 1 is the image's top row)
        i, j = k % 3, k // 3
        centre = np.array([(i + 0.5) / 3, 1 - (j + 0.5) / 2])
        ring = np.array([[-0.3, -0.3], [0.3, -0.3], [0.0, 0.3]])[:n]
        return centre + ring * np.array([1 / 3, 1 / 2])

    return Image.fromarray(img), uv_in_cell


def export(mesh, path):
    mesh.export(os.fspath(path))
    return os.fspath(path)


# -- axes ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("ext", [".glb", ".gltf", ".obj"])
def test_y_up_files_land_z_up(tmp_path, ext):
    zup = car_like_zup()
    yup = trimesh.Trimesh(np.asarray(zup.vertices) @ R_GLTF, zup.faces, process=False)  # p_gltf = R^T p_zup
    path = export(yup, tmp_path / f"car{ext}")
    asset = ma.load_mesh(path)
    assert asset.up == "y"
    V = asset.vertices
    np.testing.assert_allclose(V.min(axis=0), [-2, -1, 0], atol=1e-6)
    np.testing.assert_allclose(V.max(axis=0), [2, 1, 2], atol=1e-6)
    top = V[V[:, 2] > 1.99]
    assert len(top) and (top[:, 0] > 1.3).all() and (top[:, 1] > 0.4).all()  # the mast: +x, +y, on top
    g = ma.mesh_to_gaussians(asset, 5000, seed=1)
    high = g.means[g.means[:, 2] > 1.5]
    assert len(high) and (high[:, 0] > 1.3).all() and (high[:, 1] > 0.4).all()
    # --up z keeps the file's own axes
    np.testing.assert_allclose(ma.load_mesh(path, up="z").vertices.max(axis=0), [2, 2, 1], atol=1e-6)


def test_z_up_formats_are_read_as_stored(tmp_path):
    zup = car_like_zup()
    for ext in (".ply", ".stl", ".off"):
        asset = ma.load_mesh(export(zup, tmp_path / f"car{ext}"))
        assert asset.up == "z"
        np.testing.assert_allclose(asset.vertices.max(axis=0), [2, 1, 2], atol=1e-6)
    np.testing.assert_allclose(ma.load_mesh(tmp_path / "car.ply", up="y").vertices.max(axis=0), [2, 0, 1],
                               atol=1e-6)


def test_scene_node_transforms_are_applied(tmp_path):
    scene = trimesh.Scene()
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    scene.add_geometry(box, node_name="a", transform=trimesh.transformations.translation_matrix((5, 0, 0)))
    scene.add_geometry(box, node_name="b", transform=trimesh.transformations.translation_matrix((0, 3, 0)))
    asset = ma.load_mesh(export(scene, tmp_path / "two.glb"))
    assert len(asset.parts) == 2
    # glTF (5, 0, 0) and (0, 3, 0) -> Z up (5, 0, 0) and (0, 0, 3)
    centres = sorted(tuple(np.round(p.vertices.mean(axis=0), 6)) for p in asset.parts)
    assert centres == [(0.0, 0.0, 3.0), (5.0, 0.0, 0.0)]


# -- colours -------------------------------------------------------------------------------------------------------

def test_textured_box_faces_take_their_texture_colour(tmp_path):
    colours = np.array([[230, 20, 20], [20, 200, 30], [30, 40, 220], [240, 230, 20], [20, 220, 230], [200, 30, 210]],
                       np.uint8)
    image, uv_in_cell = cell_texture(colours)
    box = trimesh.creation.box((2.0, 1.0, 0.5))
    V, F = split_triangles(box.vertices, box.faces)
    normals_gltf = box.face_normals
    axes = [tuple(np.round(n).astype(int)) for n in normals_gltf]
    cell_of_normal = {n: k for k, n in enumerate(sorted(set(axes)))}
    uv = np.concatenate([uv_in_cell(cell_of_normal[n], 3) for n in axes])
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=image, baseColorFactor=[255, 255, 255, 255])
    mesh = trimesh.Trimesh(V, F, visual=trimesh.visual.TextureVisuals(uv=uv, material=mat), process=False)
    res = ma.sample_gaussians(ma.load_mesh(export(mesh, tmp_path / "box.glb")), 3000, seed=2)
    assert res.colour_source == "texture" and res.colour_counts == {"texture": 3000}
    g = res.gaussians
    n_gltf = normals_of(g) @ R_GLTF            # back to the file's axes: R^T n
    expect = np.array([colours[cell_of_normal[tuple(np.round(n).astype(int))]] for n in n_gltf]) / 255.0
    np.testing.assert_allclose(rgb_of(g), expect, atol=1e-5)
    assert len({tuple(c) for c in np.round(rgb_of(g), 3)}) == 6


def test_texture_sampling_conventions():
    img = np.arange(4 * 3 * 3, dtype=np.uint8).reshape(4, 3, 3) * 7
    i, j = np.meshgrid(np.arange(3), np.arange(4))
    uv = np.stack([(i.ravel() + 0.5) / 3, 1 - (j.ravel() + 0.5) / 4], axis=1)   # texel centres
    np.testing.assert_allclose(ma.sample_texture(img, uv), img.reshape(-1, 3) / 255.0, atol=1e-12)
    np.testing.assert_allclose(ma.sample_texture(img, uv + 1.0), img.reshape(-1, 3) / 255.0, atol=1e-12)  # REPEAT
    mid = ma.sample_texture(img, [[1.0 / 3, 1 - 0.5 / 4]])[0]                          # halfway, texels 0 and 1
    np.testing.assert_allclose(mid, (img[0, 0] + img[0, 1]) / 2 / 255.0, atol=1e-12)
    assert np.isnan(ma.sample_texture(img, [[np.nan, 0.5]])).all()


def test_glb_base_colour_factor_is_linear(tmp_path):
    box = trimesh.creation.box()
    image, _ = cell_texture(np.full((6, 3), 255, np.uint8))
    uv = np.full((len(box.vertices), 2), 0.5)
    factor = np.array([0.5, 0.25, 1.0, 1.0])                  # linear, as glTF says
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=image, baseColorFactor=factor)
    box.visual = trimesh.visual.TextureVisuals(uv=uv, material=mat)
    g = ma.mesh_to_gaussians(ma.load_mesh(export(box, tmp_path / "f.glb")), 200)
    expect = linear_to_srgb(np.round(factor[:3] * 255) / 255)   # trimesh stores the factor as 8 bit
    np.testing.assert_allclose(rgb_of(g), np.tile(expect, (200, 1)), atol=1e-5)
    plain = trimesh.creation.box()
    plain.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        baseColorFactor=factor))
    res = ma.sample_gaussians(ma.load_mesh(export(plain, tmp_path / "plain.glb")), 100)
    assert res.colour_source == "face"
    np.testing.assert_allclose(rgb_of(res.gaussians), np.tile(expect, (100, 1)), atol=1e-5)


def test_vertex_colours_are_interpolated(tmp_path):
    tri = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False,
                          vertex_colors=[[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255]])
    res = ma.sample_gaussians(ma.load_mesh(export(tri, tmp_path / "tri.ply")), 500, seed=3)
    assert res.colour_source == "vertex"
    x, y = res.gaussians.means[:, 0].astype(float), res.gaussians.means[:, 1].astype(float)
    np.testing.assert_allclose(rgb_of(res.gaussians), np.stack([1 - x - y, x, y], axis=1), atol=1e-5)
    # glTF COLOR_0 is linear: stored as sRGB in the Gaussians
    grey = trimesh.creation.box()
    grey.visual.vertex_colors = np.tile([51, 51, 51, 255], (len(grey.vertices), 1))
    res = ma.sample_gaussians(ma.load_mesh(export(grey, tmp_path / "grey.glb")), 50)
    assert res.colour_source == "vertex"
    np.testing.assert_allclose(rgb_of(res.gaussians), linear_to_srgb(51 / 255), atol=1e-5)


def test_face_colours_and_no_colours(tmp_path):
    box = trimesh.creation.box()
    box.visual.face_colors = np.tile([200, 100, 50, 255], (len(box.faces), 1))
    res = ma.sample_gaussians(ma.load_mesh(export(box, tmp_path / "faces.ply")), 100)
    assert res.colour_source == "face"
    np.testing.assert_allclose(rgb_of(res.gaussians), np.tile([200 / 255, 100 / 255, 50 / 255], (100, 1)), atol=1e-5)
    res = ma.sample_gaussians(ma.load_mesh(export(trimesh.creation.box(), tmp_path / "bare.stl")), 100)
    assert res.colour_source == "none"
    np.testing.assert_allclose(res.gaussians.sh, 0.0, atol=1e-7)      # neutral grey 0.5: f_dc = 0


def test_textured_obj_round_trip(tmp_path):
    colours = np.array([[250, 10, 10], [10, 250, 10], [10, 10, 250], [250, 250, 10], [10, 250, 250],
                        [250, 10, 250]], np.uint8)
    image, uv_in_cell = cell_texture(colours)
    zup = car_like_zup()
    V, F = split_triangles(np.asarray(zup.vertices) @ R_GLTF, zup.faces)
    uv = np.concatenate([uv_in_cell(k % 6, 3) for k in range(len(F))])
    mesh = trimesh.Trimesh(V, F, process=False, visual=trimesh.visual.TextureVisuals(
        uv=uv, material=trimesh.visual.material.SimpleMaterial(image=image)))
    os.makedirs(tmp_path / "obj")
    asset = ma.load_mesh(export(mesh, tmp_path / "obj" / "car.obj"))
    assert asset.up == "y"
    np.testing.assert_allclose(asset.vertices.min(axis=0), [-2, -1, 0], atol=1e-5)
    np.testing.assert_allclose(asset.vertices.max(axis=0), [2, 1, 2], atol=1e-5)
    res = ma.sample_gaussians(asset, 2000, seed=4)
    assert res.colour_source == "texture"
    got = np.round(rgb_of(res.gaussians) * 255)
    assert {tuple(c) for c in got.astype(int)} <= {tuple(c) for c in colours.astype(int)}


# -- Gaussians -----------------------------------------------------------------------------------------------------

def test_gaussian_normals_are_face_normals():
    mesh = trimesh.creation.icosphere(subdivisions=1)
    res = ma.sample_gaussians(mesh, 3000, seed=5)
    g = res.gaussians
    tri = np.asarray(mesh.vertices)[mesh.faces]
    # the face each mean lies on: in its plane and inside it
    n = mesh.face_normals
    d = np.einsum("fc,nc->nf", n, g.means.astype(float)) - np.einsum("fc,fc->f", n, tri[:, 0])
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    rel = g.means.astype(float)[:, None, :] - tri[None, :, 0]
    den = np.einsum("fc,fc->f", e1, e1) * np.einsum("fc,fc->f", e2, e2) - np.einsum("fc,fc->f", e1, e2) ** 2
    b1 = (np.einsum("nfc,fc->nf", rel, e1) * np.einsum("fc,fc->f", e2, e2)
          - np.einsum("nfc,fc->nf", rel, e2) * np.einsum("fc,fc->f", e1, e2)) / den
    b2 = (np.einsum("nfc,fc->nf", rel, e2) * np.einsum("fc,fc->f", e1, e1)
          - np.einsum("nfc,fc->nf", rel, e1) * np.einsum("fc,fc->f", e1, e2)) / den
    on = (np.abs(d) < 1e-5) & (b1 > -1e-5) & (b2 > -1e-5) & (b1 + b2 < 1 + 1e-5)
    assert on.any(axis=1).all()
    face = np.argmax(on, axis=1)
    np.testing.assert_allclose(normals_of(g), n[face], atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(g.quats, axis=1), 1.0, atol=1e-6)
    assert (g.opacities == np.float32(ma.OPACITY)).all() and g.sh.shape == (3000, 1, 3)


def test_sigma_follows_the_sampling_density():
    box = trimesh.creation.box((2.0, 1.0, 0.5))
    a = ma.sample_gaussians(box, 1000)
    assert a.area == pytest.approx(box.area)
    assert a.sigma == pytest.approx(ma.SIGMA_FACTOR * np.sqrt(box.area / 1000))
    np.testing.assert_allclose(a.gaussians.scales, np.tile([a.sigma, a.sigma, ma.NORMAL_RATIO * a.sigma], (1000, 1)),
                               rtol=1e-6)
    assert (a.gaussians.scales[:, 2] > 0).all()
    assert ma.sample_gaussians(box, 4000).sigma == pytest.approx(a.sigma / 2)
    big = box.copy()
    big.apply_scale(3.0)
    assert ma.sample_gaussians(big, 1000).sigma == pytest.approx(3 * a.sigma)
    assert ma.sample_gaussians(box, 1000, sigma_factor=0.5).sigma == pytest.approx(0.5 * a.sigma / ma.SIGMA_FACTOR)


def test_same_seed_same_gaussians():
    box = trimesh.creation.box()
    a, b = ma.mesh_to_gaussians(box, 500, seed=7), ma.mesh_to_gaussians(box, 500, seed=7)
    np.testing.assert_array_equal(a.means, b.means)
    assert not np.array_equal(a.means, ma.mesh_to_gaussians(box, 500, seed=8).means)


def test_degenerate_faces_and_nan_vertices_make_no_nan(tmp_path):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],          # a good triangle
                  [2, 0, 0], [3, 0, 0], [4, 0, 0],          # collinear: zero area
                  [np.nan, 0, 0], [5, 5, 5], [6, 5, 5],     # a NaN corner
                  [7, 7, 7]], float)
    F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 9, 9], [0, 0, 1]])
    mesh = trimesh.Trimesh(V, F, process=False, validate=False)
    res = ma.sample_gaussians(mesh, 2000, seed=0)
    g = res.gaussians
    assert len(g) == 2000 and res.dropped == 0
    for a in (g.means, g.scales, g.quats, g.opacities, g.sh):
        assert np.isfinite(a).all()
    assert (g.means[:, 2] == 0).all() and (g.means[:, :2] >= -1e-7).all() and (g.means[:, :2].sum(1) <= 1 + 1e-6).all()
    assert res.area == pytest.approx(0.5)
    out = tmp_path / "g.ply"
    splats.write_ply(out, splats.encode(g))
    assert splats.load(out).dropped == {}
    with pytest.raises(ValueError, match="no face with a positive"):
        ma.sample_gaussians(trimesh.Trimesh(V[3:6], [[0, 1, 2]], process=False), 10)


@pytest.mark.parametrize("make, what", [
    (lambda p: p.write_bytes(b"garbage"), "trimesh cannot read"),
    (lambda p: trimesh.PointCloud(np.random.default_rng(0).random((20, 3))).export(os.fspath(p)), "point cloud"),
])
def test_bad_files_raise_naming_the_file(tmp_path, make, what):
    path = tmp_path / ("broken.glb" if "trimesh" in what else "cloud.ply")
    make(path)
    with pytest.raises(ValueError, match=what) as e:
        ma.load_mesh(path)
    assert path.name in str(e.value)


def test_other_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="file not found"):
        ma.load_mesh(tmp_path / "missing.glb")
    (tmp_path / "car.fbx").write_bytes(b"x")
    with pytest.raises(ValueError, match="not a mesh format"):
        ma.load_mesh(tmp_path / "car.fbx")
    g = ma.mesh_to_gaussians(trimesh.creation.box(), 50)
    splats.write_ply(tmp_path / "splat.ply", splats.encode(g))
    with pytest.raises(ValueError, match="Gaussian-splat PLY"):
        ma.load_mesh(tmp_path / "splat.ply")
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(ValueError, match="zero"):
        ma.load_mesh(export(flat, tmp_path / "flat.ply"))


# -- stage-1 box ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("yaw", [0.0, 30.0, -55.0, 90.0, 12.5])
def test_upright_box_of_a_rotated_car(yaw):
    L, W, H = 4.5, 1.9, 1.5
    box = trimesh.creation.box((W, L, H))                  # length along local +Y, as the project's boxes
    T = trimesh.transformations.rotation_matrix(np.radians(yaw), (0, 0, 1))
    T[:3, 3] = (10.0, -3.0, H / 2)
    box.apply_transform(T)
    ob = ma.upright_box(box.vertices)
    np.testing.assert_allclose(ob["size"], [L, W, H], atol=1e-6)
    assert ob["yaw_deg"] == pytest.approx(yaw, abs=1e-6)
    np.testing.assert_allclose(ob["center"], [10.0, -3.0, H / 2], atol=1e-6)
    np.testing.assert_allclose(ma.oriented_box_3d(box.vertices), [L, W, H], atol=1e-4)
    if yaw in (30.0, -55.0):   # the axis-aligned box is wrong by far more than the 20 % stage-1 tolerance
        aabb = np.array(ob["aabb_size"])
        assert np.abs(aabb[1] / W - 1) > 0.2


def test_upright_box_of_degenerate_footprints():
    line = np.array([[0, 0, 0], [1, 1, 0], [2, 2, 1]], float)
    ob = ma.upright_box(line)
    assert ob["size"][0] == pytest.approx(2 * np.sqrt(2)) and ob["size"][1] == pytest.approx(0, abs=1e-9)
    assert ob["yaw_deg"] == pytest.approx(-45.0)
    assert ma.upright_box([[1, 2, 3]])["size"] == [0.0, 0.0, 0.0]


# -- TRELLIS: the GLB and the Gaussian PLY of one asset land in the same pose -------------------------------------

def test_trellis_glb_and_gaussian_ply_share_a_pose(tmp_path):
    # one object in TRELLIS's Z-up frame, inside the unit cube, asymmetric (the mast at +x, +y, top)
    obj = car_like_zup()
    obj.apply_translation((0, 0, -1.0))
    obj.apply_scale(0.24)
    V, F = split_triangles(obj.vertices, obj.faces)
    image, uv_in_cell = cell_texture(np.array([[200, 50, 50]] * 6, np.uint8))
    uv = np.concatenate([uv_in_cell(0, 3) for _ in range(len(F))])
    # to_glb: vertices @ [[1,0,0],[0,0,-1],[0,1,0]], a TextureVisuals/PBRMaterial Trimesh, exported by trimesh
    mat = trimesh.visual.material.PBRMaterial(roughnessFactor=1.0, baseColorTexture=image,
                                              baseColorFactor=np.array([255, 255, 255, 255], np.uint8))
    glb = trimesh.Trimesh(V @ TRELLIS_GLB, F, visual=trimesh.visual.TextureVisuals(uv=uv, material=mat))
    glb_path = export(glb, tmp_path / "sample.glb")
    # save_ply: xyz @ transform.T and rotation transform @ R, zero normals, SH 0
    g = ma.mesh_to_gaussians(obj, 20000, seed=0)
    Tply = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    assert np.array_equal(Tply, splats.ZUP_TO_TRELLIS_FILE)
    R = cameras.quaternion_to_rotation(g.quats.astype(float))
    saved = splats.Gaussians(means=(g.means.astype(float) @ Tply.T).astype(np.float32), scales=g.scales,
                             quats=cameras.rotation_to_quaternion(Tply @ R).astype(np.float32),
                             opacities=g.opacities, sh=g.sh)
    zeros = np.zeros(len(g), np.float32)
    ply_path = tmp_path / "sample.ply"
    splats.write_ply(ply_path, splats.encode(saved, extra={"nx": zeros, "ny": zeros, "nz": zeros}))
    # the project's import of the PLY: F = ZUP_TO_TRELLIS_FILE.T (scene/gaussians.py)
    loaded = splats.load(ply_path)
    Fz = splats.ZUP_TO_TRELLIS_FILE.T
    ply_means = loaded.means.astype(float) @ Fz.T
    ply_normals = (Fz @ cameras.quaternion_to_rotation(loaded.quats.astype(float)))[:, :, 2]
    # the GLB through load_mesh (auto: Y up)
    asset = ma.load_mesh(glb_path)
    from scipy.spatial import cKDTree

    # exactly TRELLIS's Z-up frame (to_glb's Trimesh merges duplicate vertices, so compare as sets)
    assert cKDTree(V).query(asset.vertices)[0].max() < 1e-6 and cKDTree(asset.vertices).query(V)[0].max() < 1e-6
    mesh_g = ma.mesh_to_gaussians(asset, 20000, seed=1)
    for means in (ply_means, mesh_g.means.astype(float)):
        np.testing.assert_allclose(means.min(axis=0), V.min(axis=0), atol=0.01)
        np.testing.assert_allclose(means.max(axis=0), V.max(axis=0), atol=0.01)
        top = means[means[:, 2] > V[:, 2].max() - 0.1]
        assert (top[:, 0] > 0.3).all() and (top[:, 1] > 0.1).all()     # the mast, in the same corner
    np.testing.assert_allclose(ply_normals, normals_of(g), atol=1e-5)
    # and the nearest PLY Gaussian to each mesh Gaussian is close (same surface, same pose)
    dist = cKDTree(ply_means).query(mesh_g.means.astype(float))[0]
    assert np.percentile(dist, 99) < 0.02
    if hasattr(splats, "detect_axes"):
        assert splats.detect_axes(splats.read_ply(ply_path))[0] == "TRELLIS"


# -- the mask against the mesh's own silhouette --------------------------------------------------------------------

def test_silhouette_of_a_square():
    square = trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]], process=False)
    K = np.array([[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]])
    T = ma.look_at((0, 0, 10), (0, 0, 0), up=(0, 1, 0))
    sil = ma.silhouette(square.vertices, square.faces, K, T, 64, 64)
    assert sil.sum() == 400 and sil[22:42, 22:42].all()           # 20 x 20 pixel centres inside
    assert not ma.silhouette(square.vertices, square.faces, K, ma.look_at((0, 0, 5), (0, 0, 10), (0, 1, 0)), 64,
                             64).any()                                # behind the camera


def test_rendered_mask_matches_the_silhouette():
    """20 k Gaussians on a 30 m² object seen from 9 m at 256 x 144 (σ ≈ 0.7 px): within about a pixel of the
    mesh's outline (the renderer's 0.3 px² blur alone spreads every edge by ~0.5 px), opaque inside."""
    car = car_like_zup()
    g = ma.mesh_to_gaussians(car, 20000, seed=0)
    views = ma.orbit_cameras((0, 0, 1), 9.0, 256, 144, views=3)
    sils = [ma.silhouette(car.vertices, car.faces, K, T, 256, 144) for K, T in views]
    for (K, T), sil in zip(views, sils):
        m = ma.mask_metrics(ma.render_mask(g, K, T, 256, 144, reference=True), sil)
        assert sil.sum() > 3000
        assert m["iou"] > 0.92 and m["leak"] < 0.005 and m["spill"] < 0.09 and m["boundary_px"] < 1.5, m
    # the trade-off c sets, seen with 2 k Gaussians (σ of pixels, above the blur): too small leaves holes (leak),
    # too large bleeds past the outline (spill); the default sits between
    K, T = views[0]
    m = {c: ma.mask_metrics(ma.render_mask(ma.mesh_to_gaussians(car, 2000, sigma_factor=c), K, T, 256, 144,
                                           reference=True), sils[0]) for c in (0.3, ma.SIGMA_FACTOR, 1.5)}
    assert m[0.3]["leak"] > 0.1 and m[1.5]["spill"] > 0.4
    assert m[ma.SIGMA_FACTOR]["mean_abs"] < 0.6 * min(m[0.3]["mean_abs"], m[1.5]["mean_abs"])


# -- the command ---------------------------------------------------------------------------------------------------

def run_backend(*args):
    proc = subprocess.run([sys.executable, "-m", "backend", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)
    return proc.returncode, [json.loads(line) for line in proc.stdout.splitlines() if line.strip()], proc.stderr


def test_command_end_to_end(tmp_path):
    zup = car_like_zup()
    glb = trimesh.Trimesh(np.asarray(zup.vertices) @ R_GLTF, zup.faces, process=False)
    path = export(glb, tmp_path / "car.glb")
    out = tmp_path / "out" / "car.gaussians.ply"
    code, events, err = run_backend("mesh-asset", path, "--out", out, "--count", 3000, "--seed", 2)
    assert code == 0, err
    assert [e["event"] for e in events][-2:] == ["artifact", "done"]
    assert all(e["event"] == "progress" for e in events[:-2])
    done = events[-1]
    assert done["command"] == "mesh-asset"
    r = done["result"]
    assert r["ply"] == str(out) and r["count"] == 3000 and r["up"] == "y" and r["colour_source"] == "none"
    assert r["area"] == pytest.approx(zup.area)
    assert r["sigma"] == pytest.approx(ma.SIGMA_FACTOR * np.sqrt(zup.area / 3000))
    np.testing.assert_allclose(r["obb"]["size"], [4, 2, 2], atol=1e-6)
    assert r["obb"]["yaw_deg"] == pytest.approx(90.0) and len(r["obb_3d"]) == 3
    np.testing.assert_allclose(r["bounds"], [[-2, -1, 0], [2, 1, 2]], atol=1e-6)
    ply = splats.read_ply(out)
    assert len(ply) == 3000 and ply.sh_degree == 0 and not ({"nx", "ny", "nz"} & set(ply.extra))
    g = splats.decode(ply)
    assert g.dropped == {} and g.means[:, 2].min() >= -1e-6 and g.means[:, 2].max() <= 2 + 1e-6
    if hasattr(splats, "detect_axes"):
        assert splats.detect_axes(ply)[0] == "NONE"
    # same seed, same file
    code, _, _ = run_backend("mesh-asset", path, "--out", tmp_path / "again.ply", "--count", 3000, "--seed", 2)
    assert code == 0 and (tmp_path / "again.ply").read_bytes() == out.read_bytes()


def test_command_bad_input_exits_2(tmp_path):
    bad = tmp_path / "broken.glb"
    bad.write_bytes(b"glTF not really")
    for args in ([bad, "--out", tmp_path / "o.ply"], [tmp_path / "missing.obj", "--out", tmp_path / "o.ply"],
                 [bad, "--out", tmp_path / "o.ply", "--count", 0]):
        code, events, _ = run_backend("mesh-asset", *args)
        assert code == 2
        assert events[-1]["event"] == "error" and ("broken.glb" in events[-1]["message"]
                                                  or "missing.obj" in events[-1]["message"]
                                                  or "--count" in events[-1]["message"])
    assert not (tmp_path / "o.ply").exists()


def test_command_default_count_is_the_modules():
    from backend.__main__ import build_parser

    args = build_parser().parse_args(["mesh-asset", "x.glb", "--out", "y.ply"])
    assert args.count == ma.DEFAULT_COUNT and args.up == "auto" and args.seed == 0


# -- real TRELLIS files (shared/realdata/trellis; never copied into the repository) --------------------------------

def _stands(V, F):
    """True when the surface's centroid lies over the hull of its lowest points (within 2 % of the height): how an
    upright object rests on the ground."""
    from scipy.spatial import Delaunay

    a = ma._face_areas(V, F)
    com = (a[:, None] * V[F].mean(axis=1)).sum(axis=0) / a.sum()
    low = V[V[:, 2] <= V[:, 2].min() + 0.02 * np.ptp(V[:, 2])][:, :2]
    return len(low) >= 3 and Delaunay(low).find_simplex(com[None, :2])[0] >= 0


TURNS = {"upside down": np.diag([1.0, -1.0, -1.0]), "on its back": R_GLTF.T, "face down": R_GLTF,
         "on its side": np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]),
         "on its other side": np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]])}


@pytest.mark.parametrize("name", ["uanu2002_trellis_sample.glb", "harishreddy17_trellis_sample.glb"])
def test_real_trellis_glb(name, tmp_path):
    path = realdata(f"trellis/{name}")
    r = ma.convert(path, tmp_path / "g.ply", count=50_000)
    assert r["up"] == "y" and r["colour_source"] == "texture" and r["dropped"] == 0
    g = splats.load(tmp_path / "g.ply")
    assert len(g) == 50_000 and not g.dropped
    rgb = rgb_of(g)
    assert rgb.std(axis=0).min() > 0.05                       # a real texture, not one flat colour
    assert np.abs(g.means).max() <= 0.5 + 1e-3                # TRELLIS's unit cube
    assert r["bounds"][1][2] - r["bounds"][0][2] == pytest.approx(1.0, abs=0.01)  # normalised by the height here
    # our texture sampling agrees with trimesh's own sampler (which differs by half a texel at most)
    asset = ma.load_mesh(path)
    part = asset.parts[0]
    pts, fidx, bary = trimesh.sample.sample_surface(part, 2000, return_barycentric=True, seed=0)
    uvs = np.einsum("nk,nkc->nc", bary, part.visual.uv[part.faces[fidx]])
    theirs = trimesh.visual.color.uv_to_interpolated_color(uvs, part.visual.material.baseColorTexture)[:, :3] / 255
    assert np.abs(ma.sample_texture(part.visual.material.baseColorTexture, uvs) - theirs).mean() < 0.02
    # upright: it stands on its lowest points as converted
    V, F = asset.vertices, asset.faces
    assert _stands(V, F)


def test_real_trellis_chair_is_upright_and_green():
    asset = ma.load_mesh(realdata("trellis/uanu2002_trellis_sample.glb"))
    V, F = asset.vertices, asset.faces
    assert _stands(V, F)
    for turn, M in TURNS.items():       # no other way up stands: legs down is the only stable pose
        assert not _stands(V @ M.T, F), turn
    rgb = rgb_of(ma.mesh_to_gaussians(asset, 20000))
    upper = ma.mesh_to_gaussians(asset, 20000).means[:, 2] > 0   # the seat and back: green; the legs: grey
    assert rgb[upper, 1].mean() > rgb[upper, 0].mean() + 0.1 and rgb[upper, 1].mean() > rgb[upper, 2].mean() + 0.1


def test_real_trellis_t_glb_matches_its_mesh_ply():
    """The GLB generated for TRELLIS's "T" example, converted from Y up, lies on TRELLIS's own Z-up T mesh
    (assets/T.ply) better than any other way up or around."""
    from scipy.spatial import cKDTree

    glb = ma.mesh_to_gaussians(ma.load_mesh(realdata("trellis/harishreddy17_trellis_sample.glb")), 20000).means
    ply = ma.mesh_to_gaussians(ma.load_mesh(realdata("trellis/trellis_assets_T_mesh.ply")), 20000).means

    def chamfer(p):
        return cKDTree(ply).query(p)[0].mean() + cKDTree(p).query(ply)[0].mean()

    here = chamfer(glb.astype(float))
    assert here < 0.04
    for turn, M in dict(TURNS, **{"turned 180°": np.diag([-1.0, -1.0, 1.0])}).items():
        assert chamfer(glb.astype(float) @ M.T) > here * 1.2, turn


def test_real_mesh_ply_without_colours(tmp_path):
    path = realdata("trellis/trellis_assets_T_mesh.ply")
    r = ma.convert(path, tmp_path / "t.ply", count=20_000)
    assert r["up"] == "z" and r["colour_source"] == "none" and r["faces"] == 61402
    g = splats.load(tmp_path / "t.ply")
    np.testing.assert_allclose(rgb_of(g), ma.NEUTRAL_GREY, atol=1e-6)
    np.testing.assert_allclose(r["bounds"][0][2], -0.5, atol=0.01)
    assert np.isfinite(g.means).all() and len(g) == 20_000
    # an upright box: height 1 (the z range), length and width from the footprint
    assert r["obb"]["size"][2] == pytest.approx(1.0, abs=0.01) and r["obb"]["size"][0] >= r["obb"]["size"][1]


# -- inputs that must not hang or traceback (issue 14) ----------------------------------------------------------------

def _triangle_gltf(folder, buffer_uri="tri.bin", image_uri=None):
    """A one-triangle glTF whose buffer (and optional base-colour image) are separate files named by URI."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    uv = np.array([[0, 0], [1, 0], [0, 1]], np.float32)
    indices = np.array([0, 1, 2, 0], np.uint16)  # padded to 4 bytes
    blob = positions.tobytes() + uv.tobytes() + indices.tobytes()
    gltf = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "buffers": [{"uri": buffer_uri, "byteLength": len(blob)}],
            "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                            {"buffer": 0, "byteOffset": 36, "byteLength": 24},
                            {"buffer": 0, "byteOffset": 60, "byteLength": 6}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                           "min": [0, 0, 0], "max": [1, 1, 0]},
                          {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"},
                          {"bufferView": 2, "componentType": 5123, "count": 3, "type": "SCALAR"}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2}]}]}
    if image_uri is not None:
        gltf["meshes"][0]["primitives"][0]["material"] = 0
        gltf["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
        gltf["textures"] = [{"source": 0}]
        gltf["images"] = [{"uri": image_uri}]
    if buffer_uri == "tri.bin":
        (folder / "tri.bin").write_bytes(blob)
    (folder / "tri.gltf").write_text(json.dumps(gltf))
    return folder / "tri.gltf"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_fifo_inputs_are_refused_at_once(tmp_path):
    """A FIFO as the mesh, or named by the mesh as its buffer or texture, once blocked trimesh for ever."""
    import time

    for name in ("pipe.glb", "pipe.ply", "pipe.obj"):
        os.mkfifo(tmp_path / name)
        t = time.perf_counter()
        with pytest.raises(ma.MeshAssetError, match=rf"{name.replace('.', '[.]')}: is a FIFO \(named pipe\)") as e:
            ma.load_mesh(tmp_path / name)
        assert time.perf_counter() - t < 1.0 and e.value.field == "(file)"
    with pytest.raises(ma.MeshAssetError, match="is a directory"):
        ma.load_mesh(tmp_path)
    ok = tmp_path / "ok"
    ok.mkdir()
    assert len(ma.load_mesh(_triangle_gltf(ok)).faces) == 1  # the hand-written glTF is valid
    for what in ("buffer", "image"):
        folder = tmp_path / what
        folder.mkdir()
        if what == "buffer":
            os.mkfifo(folder / "fifo.bin")
            path = _triangle_gltf(folder, buffer_uri="fifo.bin")
        else:
            os.mkfifo(folder / "fifo.png")
            path = _triangle_gltf(folder, image_uri="fifo.png")
            (folder / "tri.bin").write_bytes((ok / "tri.bin").read_bytes())
        result = {}

        def attempt():
            try:
                result["asset"] = ma.load_mesh(path)
            except ValueError as e:
                result["error"] = e

        worker = __import__("threading").Thread(target=attempt, daemon=True)
        worker.start()
        worker.join(10.0)
        if worker.is_alive():
            with open(folder / ("fifo.bin" if what == "buffer" else "fifo.png"), "wb"):
                pass  # unblock it, then fail
            pytest.fail(f"load_mesh blocked on a FIFO {what}")
        # named even where trimesh would go on without it (a texture): the user's file to fix
        e = result.get("error")
        assert isinstance(e, ma.MeshAssetError), result
        name = "fifo.bin" if what == "buffer" else "fifo.png"
        assert str(e).startswith(f"tri.gltf: '{name}' (named by the mesh) is a FIFO") and e.field == name


def test_gaussian_ply_detected_by_its_properties_not_its_comments(tmp_path):
    g = ma.mesh_to_gaussians(trimesh.creation.box(), 50)
    splats.write_ply(tmp_path / "splat.ply", splats.encode(g), comment="exported by end_header tools")
    with pytest.raises(ma.MeshAssetError, match="Gaussian-splat PLY") as e:
        ma.load_mesh(tmp_path / "splat.ply")
    assert isinstance(e.value, ma.files.InputError)
    box = trimesh.creation.box()
    data = box.export(file_type="ply")  # binary; a comment naming Gaussian properties is not a Gaussian file
    data = data.replace(b"\nelement vertex", b"\ncomment not f_dc_0 scale_0 rot_0\nelement vertex", 1)
    (tmp_path / "mesh.ply").write_bytes(data)
    assert len(ma.load_mesh(tmp_path / "mesh.ply").faces) == 12


def test_ply_counts_beyond_the_file_are_refused_before_trimesh(tmp_path):
    data = trimesh.creation.box().export(file_type="ply")
    head, body = data.split(b"end_header\n", 1)
    n = int(head.split(b"element vertex ")[1].split(b"\n")[0])
    (tmp_path / "big.ply").write_bytes(head.replace(b"element vertex %d" % n, b"element vertex 999999999999")
                                       + b"end_header\n" + body)
    with pytest.raises(ma.MeshAssetError, match=r"big\.ply: the header promises 999999999999 vertex rows") as e:
        ma.load_mesh(tmp_path / "big.ply")
    assert e.value.field == "vertex"
    (tmp_path / "empty.obj").write_bytes(b"")
    with pytest.raises(ma.MeshAssetError, match=r"empty\.obj: the file is empty"):
        ma.load_mesh(tmp_path / "empty.obj")


def test_mesh_named_end_header_converts(tmp_path):
    """The output PLY's comment carries the mesh's name: a name holding "end_header" must not cut the header."""
    path = export(trimesh.creation.box(), tmp_path / "end_header.obj")
    out = tmp_path / "end_header.gaussians.ply"
    r = ma.convert(path, out, count=64)
    assert b"comment scpainter mesh-asset end_header.obj" in out.read_bytes()[:400]
    g = splats.load(out)
    assert r["count"] == len(g) == 64 and g.dropped == {}
    assert np.all(np.abs(g.means) <= 0.5 + 1e-6)  # the unit box: values read from the right offset
