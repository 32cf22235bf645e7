"""Mesh assets (``backend.mesh.asset``, ``python -m backend mesh-asset``): flat Gaussians on the surface (normals,
σ, seeds, degenerate faces), the TRELLIS GLB/PLY pose, the command, and real TRELLIS files. Loading, colours, the box
and the silhouette have their own test files (test_load, test_colors, test_box,
test_silhouette)."""

import os

import numpy as np
import pytest
import trimesh

from tests.backend.mesh import mesh_fixtures as MF
from backend.mesh import asset as ma
from backend.mesh import colors as mesh_colors, load as mesh_load
from scpainter_blender.core.geometry import cameras
from scpainter_blender.core.splats import gaussians as splats, inria as splats_inria, reader as splats_io, trellis
from tests_support import realdata, run_backend_here


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
    np.testing.assert_allclose(MF.normals_of(g), n[face], atol=1e-5)
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
    splats_inria.write_ply(out, splats.encode(g))
    assert splats_io.load(out).dropped == {}
    with pytest.raises(ValueError, match="no face with a positive"):
        ma.sample_gaussians(trimesh.Trimesh(V[3:6], [[0, 1, 2]], process=False), 10)


# -- TRELLIS: the GLB and the Gaussian PLY of one asset land in the same pose --------------------------------------

def test_trellis_glb_and_gaussian_ply_share_a_pose(tmp_path):
    # one object in TRELLIS's Z-up frame, inside the unit cube, asymmetric (the mast at +x, +y, top)
    obj = MF.car_like_zup()
    obj.apply_translation((0, 0, -1.0))
    obj.apply_scale(0.24)
    V, F = MF.split_triangles(obj.vertices, obj.faces)
    image, uv_in_cell = MF.cell_texture(np.array([[200, 50, 50]] * 6, np.uint8))
    uv = np.concatenate([uv_in_cell(0, 3) for _ in range(len(F))])
    # to_glb: vertices @ [[1,0,0],[0,0,-1],[0,1,0]], a TextureVisuals/PBRMaterial Trimesh, exported by trimesh
    mat = trimesh.visual.material.PBRMaterial(roughnessFactor=1.0, baseColorTexture=image,
                                              baseColorFactor=np.array([255, 255, 255, 255], np.uint8))
    glb = trimesh.Trimesh(V @ MF.TRELLIS_GLB, F, visual=trimesh.visual.TextureVisuals(uv=uv, material=mat))
    glb_path = MF.export(glb, tmp_path / "sample.glb")
    # save_ply: xyz @ transform.T and rotation transform @ R, zero normals, SH 0
    g = ma.mesh_to_gaussians(obj, 20000, seed=0)
    Tply = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    assert np.array_equal(Tply, trellis.ZUP_TO_TRELLIS_FILE)
    R = cameras.quaternion_to_rotation(g.quats.astype(float))
    saved = splats.Gaussians(means=(g.means.astype(float) @ Tply.T).astype(np.float32), scales=g.scales,
                             quats=cameras.rotation_to_quaternion(Tply @ R).astype(np.float32),
                             opacities=g.opacities, sh=g.sh)
    zeros = np.zeros(len(g), np.float32)
    ply_path = tmp_path / "sample.ply"
    splats_inria.write_ply(ply_path, splats.encode(saved, extra={"nx": zeros, "ny": zeros, "nz": zeros}))
    # the project's import of the PLY: F = ZUP_TO_TRELLIS_FILE.T (scene/gaussians.py)
    loaded = splats_io.load(ply_path)
    Fz = trellis.ZUP_TO_TRELLIS_FILE.T
    ply_means = loaded.means.astype(float) @ Fz.T
    ply_normals = (Fz @ cameras.quaternion_to_rotation(loaded.quats.astype(float)))[:, :, 2]
    # the GLB through load_mesh (auto: Y up)
    asset = mesh_load.load_mesh(glb_path)
    from scipy.spatial import cKDTree

    # exactly TRELLIS's Z-up frame (to_glb's Trimesh merges duplicate vertices, so compare as sets)
    assert cKDTree(V).query(asset.vertices)[0].max() < 1e-6 and cKDTree(asset.vertices).query(V)[0].max() < 1e-6
    mesh_g = ma.mesh_to_gaussians(asset, 20000, seed=1)
    for means in (ply_means, mesh_g.means.astype(float)):
        np.testing.assert_allclose(means.min(axis=0), V.min(axis=0), atol=0.01)
        np.testing.assert_allclose(means.max(axis=0), V.max(axis=0), atol=0.01)
        top = means[means[:, 2] > V[:, 2].max() - 0.1]
        assert (top[:, 0] > 0.3).all() and (top[:, 1] > 0.1).all()     # the mast, in the same corner
    np.testing.assert_allclose(ply_normals, MF.normals_of(g), atol=1e-5)
    # and the nearest PLY Gaussian to each mesh Gaussian is close (same surface, same pose)
    dist = cKDTree(ply_means).query(mesh_g.means.astype(float))[0]
    assert np.percentile(dist, 99) < 0.02
    assert trellis.detect_axes(splats_io.read_ply(ply_path))[0] == "TRELLIS"


# -- the command ---------------------------------------------------------------------------------------------------

def test_command_end_to_end(tmp_path):
    zup = MF.car_like_zup()
    glb = trimesh.Trimesh(np.asarray(zup.vertices) @ MF.R_GLTF, zup.faces, process=False)
    path = MF.export(glb, tmp_path / "car.glb")
    out = tmp_path / "out" / "car.gaussians.ply"
    code, events, err = run_backend_here("mesh-asset", path, "--out", out, "--count", 3000, "--seed", 2)
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
    ply = splats_io.read_ply(out)
    assert len(ply) == 3000 and ply.sh_degree == 0 and not ({"nx", "ny", "nz"} & set(ply.extra))
    g = splats.decode(ply)
    assert g.dropped == {} and g.means[:, 2].min() >= -1e-6 and g.means[:, 2].max() <= 2 + 1e-6
    assert trellis.detect_axes(ply)[0] == "NONE"
    # same seed, same file
    code, _, _ = run_backend_here("mesh-asset", path, "--out", tmp_path / "again.ply", "--count", 3000, "--seed", 2)
    assert code == 0 and (tmp_path / "again.ply").read_bytes() == out.read_bytes()


def test_command_bad_input_exits_2(tmp_path):
    bad = tmp_path / "broken.glb"
    bad.write_bytes(b"glTF not really")
    for args in ([bad, "--out", tmp_path / "o.ply"], [tmp_path / "missing.obj", "--out", tmp_path / "o.ply"],
                 [bad, "--out", tmp_path / "o.ply", "--count", 0]):
        code, events, _ = run_backend_here("mesh-asset", *args)
        assert code == 2
        assert events[-1]["event"] == "error" and ("broken.glb" in events[-1]["message"]
                                                  or "missing.obj" in events[-1]["message"]
                                                  or "--count" in events[-1]["message"])
    assert not (tmp_path / "o.ply").exists()


def test_command_default_count_is_the_modules():
    from backend.__main__ import build_parser

    args = build_parser().parse_args(["mesh-asset", "x.glb", "--out", "y.ply"])
    assert args.count == ma.DEFAULT_COUNT and args.up == "auto" and args.seed == 0


def test_mesh_named_end_header_converts(tmp_path):
    """The output PLY's comment carries the mesh's name: a name holding "end_header" must not cut the header."""
    path = MF.export(trimesh.creation.box(), tmp_path / "end_header.obj")
    out = tmp_path / "end_header.gaussians.ply"
    r = ma.convert(path, out, count=64)
    assert b"comment scpainter mesh-asset end_header.obj" in out.read_bytes()[:400]
    g = splats_io.load(out)
    assert r["count"] == len(g) == 64 and g.dropped == {}
    assert np.all(np.abs(g.means) <= 0.5 + 1e-6)  # the unit box: values read from the right offset


# -- real TRELLIS files (shared/realdata/trellis; never copied into the repository) --------------------------------

def _stands(V, F):
    """True when the surface's centroid lies over the hull of its lowest points (within 2 % of the height): how an
    upright object rests on the ground."""
    from scipy.spatial import Delaunay

    a = mesh_load.face_areas(V, F)
    com = (a[:, None] * V[F].mean(axis=1)).sum(axis=0) / a.sum()
    low = V[V[:, 2] <= V[:, 2].min() + 0.02 * np.ptp(V[:, 2])][:, :2]
    return len(low) >= 3 and Delaunay(low).find_simplex(com[None, :2])[0] >= 0


TURNS = {"upside down": np.diag([1.0, -1.0, -1.0]), "on its back": MF.R_GLTF.T, "face down": MF.R_GLTF,
         "on its side": np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]),
         "on its other side": np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]])}


@pytest.mark.parametrize("name", ["uanu2002_trellis_sample.glb", "harishreddy17_trellis_sample.glb"])
def test_real_trellis_glb(name, tmp_path):
    path = realdata(f"trellis/{name}")
    r = ma.convert(path, tmp_path / "g.ply", count=50_000)
    assert r["up"] == "y" and r["colour_source"] == "texture" and r["dropped"] == 0
    g = splats_io.load(tmp_path / "g.ply")
    assert len(g) == 50_000 and not g.dropped
    rgb = MF.rgb_of(g)
    assert rgb.std(axis=0).min() > 0.05                       # a real texture, not one flat colour
    assert np.abs(g.means).max() <= 0.5 + 1e-3                # TRELLIS's unit cube
    assert r["bounds"][1][2] - r["bounds"][0][2] == pytest.approx(1.0, abs=0.01)  # normalised by the height here
    # our texture sampling agrees with trimesh's own sampler (which differs by half a texel at most)
    asset = mesh_load.load_mesh(path)
    part = asset.parts[0]
    pts, fidx, bary = trimesh.sample.sample_surface(part, 2000, return_barycentric=True, seed=0)
    uvs = np.einsum("nk,nkc->nc", bary, part.visual.uv[part.faces[fidx]])
    theirs = trimesh.visual.color.uv_to_interpolated_color(uvs, part.visual.material.baseColorTexture)[:, :3] / 255
    assert np.abs(mesh_colors.sample_texture(part.visual.material.baseColorTexture, uvs) - theirs).mean() < 0.02
    # upright: it stands on its lowest points as converted
    V, F = asset.vertices, asset.faces
    assert _stands(V, F)


def test_real_trellis_chair_is_upright_and_green():
    asset = mesh_load.load_mesh(realdata("trellis/uanu2002_trellis_sample.glb"))
    V, F = asset.vertices, asset.faces
    assert _stands(V, F)
    for turn, M in TURNS.items():       # no other way up stands: legs down is the only stable pose
        assert not _stands(V @ M.T, F), turn
    rgb = MF.rgb_of(ma.mesh_to_gaussians(asset, 20000))
    upper = ma.mesh_to_gaussians(asset, 20000).means[:, 2] > 0   # the seat and back: green; the legs: grey
    assert rgb[upper, 1].mean() > rgb[upper, 0].mean() + 0.1 and rgb[upper, 1].mean() > rgb[upper, 2].mean() + 0.1


def test_real_trellis_t_glb_matches_its_mesh_ply():
    """The GLB generated for TRELLIS's "T" example, converted from Y up, lies on TRELLIS's own Z-up T mesh
    (assets/T.ply) better than any other way up or around."""
    from scipy.spatial import cKDTree

    glb = ma.mesh_to_gaussians(mesh_load.load_mesh(realdata("trellis/harishreddy17_trellis_sample.glb")), 20000).means
    ply = ma.mesh_to_gaussians(mesh_load.load_mesh(realdata("trellis/trellis_assets_T_mesh.ply")), 20000).means

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
    g = splats_io.load(tmp_path / "t.ply")
    np.testing.assert_allclose(MF.rgb_of(g), mesh_colors.NEUTRAL_GREY, atol=1e-6)
    np.testing.assert_allclose(r["bounds"][0][2], -0.5, atol=0.01)
    assert np.isfinite(g.means).all() and len(g) == 20_000
    # an upright box: height 1 (the z range), length and width from the footprint
    assert r["obb"]["size"][2] == pytest.approx(1.0, abs=0.01) and r["obb"]["size"][0] >= r["obb"]["size"][1]


# -- hostile files through the command (issue 30; the readers' side: test_checks.py) --------------------------

def test_command_refuses_hostile_files_with_exit_2_and_no_traceback(tmp_path):
    from PIL import Image

    Image.new("RGB", (8, 8), (200, 0, 0)).save(tmp_path / "tex.png")
    nan_uv = MF.triangle_gltf(tmp_path, image_uri="tex.png", uv=[[np.nan, 0], [0, 0], [0, 1]])
    code, events, err = run_backend_here("mesh-asset", nan_uv, "--out", tmp_path / "o.ply", "--count", 100)
    assert code == 2 and events[-1]["event"] == "error", err   # was: a 0-Gaussian PLY and exit 0
    assert events[-1]["file"] == nan_uv and events[-1]["field"] == "TEXCOORD_0" and events[-1]["hint"]
    (tmp_path / "t.ply").write_text(
        "ply\nformat ascii 1.0\ncomment TextureFile lost.png\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nproperty float texture_u\nproperty float texture_v\nelement face 1\n"
        "property list uchar int vertex_indices\nend_header\n0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2\n")
    code, events, err = run_backend_here("mesh-asset", tmp_path / "t.ply", "--out", tmp_path / "o.ply", "--count", 100)
    assert code == 2 and events[-1]["field"] == "lost.png" and "Traceback" not in err, err
    assert not (tmp_path / "o.ply").exists()


def test_command_warns_for_what_trimesh_went_past(tmp_path):
    import json

    path = MF.triangle_gltf(tmp_path)
    tree = json.load(open(path))
    tree["materials"] = [{"extensions": {"KHR_materials_pbrSpecularGlossiness": {"diffuseFactor": "red"}}}]
    tree["meshes"][0]["primitives"][0]["material"] = 0
    json.dump(tree, open(path, "w"))
    code, events, err = run_backend_here("mesh-asset", path, "--out", tmp_path / "o.ply", "--count", 100)
    assert code == 0, err
    warned = [e for e in events if e["event"] == "warning"]
    assert [w["code"] for w in warned] == [mesh_load.READER_WARNING] and "specular-glossiness" in warned[0]["message"]
    assert events[-1]["result"]["warnings"] == [{k: warned[0][k] for k in ("message", "code")}]
    assert "Traceback" not in err and err.strip() == f"warning: {warned[0]['message']}"


_HOLD_BEFORE_RENAME = r"""
import os, runpy, sys
# python -m backend mesh-asset, stopped between writing its temporary and renaming it over --out: it reports the
# temporary on the descriptor named by SCPAINTER_TEST_FD and waits for a byte on standard input (or a SIGKILL)
out, report = os.path.abspath(sys.argv[1]), int(os.environ["SCPAINTER_TEST_FD"])
real = os.replace
def where(name, fd):  # outputs renames relative to the folder's descriptor (dst_dir_fd): the full path
    return os.path.join(os.readlink(f"/proc/self/fd/{fd}"), name) if fd is not None else os.path.abspath(name)
def held(src, dst, *args, **kwargs):
    if where(dst, kwargs.get("dst_dir_fd")) == out:
        os.write(report, (where(src, kwargs.get("src_dir_fd")) + "\n").encode())
        os.read(0, 1)
    return real(src, dst, *args, **kwargs)
os.replace = held
sys.argv = ["backend", "mesh-asset", *sys.argv[2:]]
runpy.run_module("backend", run_name="__main__")
"""


def _held_run(mesh, out):
    """A ``mesh-asset`` subprocess held just before its rename; returns (process, its temporary's path)."""
    import select
    import subprocess
    import sys

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    r, w = os.pipe()
    proc = subprocess.Popen([sys.executable, "-c", _HOLD_BEFORE_RENAME, str(out), str(mesh), "--out", str(out),
                             "--count", "2000"], cwd=root, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, pass_fds=(w,), env={**os.environ, "SCPAINTER_TEST_FD": str(w)})
    os.close(w)
    try:
        ready, _, _ = select.select([r], [], [], 300)   # a bounded wait for the event, not a sleep
        line = os.read(r, 4096).decode() if ready else ""
    finally:
        os.close(r)
    if not line.endswith("\n"):
        proc.kill()
        proc.wait(60)
        pytest.fail(f"mesh-asset never reached its rename (exit {proc.returncode})")
    return proc, line.strip()


def test_a_killed_run_leaves_a_temporary_the_next_run_removes(tmp_path):
    import signal

    mesh = MF.export(MF.car_like_zup(), tmp_path / "car.stl")
    out = tmp_path / "assets" / "car.ply"

    def temporaries():
        return sorted(n for n in os.listdir(out.parent) if n.startswith(".car.ply.") and n.endswith(".tmp"))

    # a live run's temporary is never taken from it: another run for the same output finishes beside it
    live, tmp = _held_run(mesh, out)
    assert os.path.isfile(tmp) and temporaries() == [os.path.basename(tmp)]
    code, _, err = run_backend_here("mesh-asset", mesh, "--out", out, "--count", 100)
    assert code == 0 and os.path.isfile(tmp), err
    live.stdin.write(b"\n")
    live.stdin.close()
    assert live.wait(300) == 0 and temporaries() == [] and len(splats_io.load(out)) == 2000
    # SIGKILLed mid-write: its temporary stays until the next run for that output
    killed, tmp = _held_run(mesh, out)
    killed.send_signal(signal.SIGKILL)
    assert killed.wait(60) == -signal.SIGKILL and temporaries() == [os.path.basename(tmp)]
    code, _, err = run_backend_here("mesh-asset", mesh, "--out", out, "--count", 100)
    assert code == 0, err
    assert temporaries() == [] and len(splats_io.load(out)) == 100
