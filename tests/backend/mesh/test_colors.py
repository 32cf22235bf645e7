"""backend.mesh.colors through the sampler: texture colours (glTF sampling conventions), linear glTF factors and
vertex colours, face colours, no colour at all, a textured OBJ."""

import os

import numpy as np
import trimesh

from tests.backend.mesh import mesh_fixtures as MF
from backend.mesh import asset as ma
from backend.mesh import colors as mesh_colors, load as mesh_load
from scpainter_blender.core.colors import linear_to_srgb


def test_textured_box_faces_take_their_texture_colour(tmp_path):
    colours = np.array([[230, 20, 20], [20, 200, 30], [30, 40, 220], [240, 230, 20], [20, 220, 230], [200, 30, 210]],
                       np.uint8)
    image, uv_in_cell = MF.cell_texture(colours)
    box = trimesh.creation.box((2.0, 1.0, 0.5))
    V, F = MF.split_triangles(box.vertices, box.faces)
    normals_gltf = box.face_normals
    axes = [tuple(np.round(n).astype(int)) for n in normals_gltf]
    cell_of_normal = {n: k for k, n in enumerate(sorted(set(axes)))}
    uv = np.concatenate([uv_in_cell(cell_of_normal[n], 3) for n in axes])
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=image, baseColorFactor=[255, 255, 255, 255])
    mesh = trimesh.Trimesh(V, F, visual=trimesh.visual.TextureVisuals(uv=uv, material=mat), process=False)
    res = ma.sample_gaussians(mesh_load.load_mesh(MF.export(mesh, tmp_path / "box.glb")), 3000, seed=2)
    assert res.colour_source == "texture" and res.colour_counts == {"texture": 3000}
    g = res.gaussians
    n_gltf = MF.normals_of(g) @ MF.R_GLTF            # back to the file's axes: R^T n
    expect = np.array([colours[cell_of_normal[tuple(np.round(n).astype(int))]] for n in n_gltf]) / 255.0
    np.testing.assert_allclose(MF.rgb_of(g), expect, atol=1e-5)
    assert len({tuple(c) for c in np.round(MF.rgb_of(g), 3)}) == 6


def test_texture_sampling_conventions():
    img = np.arange(4 * 3 * 3, dtype=np.uint8).reshape(4, 3, 3) * 7
    i, j = np.meshgrid(np.arange(3), np.arange(4))
    uv = np.stack([(i.ravel() + 0.5) / 3, 1 - (j.ravel() + 0.5) / 4], axis=1)   # texel centres
    np.testing.assert_allclose(mesh_colors.sample_texture(img, uv), img.reshape(-1, 3) / 255.0, atol=1e-12)
    np.testing.assert_allclose(mesh_colors.sample_texture(img, uv + 1.0), img.reshape(-1, 3) / 255.0,
                               atol=1e-12)                                                   # REPEAT
    mid = mesh_colors.sample_texture(img, [[1.0 / 3, 1 - 0.5 / 4]])[0]                      # halfway, texels 0 and 1
    np.testing.assert_allclose(mid, (img[0, 0] + img[0, 1]) / 2 / 255.0, atol=1e-12)
    assert np.isnan(mesh_colors.sample_texture(img, [[np.nan, 0.5]])).all()


def test_glb_base_colour_factor_is_linear(tmp_path):
    box = trimesh.creation.box()
    image, _ = MF.cell_texture(np.full((6, 3), 255, np.uint8))
    uv = np.full((len(box.vertices), 2), 0.5)
    factor = np.array([0.5, 0.25, 1.0, 1.0])                  # linear, as glTF says
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=image, baseColorFactor=factor)
    box.visual = trimesh.visual.TextureVisuals(uv=uv, material=mat)
    g = ma.mesh_to_gaussians(mesh_load.load_mesh(MF.export(box, tmp_path / "f.glb")), 200)
    expect = linear_to_srgb(np.round(factor[:3] * 255) / 255)   # trimesh stores the factor as 8 bit
    np.testing.assert_allclose(MF.rgb_of(g), np.tile(expect, (200, 1)), atol=1e-5)
    plain = trimesh.creation.box()
    plain.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        baseColorFactor=factor))
    res = ma.sample_gaussians(mesh_load.load_mesh(MF.export(plain, tmp_path / "plain.glb")), 100)
    assert res.colour_source == "face"
    np.testing.assert_allclose(MF.rgb_of(res.gaussians), np.tile(expect, (100, 1)), atol=1e-5)


def test_vertex_colours_are_interpolated(tmp_path):
    tri = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False,
                          vertex_colors=[[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255]])
    res = ma.sample_gaussians(mesh_load.load_mesh(MF.export(tri, tmp_path / "tri.ply")), 500, seed=3)
    assert res.colour_source == "vertex"
    x, y = res.gaussians.means[:, 0].astype(float), res.gaussians.means[:, 1].astype(float)
    np.testing.assert_allclose(MF.rgb_of(res.gaussians), np.stack([1 - x - y, x, y], axis=1), atol=1e-5)
    # glTF COLOR_0 is linear: stored as sRGB in the Gaussians
    grey = trimesh.creation.box()
    grey.visual.vertex_colors = np.tile([51, 51, 51, 255], (len(grey.vertices), 1))
    res = ma.sample_gaussians(mesh_load.load_mesh(MF.export(grey, tmp_path / "grey.glb")), 50)
    assert res.colour_source == "vertex"
    np.testing.assert_allclose(MF.rgb_of(res.gaussians), linear_to_srgb(51 / 255), atol=1e-5)


def test_face_colours_and_no_colours(tmp_path):
    box = trimesh.creation.box()
    box.visual.face_colors = np.tile([200, 100, 50, 255], (len(box.faces), 1))
    res = ma.sample_gaussians(mesh_load.load_mesh(MF.export(box, tmp_path / "faces.ply")), 100)
    assert res.colour_source == "face"
    np.testing.assert_allclose(MF.rgb_of(res.gaussians), np.tile([200 / 255, 100 / 255, 50 / 255], (100, 1)), atol=1e-5)
    res = ma.sample_gaussians(mesh_load.load_mesh(MF.export(trimesh.creation.box(), tmp_path / "bare.stl")), 100)
    assert res.colour_source == "none"
    np.testing.assert_allclose(res.gaussians.sh, 0.0, atol=1e-7)      # neutral grey 0.5: f_dc = 0


def test_textured_obj_round_trip(tmp_path):
    colours = np.array([[250, 10, 10], [10, 250, 10], [10, 10, 250], [250, 250, 10], [10, 250, 250],
                        [250, 10, 250]], np.uint8)
    image, uv_in_cell = MF.cell_texture(colours)
    zup = MF.car_like_zup()
    V, F = MF.split_triangles(np.asarray(zup.vertices) @ MF.R_GLTF, zup.faces)
    uv = np.concatenate([uv_in_cell(k % 6, 3) for k in range(len(F))])
    mesh = trimesh.Trimesh(V, F, process=False, visual=trimesh.visual.TextureVisuals(
        uv=uv, material=trimesh.visual.material.SimpleMaterial(image=image)))
    os.makedirs(tmp_path / "obj")
    asset = mesh_load.load_mesh(MF.export(mesh, tmp_path / "obj" / "car.obj"))
    assert asset.up == "y"
    np.testing.assert_allclose(asset.vertices.min(axis=0), [-2, -1, 0], atol=1e-5)
    np.testing.assert_allclose(asset.vertices.max(axis=0), [2, 1, 2], atol=1e-5)
    res = ma.sample_gaussians(asset, 2000, seed=4)
    assert res.colour_source == "texture"
    got = np.round(MF.rgb_of(res.gaussians) * 255)
    assert {tuple(c) for c in got.astype(int)} <= {tuple(c) for c in colours.astype(int)}
