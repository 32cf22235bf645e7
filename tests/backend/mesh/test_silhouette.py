"""backend.mesh.silhouette: the mesh's own silhouette, and the rendered asset mask of its Gaussians against it (how
the default σ factor was chosen)."""

import numpy as np
import trimesh

from tests.backend.mesh import mesh_fixtures as MF
from backend.mesh import asset as ma
from backend.mesh.silhouette import look_at, mask_metrics, orbit_cameras, render_mask, silhouette


def test_silhouette_of_a_square():
    square = trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]], process=False)
    K = np.array([[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]])
    T = look_at((0, 0, 10), (0, 0, 0), up=(0, 1, 0))
    sil = silhouette(square.vertices, square.faces, K, T, 64, 64)
    assert sil.sum() == 400 and sil[22:42, 22:42].all()           # 20 x 20 pixel centres inside
    assert not silhouette(square.vertices, square.faces, K, look_at((0, 0, 5), (0, 0, 10), (0, 1, 0)), 64,
                          64).any()                                   # behind the camera


def test_rendered_mask_matches_the_silhouette():
    """20 k Gaussians on a 30 m² object seen from 9 m at 256 x 144 (σ ≈ 0.7 px): within about a pixel of the
    mesh's outline (the renderer's 0.3 px² blur alone spreads every edge by ~0.5 px), opaque inside."""
    car = MF.car_like_zup()
    g = ma.mesh_to_gaussians(car, 20000, seed=0)
    views = orbit_cameras((0, 0, 1), 9.0, 256, 144, views=3)
    sils = [silhouette(car.vertices, car.faces, K, T, 256, 144) for K, T in views]
    for (K, T), sil in zip(views, sils):
        m = mask_metrics(render_mask(g, K, T, 256, 144, reference=True), sil)
        assert sil.sum() > 3000
        assert m["iou"] > 0.92 and m["leak"] < 0.005 and m["spill"] < 0.09 and m["boundary_px"] < 1.5, m
    # the trade-off c sets, seen with 2 k Gaussians (σ of pixels, above the blur): too small leaves holes (leak),
    # too large bleeds past the outline (spill); the default sits between
    K, T = views[0]
    m = {c: mask_metrics(render_mask(ma.mesh_to_gaussians(car, 2000, sigma_factor=c), K, T, 256, 144,
                                     reference=True), sils[0]) for c in (0.3, ma.SIGMA_FACTOR, 1.5)}
    assert m[0.3]["leak"] > 0.1 and m[1.5]["spill"] > 0.4
    assert m[ma.SIGMA_FACTOR]["mean_abs"] < 0.6 * min(m[0.3]["mean_abs"], m[1.5]["mean_abs"])
