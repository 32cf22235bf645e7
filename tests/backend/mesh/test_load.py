"""backend.mesh.load: mesh files into Z-up parts (Y-up glTF/GLB/OBJ turned, Z-up PLY/STL/OFF as stored, scene
nodes applied), and the files refused naming themselves: broken, point clouds, Gaussian PLYs, counts the file cannot
hold, FIFOs as the mesh or named by it (issue 14)."""

import os

import numpy as np
import pytest
import trimesh

from tests.backend.mesh import mesh_fixtures as MF
from backend.mesh import asset as ma
from backend.mesh import load as mesh_load
from scpainter_blender.core import errors
from scpainter_blender.core.splats import gaussians as splats, inria as splats_inria


# -- axes ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("ext", [".glb", ".gltf", ".obj"])
def test_y_up_files_land_z_up(tmp_path, ext):
    zup = MF.car_like_zup()
    yup = trimesh.Trimesh(np.asarray(zup.vertices) @ MF.R_GLTF, zup.faces, process=False)  # p_gltf = R^T p_zup
    path = MF.export(yup, tmp_path / f"car{ext}")
    asset = mesh_load.load_mesh(path)
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
    np.testing.assert_allclose(mesh_load.load_mesh(path, up="z").vertices.max(axis=0), [2, 2, 1], atol=1e-6)


def test_z_up_formats_are_read_as_stored(tmp_path):
    zup = MF.car_like_zup()
    for ext in (".ply", ".stl", ".off"):
        asset = mesh_load.load_mesh(MF.export(zup, tmp_path / f"car{ext}"))
        assert asset.up == "z"
        np.testing.assert_allclose(asset.vertices.max(axis=0), [2, 1, 2], atol=1e-6)
    np.testing.assert_allclose(mesh_load.load_mesh(tmp_path / "car.ply", up="y").vertices.max(axis=0), [2, 0, 1],
                               atol=1e-6)


def test_scene_node_transforms_are_applied(tmp_path):
    scene = trimesh.Scene()
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    scene.add_geometry(box, node_name="a", transform=trimesh.transformations.translation_matrix((5, 0, 0)))
    scene.add_geometry(box, node_name="b", transform=trimesh.transformations.translation_matrix((0, 3, 0)))
    asset = mesh_load.load_mesh(MF.export(scene, tmp_path / "two.glb"))
    assert len(asset.parts) == 2
    # glTF (5, 0, 0) and (0, 3, 0) -> Z up (5, 0, 0) and (0, 0, 3)
    centres = sorted(tuple(np.round(p.vertices.mean(axis=0), 6)) for p in asset.parts)
    assert centres == [(0.0, 0.0, 3.0), (5.0, 0.0, 0.0)]


# -- bad files -----------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("make, what", [
    (lambda p: p.write_bytes(b"garbage"), "not a GLB file"),
    (lambda p: trimesh.PointCloud(np.random.default_rng(0).random((20, 3))).export(os.fspath(p)), "point cloud"),
])
def test_bad_files_raise_naming_the_file(tmp_path, make, what):
    path = tmp_path / ("broken.glb" if "GLB" in what else "cloud.ply")
    make(path)
    with pytest.raises(ValueError, match=what) as e:
        mesh_load.load_mesh(path)
    assert path.name in str(e.value)


def test_other_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="file not found"):
        mesh_load.load_mesh(tmp_path / "missing.glb")
    (tmp_path / "car.fbx").write_bytes(b"x")
    with pytest.raises(ValueError, match="not a mesh format"):
        mesh_load.load_mesh(tmp_path / "car.fbx")
    g = ma.mesh_to_gaussians(trimesh.creation.box(), 50)
    splats_inria.write_ply(tmp_path / "splat.ply", splats.encode(g))
    with pytest.raises(ValueError, match="Gaussian-splat PLY"):
        mesh_load.load_mesh(tmp_path / "splat.ply")
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(ValueError, match="zero"):
        mesh_load.load_mesh(MF.export(flat, tmp_path / "flat.ply"))


# -- inputs that must not hang or traceback (issue 14) -------------------------------------------------------------

@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_fifo_inputs_are_refused_at_once(tmp_path):
    """A FIFO as the mesh, or named by the mesh as its buffer or texture, once blocked trimesh for ever."""
    import time

    for name in ("pipe.glb", "pipe.ply", "pipe.obj"):
        os.mkfifo(tmp_path / name)
        t = time.perf_counter()
        with pytest.raises(mesh_load.MeshAssetError,
                           match=rf"{name.replace('.', '[.]')}: is a FIFO \(named pipe\)") as e:
            mesh_load.load_mesh(tmp_path / name)
        assert time.perf_counter() - t < 1.0 and e.value.field == "(file)"
    with pytest.raises(mesh_load.MeshAssetError, match="is a directory"):
        mesh_load.load_mesh(tmp_path)
    ok = tmp_path / "ok"
    ok.mkdir()
    assert len(mesh_load.load_mesh(MF.triangle_gltf(ok)).faces) == 1  # the hand-written glTF is valid
    for what in ("buffer", "image"):
        folder = tmp_path / what
        folder.mkdir()
        if what == "buffer":
            os.mkfifo(folder / "fifo.bin")
            path = MF.triangle_gltf(folder, buffer_uri="fifo.bin", write_buffer=False)
        else:
            os.mkfifo(folder / "fifo.png")
            path = MF.triangle_gltf(folder, image_uri="fifo.png")
            (folder / "tri.bin").write_bytes((ok / "tri.bin").read_bytes())
        result = {}

        def attempt():
            try:
                result["asset"] = mesh_load.load_mesh(path)
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
        assert isinstance(e, mesh_load.MeshAssetError), result
        name = "fifo.bin" if what == "buffer" else "fifo.png"
        assert str(e).startswith(f"tri.gltf: '{name}' (named by the mesh) is a FIFO") and e.field == name


@pytest.mark.parametrize("ext", [".ply", ".splat", ".spz", ".sog", ".glb"])
def test_gaussian_splat_files_are_refused_pointing_to_the_splat_import(tmp_path, ext):
    """Gaussian splats given to mesh-asset (a KHR_gaussian_splatting .glb, SPZ, SOG, .splat, a Gaussian PLY; the
    others written by splat-transform from the PLY) are told as splats, with the commands that read them, not as a
    point cloud or a format to export again."""
    from scpainter_blender.core.splats import compressed
    from tests_support import run_backend_here

    g = ma.mesh_to_gaussians(trimesh.creation.box(), 64, seed=2)
    splats_inria.write_ply(tmp_path / "car.ply", splats.encode(g))
    if ext == ".splat":
        compressed.write_splat(tmp_path / "car.splat", g)
    elif ext != ".ply":
        import splat_transform

        splat_transform.convert(tmp_path / "car.ply", tmp_path / f"car{ext}")
    path = tmp_path / f"car{ext}"
    with pytest.raises(mesh_load.MeshAssetError, match="holds Gaussian splats") as e:
        mesh_load.load_mesh(path)
    assert "splat-asset" in e.value.hint and "Import Gaussian Asset" in e.value.hint
    code, events, err = run_backend_here("mesh-asset", path, "--out", tmp_path / "o.ply", "--count", 100)
    assert code == 2 and "Traceback" not in err and "Gaussian splats" in events[-1]["message"]
    assert "point cloud" not in events[-1]["message"] and "export the car" not in events[-1]["message"]


def test_gaussian_ply_detected_by_its_properties_not_its_comments(tmp_path):
    g = ma.mesh_to_gaussians(trimesh.creation.box(), 50)
    splats_inria.write_ply(tmp_path / "splat.ply", splats.encode(g), comment="exported by end_header tools")
    with pytest.raises(mesh_load.MeshAssetError, match="Gaussian-splat PLY") as e:
        mesh_load.load_mesh(tmp_path / "splat.ply")
    assert isinstance(e.value, errors.InputError)
    box = trimesh.creation.box()
    data = box.export(file_type="ply")  # binary; a comment naming Gaussian properties is not a Gaussian file
    data = data.replace(b"\nelement vertex", b"\ncomment not f_dc_0 scale_0 rot_0\nelement vertex", 1)
    (tmp_path / "mesh.ply").write_bytes(data)
    assert len(mesh_load.load_mesh(tmp_path / "mesh.ply").faces) == 12


def test_ply_counts_beyond_the_file_are_refused_before_trimesh(tmp_path):
    data = trimesh.creation.box().export(file_type="ply")
    head, body = data.split(b"end_header\n", 1)
    n = int(head.split(b"element vertex ")[1].split(b"\n")[0])
    (tmp_path / "big.ply").write_bytes(head.replace(b"element vertex %d" % n, b"element vertex 999999999999")
                                       + b"end_header\n" + body)
    with pytest.raises(mesh_load.MeshAssetError, match=r"big\.ply: the header promises 999999999999 vertex rows") as e:
        mesh_load.load_mesh(tmp_path / "big.ply")
    assert e.value.field == "vertex"
    (tmp_path / "empty.obj").write_bytes(b"")
    with pytest.raises(mesh_load.MeshAssetError, match=r"empty\.obj: the file is empty"):
        mesh_load.load_mesh(tmp_path / "empty.obj")
