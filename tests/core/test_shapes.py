"""core.shapes: the procedural car, surface Gaussians, and saving them the way Amodal3R does."""

import numpy as np

from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core import shapes
from scpainter_blender.core.splats import gaussians as splats, reader as splats_io


def test_car_dimensions():
    b = shapes.MeshBuilder()
    shapes.add_car(b, np.random.default_rng(0), "paint", "glass", "tyre")
    lo, hi = b.bounds()
    assert np.allclose(lo[:2], [-0.92, -2.2]) and np.allclose(hi[:2], [0.92, 2.2])
    assert lo[2] == 0.0 and 1.4 < hi[2] < 1.7
    tri, slot = b.triangles()
    assert set(slot.tolist()) == {0, 1, 2} and tri.shape[1:] == (3, 3)


def test_surface_gaussians_lie_flat_on_the_surface():
    b = shapes.MeshBuilder()
    b.box((0, 0, 1), (2.0, 4.0, 2.0), "red")
    g = shapes.surface_gaussians(b, {"red": (1.0, 0.0, 0.0)}, 5000, seed=1)
    assert len(g) == 5000
    local = np.abs(g.means - [0, 0, 1])
    on_face = np.isclose(local, [1.0, 2.0, 1.0], atol=1e-6)
    assert np.all(on_face.sum(axis=1) >= 1)  # every mean sits on a face of the box
    R = C.quaternion_to_rotation(g.quats)
    normal = R[:, :, 2]  # local z
    face_axis = np.argmax(on_face, axis=1)
    assert np.allclose(np.abs(normal[np.arange(5000), face_axis]), 1.0, atol=1e-5)
    assert np.all(g.scales[:, 2] < g.scales[:, 0])  # flat along the normal
    assert np.allclose(g.base_colors(), [1.0, 0.0, 0.0], atol=1e-6)
    # area-weighted: the ±x and ±z faces (4 x 2 m) get twice the samples of the ±y ends (2 x 2 m)
    counts = np.bincount(face_axis, minlength=3)
    assert abs(counts[0] / counts[1] - 2.0) < 0.2 and abs(counts[1] / counts[2] - 0.5) < 0.05


def test_outward_normals():
    b = shapes.MeshBuilder()
    b.cylinder((0, 0, 0), 1.0, 2.0, 1, "m")
    b.cylinder((5, 0, 0), 1.0, 2.0, 0, "m")
    tri, _ = b.triangles()
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centre = tri.mean(axis=1) - np.where(tri.mean(axis=1)[:, :1] > 2.5, [5.0, 0, 0], [0.0, 0, 0])
    assert np.all(np.einsum("ij,ij->i", n, centre) > 0)


def test_save_as_amodal3r_round_trip(tmp_path):
    g = shapes.procedural_car_gaussians(count=3000, seed=2)
    A = shapes.save_as_amodal3r(tmp_path / "car.ply", g)
    raw = splats_io.read_ply(tmp_path / "car.ply")
    assert raw.sh_degree == 0 and set(raw.extra) == {"nx", "ny", "nz"}  # TRELLIS's 17 properties
    back = splats.decode(raw)
    assert np.all(np.abs(back.means) <= 0.5)                           # TRELLIS's unit cube
    restored = shapes.transform_gaussians(back, np.linalg.inv(A))
    assert np.abs(restored.means - g.means).max() < 1e-5
    assert np.allclose(restored.scales, g.scales, rtol=1e-4)
    dots = np.abs(np.einsum("ij,ij->i", restored.quats, g.quats))
    assert dots.min() > 1 - 1e-5
    assert np.allclose(back.opacities, 0.95, atol=1e-6)
