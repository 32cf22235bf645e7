"""core.splats.gltf_splats: glTF KHR_gaussian_splatting written by the real writer (splat-transform's .glb) read
back against our read of the source PLY, with the frames stated; a .gltf built here (external percent-encoded
buffer, interleaved and normalised accessors, nested node transforms) against values computed here; mesh glTFs
stay meshes (``reader.is_mesh``); unreadable ones are refused naming the field."""

import json
import struct

import numpy as np
import pytest

from tests.core.splats import splat_fixtures as F
import splat_transform
from tests_support import realdata
from scpainter_blender.core.geometry import cameras
from scpainter_blender.core.splats import gaussians as splats, gltf_splats, reader as splats_io

REAL = ("3dgs/loadersgl_train-1000.ply", "3dgs/supersplat_fruit_drops_minimal.ply", "3dgs/gshairlod_donut_fused.ply")
#: splat-transform writes a GLB in its engine frame, the PLY's turned 180° about z (its Transform.PLY), and we
#: turn glTF's +Y up to +Z up: p_ours = PLY_TO_OURS @ p_ply.
PLY_TO_OURS = gltf_splats.Y_UP_TO_Z_UP @ np.diag([-1.0, -1.0, 1.0])
# Bounds: the GLB holds float32 values (exp of log σ, sigmoid of the opacity logit); the turn and the inverse
# activations add float32 rounding only.
POSITION_BOUND = 1e-5     # relative to the scene's extent (1 unit here): float32 rounding
LOG_SCALE_BOUND = 1e-5    # log(float32(exp(s))) - s
OPACITY_BOUND = 1e-6      # after the sigmoid
QUAT_BOUND = 1e-5         # unit quaternions up to sign, per component
COLOUR_BOUND = 1e-4       # SH colour at 200 view directions (rotated SH against the source's at the turned direction)


def colours(ply, dirs):
    return splats.sh_to_rgb(splats.sh_coefficients(ply.f_dc, ply.f_rest), dirs)


def assert_turned(got, src, M, xyz=None, log_scale=0.0, opacity_bound=OPACITY_BOUND):
    """``got`` = ``src`` turned by the rotation ``M`` (positions ``xyz``, default M p; quaternions; SH), its log σ
    plus ``log_scale``, its opacity kept."""
    assert got.format == "gltf_splats" and len(got) == len(src) and got.sh_degree == src.sh_degree
    xyz = src.xyz.astype(np.float64) @ M.T if xyz is None else xyz
    extent = max(1.0, float(np.abs(xyz).max()))
    assert np.abs(got.xyz - xyz).max() <= POSITION_BOUND * extent
    assert np.abs(got.scale - (src.scale + log_scale)).max() <= LOG_SCALE_BOUND
    o = lambda p: splats.opacities_from_logits(p.opacity)  # noqa: E731
    assert np.abs(o(got) - o(src)).max() <= opacity_bound
    want = gltf_splats._quat_multiply(cameras.rotation_to_quaternion(M), splats.unit_quaternions(src.rot))
    q = splats.unit_quaternions(got.rot)
    q *= np.where((q * want).sum(1) < 0, -1.0, 1.0)[:, None]
    assert np.abs(q - want).max() <= QUAT_BOUND
    d = np.random.default_rng(0).normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rows = np.random.default_rng(1).integers(0, len(src), 200)
    sub = lambda p: splats.GaussianPly(p.xyz[rows], p.f_dc[rows], p.f_rest[rows], p.opacity[rows],  # noqa: E731
                                       p.scale[rows], p.rot[rows])
    assert np.abs(colours(sub(got), d @ M.T) - colours(sub(src), d)).max() <= COLOUR_BOUND


@pytest.mark.parametrize("rel", REAL + (F.GENERATED,))
def test_splat_transform_glb_reads_back(tmp_path, rel):
    src_path = F.source_ply(rel, tmp_path)
    out = splat_transform.convert(src_path, tmp_path / "car.glb")
    assert splats_io.detect(out) == "gltf_splats" and not splats_io.is_mesh(out)
    assert_turned(splats_io.read(out), splats_io.read(src_path), PLY_TO_OURS)


def _gltf(path, ply, node_tree, buffer_name="car splats.bin", required=(), interleave=True):
    """A .gltf of ``splat_fixtures.gltf_splats`` with its buffer in an external file ``buffer_name`` (its URI
    percent-encoded); returns the JSON."""
    tree, blob = F.gltf_splats(ply, node_tree, buffer_uri=buffer_name.replace(" ", "%20"), required=required)
    (path.parent / buffer_name).write_bytes(blob)
    path.write_text(json.dumps(tree))
    return tree


def test_gltf_with_node_transforms_and_external_buffer(tmp_path):
    src = F.random_ply(N=300, degree=2, seed=3)
    # parent: 90° about y and a uniform scale 2, translated; child: matrix form, a turn of 30° about x
    half = np.sqrt(0.5)
    Rx = cameras.quaternion_to_rotation(np.array([np.cos(np.pi / 12), np.sin(np.pi / 12), 0, 0]))
    child = np.eye(4)
    child[:3, :3], child[:3, 3] = Rx, (0.5, 0.0, -1.0)
    nodes = [{"translation": [1.0, 2.0, 3.0], "rotation": [0.0, half, 0.0, half], "scale": [2.0, 2.0, 2.0],
              "children": [1]}, {"matrix": child.T.ravel().tolist(), "mesh": 0}]
    _gltf(tmp_path / "car.gltf", src, nodes)
    got = splats_io.read(tmp_path / "car.gltf")
    Ry = cameras.quaternion_to_rotation(np.array([half, 0.0, half, 0.0]))
    world = np.eye(4)
    world[:3, :3], world[:3, 3] = 2.0 * Ry, (1.0, 2.0, 3.0)
    world = world @ child
    M = gltf_splats.Y_UP_TO_Z_UP @ (world[:3, :3] / 2.0)
    xyz = (src.xyz.astype(np.float64) @ world[:3, :3].T + world[:3, 3]) @ gltf_splats.Y_UP_TO_Z_UP.T
    # σ doubled by the node's scale; opacity through a normalised byte: half a step after the sigmoid
    assert_turned(got, src, M, xyz=xyz, log_scale=np.log(2.0), opacity_bound=0.5 / 255 + 1e-6)


def test_mesh_gltf_stays_a_mesh_and_refusals_name_the_field(tmp_path):
    glb = realdata("trellis/uanu2002_trellis_sample.glb")
    assert splats_io.is_mesh(glb)
    with pytest.raises(splats.SplatsError, match=r"uanu2002_trellis_sample\.glb: a mesh \(\.glb\), not Gaussian "
                                                 r"splats \(no KHR_gaussian_splatting\)"):
        splats_io.read(glb)
    src = F.random_ply(N=20, degree=0, seed=5)
    _gltf(tmp_path / "c.gltf", src, [{"mesh": 0}], required=["EXT_meshopt_compression"])
    with pytest.raises(splats.SplatsError, match=r"c\.gltf: requires glTF extensions \['EXT_meshopt_compression'\]"):
        splats_io.read(tmp_path / "c.gltf")
    _gltf(tmp_path / "s.gltf", src, [{"scale": [1.0, -2.0, 1.0], "mesh": 0}])
    with pytest.raises(splats.SplatsError, match=r"s\.gltf: nodes\[0\]: its transform mirrors or flattens the "
                                                 r"splats \(determinant -2\)"):
        splats_io.read(tmp_path / "s.gltf")
    tree = _gltf(tmp_path / "a.gltf", src, [{"mesh": 0}])
    tree["accessors"][2]["count"] = 21
    (tmp_path / "a.gltf").write_text(json.dumps(tree))
    with pytest.raises(splats.SplatsError, match=r"a\.gltf: accessors\[2\]: 21 elements of 12 bytes"):
        splats_io.read(tmp_path / "a.gltf")
    tree["accessors"][2]["count"] = 20
    tree["buffers"][0]["uri"] = "../outside.bin"
    (tmp_path / "o.gltf").write_text(json.dumps(tree))
    with pytest.raises(splats.SplatsError, match=r"o\.gltf: buffers\[0\]\.uri: '\.\./outside\.bin' is outside"):
        splats_io.read(tmp_path / "o.gltf")
    # a glTF without the extension is a mesh, by content, whatever its name
    del tree["extensionsUsed"]
    del tree["meshes"][0]["primitives"][0]["extensions"]
    tree["buffers"][0]["uri"] = "car%20splats.bin"
    (tmp_path / "m.gltf").write_text(json.dumps(tree))
    assert splats_io.is_mesh(tmp_path / "m.gltf") and not splats_io.is_mesh(tmp_path / "s.gltf")
    # a GLB with the extension named .splat is still read as glTF splats
    j = json.dumps({**_gltf(tmp_path / "g.gltf", src, [{"mesh": 0}]), "buffers": [
        {"byteLength": (tmp_path / "car splats.bin").stat().st_size}]}).encode()
    j += b" " * (-len(j) % 4)
    blob = (tmp_path / "car splats.bin").read_bytes()
    data = struct.pack("<III", 0x46546C67, 2, 28 + len(j) + len(blob)) + struct.pack("<II", len(j), 0x4E4F534A) + j
    data += struct.pack("<II", len(blob), 0x004E4942) + blob
    (tmp_path / "g.splat").write_bytes(data)
    assert splats_io.read(tmp_path / "g.splat").format == "gltf_splats"


@pytest.mark.parametrize("where, value, field", [
    (("meshes", 0, "primitives"), 5, "meshes[0].primitives"),
    (("meshes", 0, "primitives", 0, "attributes"), ["POSITION"], "meshes[0].primitives[0].attributes"),
    (("meshes", 0, "primitives", 0, "attributes"), "POSITION", "meshes[0].primitives[0].attributes"),
    (("extensionsRequired",), 5, "extensionsRequired"),
    (("extensionsRequired",), gltf_splats.EXTENSION, "extensionsRequired"),
    (("nodes", 0, "children"), 5, "nodes[0].children"),
    (("scenes", 0, "nodes"), 5, "scenes[0].nodes"),
    (("nodes", 0, "translation"), 10 ** 400, "nodes[0]"),
])
def test_malformed_gltf_structure_is_refused_by_field(tmp_path, where, value, field):
    """Fuzz findings (tests/fuzz_splat_formats.py, issue 31): JSON of the wrong type where the glTF has a list or
    an object, and a number beyond float, were tracebacks (TypeError, OverflowError)."""
    src = F.random_ply(N=10, degree=1, seed=2)
    tree, blob = F.gltf_splats(src, [{"mesh": 0}])
    node = tree
    for k in where[:-1]:
        node = node[k]
    node[where[-1]] = [value, 0, 0] if where[-1] == "translation" else value
    path = tmp_path / "bad.glb"
    path.write_bytes(F.glb(tree, blob))
    with pytest.raises(splats.SplatsError, match=r"bad\.glb: ") as e:
        splats_io.read(path)
    assert e.value.field == field, str(e.value)


@pytest.mark.parametrize("key, value", [("kernel", "3dgut"), ("colorSpace", "lin_rec709_display"),
                                        ("projection", "orthographic"), ("kernel", 7)])
def test_a_kernel_colour_space_or_projection_the_renderer_does_not_draw_is_refused(tmp_path, key, value):
    """The fresh tester's finding: a linear colour space was read as sRGB and an unknown kernel accepted, silently.
    The extension's defaults (an older draft's file without the properties) and splat-transform's values read."""
    src = F.random_ply(N=10, degree=1, seed=2)
    tree, blob = F.gltf_splats(src, [{"mesh": 0}])
    ext = tree["meshes"][0]["primitives"][0]["extensions"][gltf_splats.EXTENSION]
    path = tmp_path / "plain.glb"
    path.write_bytes(F.glb(tree, blob))
    assert len(splats_io.read(path)) == 10
    ext.update(kernel="ellipse", colorSpace="srgb_rec709_display", projection="perspective",
               sortingMethod="cameraDistance")
    path.write_bytes(F.glb(tree, blob))
    assert len(splats_io.read(path)) == 10
    ext[key] = value
    path = tmp_path / "other.glb"
    path.write_bytes(F.glb(tree, blob))
    with pytest.raises(splats.SplatsError, match=r"other\.glb: ") as e:
        splats_io.read(path)
    assert e.value.field == f"meshes[0].primitives[0].extensions.{gltf_splats.EXTENSION}.{key}", str(e.value)


@pytest.mark.parametrize("linear", [np.diag([1.0, 3.0, 0.5]),                       # a non-uniform scale
                                    np.array([[1.0, 0.7, 0.0], [0.0, 1.0, 0.0], [0.2, 0.0, 2.0]])])  # a shear
def test_any_node_transform_of_positive_determinant_maps_each_covariance(tmp_path, linear):
    """The fresh tester's finding: non-uniform node scales were refused, though a Gaussian mapped by any linear L
    is the Gaussian of L Σ Lᵀ (the extension's own formula). The reference is that product, from the file's own
    values; the read Gaussians' R diag(σ²) Rᵀ must equal it, and their means L x + t."""
    src = F.random_ply(N=200, degree=1, seed=7)
    node = np.eye(4)
    node[:3, :3], node[:3, 3] = linear, (0.3, -1.0, 2.0)
    _gltf(tmp_path / "car.gltf", src, [{"matrix": node.T.ravel().tolist(), "mesh": 0}])
    got = splats.decode(splats_io.read(tmp_path / "car.gltf"))
    ref = splats.decode(src)
    L = gltf_splats.Y_UP_TO_Z_UP @ linear
    Rq = cameras.quaternion_to_rotation(ref.quats.astype(np.float64)) * ref.scales.astype(np.float64)[:, None, :]
    want = L @ Rq @ np.swapaxes(Rq, 1, 2) @ L.T
    Rg = cameras.quaternion_to_rotation(got.quats.astype(np.float64)) * got.scales.astype(np.float64)[:, None, :]
    have = Rg @ np.swapaxes(Rg, 1, 2)
    # per Gaussian, relative to its largest entry: float32 storage of q and log σ (and of the file's values)
    assert (np.abs(have - want).max(axis=(1, 2)) / np.abs(want).max(axis=(1, 2))).max() < 1e-5
    xyz = (src.xyz.astype(np.float64) @ linear.T + node[:3, 3]) @ gltf_splats.Y_UP_TO_Z_UP.T
    np.testing.assert_allclose(got.means, xyz, atol=1e-5)
    assert len(got) == 200 and not got.dropped
