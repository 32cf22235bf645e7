"""backend.render against an independent float64 brute-force renderer, on random scenes and extreme cases."""

import functools

import numpy as np
import pytest
import torch

from backend.render import gaussians as GS
from backend.render import points as PT
from backend.render import tiles as TL
from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core.splats import gaussians as splats


# -- the reference: float64 numpy, one Gaussian at a time over every pixel --------------------------------------

def jacobian_limits(K, W, H):
    """gsplat 1.5.3's clamp of x/z and y/z (persp_proj in gsplat/cuda/include/Utils.cuh): the image's tangent range
    widened by 0.3·tan(half fov) on each side, around the principal point. Returns (lo_x, hi_x, lo_y, hi_y)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy
    return -(cx / fx + 0.3 * tan_x), (W - cx) / fx + 0.3 * tan_x, -(cy / fy + 0.3 * tan_y), (H - cy) / fy + 0.3 * tan_y


def reference_gaussians(means, quats, scales, opac, sh, K, w2c, W, H, bg_depth=None, near=0.05, limits=None,
                        asset_id=None):
    """Every Gaussian at every pixel in depth order (ties by index): no screen extent, no tiles. The same
    compositing rules as the renderer, written independently and in float64. ``limits`` overrides the Jacobian
    clamp (lo_x, hi_x, lo_y, hi_y) (default: gsplat's, ``jacobian_limits``). Returns (colour, asset mask); with
    ``asset_id`` (N,) (1-based, per Gaussian) also the instance (H, W) int: per pixel the asset whose weights
    Σ α·T sum highest (np.argmax: the first, the lower id, on ties) where that sum exceeds the transmittance
    left, else 0."""
    means, quats, scales = (np.asarray(a, np.float64) for a in (means, quats, scales))
    R_w, t_w = w2c[:3, :3], w2c[:3, 3]
    fx, fy, cx, cy, skew = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    lo_x, hi_x, lo_y, hi_y = jacobian_limits(K, W, H) if limits is None else limits
    vu, uu = np.mgrid[0:H, 0:W] + 0.5
    trans = np.ones((H, W))  # transmittance
    done = np.zeros((H, W), bool)
    col = np.zeros((H, W, 3))
    n_assets = 1 if asset_id is None else int(np.max(asset_id, initial=1))
    w_asset = np.zeros((H, W, n_assets))
    centre = -R_w.T @ t_w
    items = []
    for i in range(len(means)):
        vals = np.concatenate([means[i], quats[i], scales[i], [opac[i]], sh[i].ravel()])
        qn = np.linalg.norm(quats[i]) if np.all(np.isfinite(vals)) else 0.0
        p = R_w @ means[i] + t_w
        if qn <= 1e-12 or p[2] <= near or opac[i] < 1 / 255:
            continue
        items.append((p[2], i, p))
    for z, i, p in sorted(items, key=lambda e: (e[0], e[1])):
        Rq = C.quaternion_to_rotation(quats[i] / np.linalg.norm(quats[i]))
        M = R_w @ Rq @ np.diag(np.abs(scales[i]))
        cov = M @ M.T
        tx, ty = np.clip(p[0] / z, lo_x, hi_x) * z, np.clip(p[1] / z, lo_y, hi_y) * z
        J = np.array([[fx / z, 0, -fx * tx / z ** 2], [0, fy / z, -fy * ty / z ** 2]])
        c2 = J @ cov @ J.T + 0.3 * np.eye(2)
        if np.linalg.det(c2) <= 0:
            continue
        conic = np.linalg.inv(c2)
        mu = np.array([fx * p[0] / z + skew * p[1] / z + cx, fy * p[1] / z + cy])
        du, dv = uu - mu[0], vu - mu[1]
        power = -0.5 * (conic[0, 0] * du ** 2 + 2 * conic[0, 1] * du * dv + conic[1, 1] * dv ** 2)
        alpha = np.minimum(0.99, opac[i] * np.exp(power))
        use = (alpha >= 1 / 255) & (power <= 0) & ~done
        if bg_depth is not None:
            use &= z < bg_depth
        d = means[i] - centre
        rgb = splats.sh_to_rgb(sh[i][None], (d / np.linalg.norm(d))[None])[0]
        trans_next = trans * (1 - alpha)
        stop = use & (trans_next < 1e-4)
        done |= stop
        use &= ~stop
        col += np.where(use[..., None], (alpha * trans)[..., None] * rgb, 0)
        if asset_id is not None:
            w_asset[..., asset_id[i] - 1] += np.where(use, alpha * trans, 0.0)
        trans = np.where(use, trans_next, trans)
    if asset_id is None:
        return col, 1 - trans  # colour, asset mask
    best = np.argmax(w_asset, -1)
    won = np.take_along_axis(w_asset, best[..., None], -1)[..., 0] > trans
    return col, 1 - trans, np.where(won, best + 1, 0)


def random_scene(n, seed, degree=1, spread=2.0):
    rng = np.random.default_rng(seed)
    means = rng.uniform([-spread, -spread * 0.6, 3], [spread, spread * 0.6, 9], (n, 3))
    quats = rng.normal(size=(n, 4)) * rng.uniform(0.2, 3.0, (n, 1))  # unnormalised on purpose
    scales = np.exp(rng.uniform(np.log(0.01), np.log(0.5), (n, 3)))
    opac = rng.uniform(0.05, 1.0, n)
    sh = rng.normal(0, 0.4, (n, (degree + 1) ** 2, 3))
    return means, quats, scales, opac, sh


K = np.array([[60.0, 0, 32.0], [0, 60.0, 24.0], [0, 0, 1]])
EYE = np.eye(4)


# Every fast path is checked against the reference: the torch pair rasterizer (after the torch projection) and the
# production path (the tile kernels after the default projection: numba on the CPU, Triton on CUDA), each on the
# devices it runs on, in float64 (equal to the reference within 1e-6; the CUDA tile kernel is float32 inside) and in
# float32 (within 1e-4).
RASTERIZERS = [
    pytest.param(("pairs", "cpu"), id="pairs-cpu"),
    pytest.param(("tiles", "cpu"), id="tiles-cpu"),
    pytest.param(("pairs", "cuda"), id="pairs-cuda", marks=pytest.mark.gpu),
    pytest.param(("tiles", "cuda"), id="tiles-cuda", marks=pytest.mark.gpu),
]
DTYPES = [pytest.param(torch.float64, id="f64"), pytest.param(torch.float32, id="f32")]


@pytest.fixture(params=RASTERIZERS)
def raster(request):
    return request.param


@pytest.fixture(params=DTYPES)
def dtype(request):
    return request.param


def tolerance(dtype, raster):
    return 1e-6 if dtype == torch.float64 and raster != ("tiles", "cuda") else 1e-4


def fast(means, quats, scales, opac, sh, K, w2c, W, H, bg=None, dtype=torch.float32, raster=("pairs", "cpu")):
    kind, device = raster
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=dtype, device=device)  # noqa: E731
    proj = GS.project(t(means), t(quats), t(scales), t(opac), t(sh), K, w2c, W, H, fast=kind == "tiles")
    rasterize = GS.rasterize if kind == "pairs" else TL.rasterize
    col, asset_mask, *_ = rasterize(proj, W, H, None if bg is None else t(bg))
    return col.double().cpu().numpy(), asset_mask.double().cpu().numpy()


def max_err(got, ref):
    return max(float(np.abs(g - r).max()) if g.size else 0.0 for g, r in zip(got, ref))


@pytest.mark.parametrize("seed,degree", [(0, 0), (1, 1), (2, 3)])
def test_random_scenes_equal_the_dense_render(seed, degree, raster, dtype):
    """The render equals the reference with no screen extent at all: the extent drops nothing the rules keep."""
    scene = random_scene(150, seed, degree)
    ref = reference_gaussians(*scene, K, EYE, 64, 48)
    assert max_err(fast(*scene, K, EYE, 64, 48, dtype=dtype, raster=raster), ref) <= tolerance(dtype, raster)
    assert ref[1].max() > 0.5  # the scene is not empty


def test_faint_wide_gaussians_equal_the_dense_render(raster, dtype):
    """Opacities from 0.01 to 1 and Gaussians stretched along one axis: the 3σ square of the old renderer lost
    8.6e-4 of the asset mask here against the dense render (and 1.3e-3 to 4.4e-3 on the random scenes above); the
    opacity-aware extent keeps every α >= 1/255."""
    means, quats, scales, opac, sh = random_scene(60, 13, 1)
    scales[:, 0] *= 4.0                       # wide along one axis: the 3σ square's corners are not where it fails
    opac[:] = np.linspace(0.01, 1.0, len(opac))
    ref = reference_gaussians(means, quats, scales, opac, sh, K, EYE, 64, 48)
    got = fast(means, quats, scales, opac, sh, K, EYE, 64, 48, dtype=dtype, raster=raster)
    assert max_err(got, ref) <= tolerance(dtype, raster) and ref[1].max() > 0.5


def test_extent_holds_every_pixel_with_visible_alpha():
    """gsplat's rule, checked directly: every pixel where a Gaussian's α reaches 1/255 is inside its pixel box, and
    the radius is ceil(min(3.33, sqrt(2 ln(255 o))) · sqrt(Σ₂ii))."""
    W, H = 64, 48
    scene = random_scene(200, 14, 0)
    scene[3][:] = np.random.default_rng(14).uniform(1 / 255, 1.0, 200)   # opacities down to the threshold
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float64)  # noqa: E731
    proj = GS.project(*(t(a) for a in scene), K, EYE, W, H, fast=False)
    boxes = GS.pixel_boxes(proj, W, H).numpy()
    vu, uu = np.mgrid[0:H, 0:W] + 0.5
    inside_any = 0
    for g in range(len(proj["depth"])):
        (ca, cb, cc), (mx, my) = proj["conic"][g].numpy(), proj["mean2d"][g].numpy()
        du, dv = uu - mx, vu - my
        alpha = proj["opacity"][g].item() * np.exp(-0.5 * (ca * du ** 2 + 2 * cb * du * dv + cc * dv ** 2))
        vis = alpha >= 1 / 255
        x0, x1, y0, y1 = boxes[g]
        box = (uu - 0.5 >= x0) & (uu - 0.5 <= x1) & (vu - 0.5 >= y0) & (vu - 0.5 <= y1)
        assert not (vis & ~box).any(), g
        inside_any += vis.sum()
        sxx, syy = cc / (ca * cc - cb * cb), ca / (ca * cc - cb * cb)  # Σ₂ = conic⁻¹
        extend = min(3.33, np.sqrt(2 * np.log(255 * proj["opacity"][g].item())))
        assert np.allclose(proj["radius"][g].numpy(), np.ceil(extend * np.sqrt([sxx, syy])), atol=0)
    assert inside_any > 1000


def test_jacobian_clamp_follows_the_principal_point(raster, dtype):
    """An off-centre K: the clamp is gsplat's, -(cx/fx + 0.3·tan) .. (W - cx)/fx + 0.3·tan. Large Gaussians just
    outside the view on the short side reach into the image with the clamped J; the centred clamp
    (±1.3·tan(fov/2)) would render them differently, and the reference tells the two apart."""
    W, H = 64, 48
    Ko = np.array([[60.0, 0, 10.0], [0, 60.0, 40.0], [0, 0, 1]])  # principal point near the top-left corner
    lo_x, hi_x, lo_y, hi_y = jacobian_limits(Ko, W, H)
    assert np.allclose(GS.jacobian_limits(Ko, W, H), (-lo_x, hi_x, -lo_y, hi_y))
    means, quats, scales, opac, sh = random_scene(40, 15, 1)
    means[:20, 0] = -0.55 * means[:20, 2]     # x/z = -0.55: outside the view (-cx/fx = -0.17) and past -0.33
    means[20:, 1] = -0.9 * means[20:, 2]      # y/z = -0.9: past -(cy/fy + 0.3·tan_y) = -0.79
    scales[:] = np.maximum(scales, 0.8)        # wide enough to reach into the image
    ref = reference_gaussians(means, quats, scales, opac, sh, Ko, EYE, W, H)
    got = fast(means, quats, scales, opac, sh, Ko, EYE, W, H, dtype=dtype, raster=raster)
    assert ref[1].max() > 0.5 and max_err(got, ref) <= tolerance(dtype, raster)
    centred = 1.3 * 0.5 * W / 60.0, 1.3 * 0.5 * H / 60.0
    old = reference_gaussians(means, quats, scales, opac, sh, Ko, EYE, W, H,
                              limits=(-centred[0], centred[0], -centred[1], centred[1]))
    assert max_err(old, ref) > 1e-2


def test_centred_jacobian_clamp_is_inria_s():
    Kc = np.array([[60.0, 0, 32.0], [0, 50.0, 24.0], [0, 0, 1]])
    assert np.allclose(GS.jacobian_limits(Kc, 64, 48), [1.3 * 32 / 60] * 2 + [1.3 * 24 / 50] * 2)


def extreme_scene():
    means, quats, scales, opac, sh = random_scene(40, 7, 0)
    scales[0] = 0.0                       # degenerate: the 0.3 px blur keeps it a tiny disk
    scales[1] = [300.0, 1e-4, 50.0]       # huge and flat
    quats[2] = 0.0                        # zero quaternion: dropped
    means[3, 0] = np.nan                  # NaN row: dropped
    means[4] = [0.0, 0.0, 0.02]           # in front of the camera but inside the near plane: culled
    means[5] = [0.0, 0.0, -3.0]           # behind the camera
    means[6], scales[6] = [0.2, 0.1, 0.5], [2.0, 2.0, 2.0]  # the camera inside a Gaussian
    means[7] = [500.0, 0.0, 4.0]          # far off-screen: the clamped Jacobian keeps it bounded
    opac[8] = 1 / 255                     # at the threshold: an extent of 0 px (α < 1/255 off its mean)
    opac[9] = 0.5 / 255                   # below it: dropped
    sh[10, 0, 1] = np.inf                 # non-finite colour: dropped
    return means, quats, scales, opac, sh


def test_extreme_cases(raster, dtype):
    scene = extreme_scene()
    got = fast(*scene, K, EYE, 64, 48, dtype=dtype, raster=raster)
    ref = reference_gaussians(*scene, K, EYE, 64, 48)
    assert np.all(np.isfinite(got[0])) and np.all(np.isfinite(got[1]))
    assert max_err(got, ref) <= tolerance(dtype, raster)


def test_far_from_origin_relative_to_camera(raster, dtype):
    """1e5 m offsets: positions relative to a scene origin, the camera re-expressed for it."""
    means, quats, scales, opac, sh = random_scene(80, 8, 0)
    offset = np.array([1e5, -2e5, 30.0])
    w2c = np.eye(4)
    w2c[:3, 3] = -offset                  # the same camera, now standing at the offset
    rel = PT.relative_camera(w2c, offset)
    got = fast(means, quats, scales, opac, sh, K, rel, 64, 48, dtype=dtype, raster=raster)  # relative to `offset`
    ref = reference_gaussians(means, quats, scales, opac, sh, K, EYE, 64, 48)
    assert max_err(got, ref) <= tolerance(dtype, raster)


@pytest.mark.parametrize("W,H", [(1, 1), (3, 1), (64, 48)])
def test_tiny_images_and_empty_scenes(W, H, raster, dtype):
    Kt = np.array([[W * 0.9, 0, W / 2], [0, W * 0.9, H / 2], [0, 0, 1]])
    scene = random_scene(30, 9, 0)
    got = fast(*scene, Kt, EYE, W, H, dtype=dtype, raster=raster)
    ref = reference_gaussians(*scene, Kt, EYE, W, H)
    assert got[0].shape == (H, W, 3) and max_err(got, ref) <= tolerance(dtype, raster)
    empty = [a[:0] for a in scene]
    col, mask = fast(*empty, Kt, EYE, W, H, dtype=dtype, raster=raster)
    assert not col.any() and not mask.any()


def test_points_hide_gaussians_behind_them(raster, dtype):
    scene = random_scene(100, 10, 0)
    bg = np.full((48, 64), np.inf)
    bg[:, :32] = 5.0                      # a wall of points at 5 m over the left half
    got = fast(*scene, K, EYE, 64, 48, bg=bg, dtype=dtype, raster=raster)
    ref = reference_gaussians(*scene, K, EYE, 64, 48, bg_depth=bg)
    assert max_err(got, ref) <= tolerance(dtype, raster)


# -- points ------------------------------------------------------------------------------------------------------

def reference_points(xyz, rgb, K, w2c, W, H, near=0.05):
    img, depth, win = np.zeros((H, W, 3)), np.full((H, W), np.inf), np.full((H, W), -1)
    for i, p in enumerate(xyz):
        c = w2c[:3, :3] @ p + w2c[:3, 3]
        if not np.all(np.isfinite(c)) or c[2] <= near:
            continue
        u = np.floor(K[0, 0] * c[0] / c[2] + K[0, 1] * c[1] / c[2] + K[0, 2])
        v = np.floor(K[1, 1] * c[1] / c[2] + K[1, 2])
        if 0 <= u < W and 0 <= v < H:
            u, v = int(u), int(v)
            z = np.float32(c[2])
            if z < depth[v, u]:  # strictly nearer wins; equal depth keeps the lower index
                depth[v, u], win[v, u], img[v, u] = z, i, rgb[i]
    return img, depth, win


def test_points_zbuffer_matches_reference_and_breaks_ties_by_index():
    rng = np.random.default_rng(0)
    xyz = rng.uniform([-3, -2, -1], [3, 2, 10], (5000, 3))
    xyz[10] = xyz[11] = [0.1, 0.1, 4.0]   # an exact tie: index 10 wins
    xyz[12] = [0.0, 0.0, 0.0]             # at the camera
    xyz[13, 1] = np.nan
    rgb = rng.random((5000, 3))
    img, depth, win = PT.render_points(torch.tensor(xyz, dtype=torch.float32), torch.tensor(rgb, dtype=torch.float32),
                                       K, EYE, 64, 48)
    r_img, r_depth, r_win = reference_points(xyz.astype(np.float32).astype(np.float64), rgb, K, EYE, 64, 48)
    assert np.array_equal(win.numpy(), r_win)
    assert np.allclose(depth.numpy(), r_depth) and np.allclose(img.numpy(), r_img, atol=1e-7)
    u = int(np.floor(60 * 0.1 / 4 + 32)), int(np.floor(60 * 0.1 / 4 + 24))
    assert win[u[1], u[0]] == 10


def test_point_splat_radius():
    xyz = torch.tensor([[0.0, 0.0, 5.0], [0.0, 0.0, 4.0]])
    rgb = torch.tensor([[1.0, 0, 0], [0, 1.0, 0]])
    img, depth, win = PT.render_points(xyz, rgb, K, EYE, 64, 48, radius_px=2)
    assert (win >= 0).sum() == 25 and torch.all(win[win >= 0] == 1)  # the nearer point covers the 5x5 square


def test_4096_wide_image(raster):
    """A 4096 x 2304 frame (pixel coordinates in the thousands, float32) and 4096 x 1: both still match."""
    W, H = 4096, 2304
    scene, (Kw, ref), (K1, ref1) = wide_references()
    got = fast(*scene, Kw, EYE, W, H, raster=raster)
    assert ref[1].max() > 0.5 and max_err(got, ref) <= 1e-4
    got = fast(*scene, K1, EYE, W, 1, raster=raster)
    assert max_err(got, ref1) <= 1e-4


@functools.lru_cache(maxsize=1)
def wide_references():
    """The dense reference of test_4096_wide_image, computed once for every rasterizer (9.4 M pixels)."""
    W, H = 4096, 2304
    scene = random_scene(6, 11, 1, spread=3.0)
    Kw = np.array([[2800.0, 0, W / 2], [0, 2800.0, H / 2], [0, 0, 1]])
    K1 = np.array([[2800.0, 0, W / 2], [0, 2800.0, 0.5], [0, 0, 1]])
    return (scene, (Kw, reference_gaussians(*scene, Kw, EYE, W, H)), (K1, reference_gaussians(*scene, K1, EYE, W, 1)))


def test_tile_size_does_not_change_the_image():
    scene = random_scene(300, 12, 1)
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    proj = GS.project(*(t(a) for a in scene), K, EYE, 64, 48)
    out = [TL.rasterize(proj, 64, 48, tile=s) for s in (4, 16, 64)]
    for o in out[1:]:
        assert all(torch.equal(a, b) for a, b in zip(out[0], o))


def test_points_on_a_4096_wide_image():
    rng = np.random.default_rng(3)
    W, H = 4096, 64
    Kw = np.array([[2000.0, 0, W / 2], [0, 2000.0, H / 2], [0, 0, 1]])
    xyz = rng.uniform([-5, -0.1, 2], [5, 0.1, 6], (20000, 3)).astype(np.float32).astype(np.float64)
    # float32 projection carries ~1e-4 px of rounding at u ~ 4000: a point that close to a pixel edge may land on
    # either side, which is float32's contract, not a z-buffer error. Leave those few out and demand exactness.
    u = Kw[0, 0] * xyz[:, 0] / xyz[:, 2] + Kw[0, 2]
    v = Kw[1, 1] * xyz[:, 1] / xyz[:, 2] + Kw[1, 2]
    edge = lambda x: np.abs(x - np.round(x)) < 2e-3  # noqa: E731
    xyz = xyz[~edge(u) & ~edge(v)]
    rgb = rng.random((len(xyz), 3))
    img, depth, win = PT.render_points(torch.tensor(xyz, dtype=torch.float32), torch.tensor(rgb, dtype=torch.float32),
                                       Kw, EYE, W, H)
    r_img, r_depth, r_win = reference_points(xyz, rgb, Kw, EYE, W, H)
    assert len(xyz) > 19700 and (r_win >= 0).sum() > 5000 and np.array_equal(win.numpy(), r_win)


def test_torch_and_numpy_evaluate_one_formula():
    """The renderer's SH colours (torch) and core.splats.gaussians' (numpy): both from core.splats.sh.basis, equal to rounding."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for degree in range(4):
        coeffs = rng.normal(0, 0.5, (50, (degree + 1) ** 2, 3))
        got = GS.sh_colors(torch.as_tensor(coeffs), torch.as_tensor(d)).numpy()
        assert np.allclose(got, splats.sh_to_rgb(coeffs, d), atol=1e-12, rtol=0), degree
