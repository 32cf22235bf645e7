"""The numba point z-buffer (points_cpu) against the torch reference (points.render_points_torch): identical winners,
depths and colours, bit for bit, on random and extreme scenes."""

import numba
import numpy as np
import pytest
import torch

from backend.render import points as PT
from backend.render import points_cpu as PC

K = np.array([[60.0, 0.0, 32.0], [0.0, 60.0, 24.0], [0.0, 0.0, 1.0]])
EYE = np.eye(4)
W, H = 64, 48


def both(xyz, rgb, K=K, w2c=EYE, width=W, height=H, **kw):
    """(fast, reference) outputs; asserts the fast one has the documented dtypes and shapes."""
    xyz = torch.as_tensor(np.asarray(xyz), dtype=torch.float32)
    rgb = torch.as_tensor(np.asarray(rgb))
    fast = PT.render_points(xyz, rgb, K, w2c, width, height, **kw)
    ref = PT.render_points_torch(xyz, rgb, K, w2c, width, height, **kw)
    for a, dt, shape in zip(fast, (torch.float32, torch.float32, torch.int64),
                            ((height, width, 3), (height, width), (height, width))):
        assert a.dtype == dt and tuple(a.shape) == shape
    return fast, ref


def assert_identical(fast, ref):
    for a, b, name in zip(fast, ref, ("rgb", "depth", "winner")):
        assert torch.equal(a, b), f"{name}: {int((a != b).sum())} values differ"


def camera(rng):
    """A random rotation and translation (world_to_camera) and a K with skew and an off-centre principal point."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = R, rng.normal(0, 2, 3)
    Kr = np.array([[rng.uniform(30, 90), rng.uniform(-2, 2), rng.uniform(20, 44)],
                   [0.0, rng.uniform(30, 90), rng.uniform(14, 34)], [0.0, 0.0, 1.0]])
    return Kr, w2c


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("radius", [0, 1, 2])
def test_random_scenes_identical(seed, radius):
    rng = np.random.default_rng(seed)
    Kr, w2c = camera(rng)
    centre = -w2c[:3, :3].T @ w2c[:3, 3]
    xyz = centre + rng.normal(0, 4, (20000, 3))  # around the camera: in front, behind, beside
    rgb = rng.random((20000, 3)).astype(np.float32)
    fast, ref = both(xyz, rgb, Kr, w2c, radius_px=radius)
    assert (ref[2] >= 0).sum() > 300  # the scene shows something
    assert_identical(fast, ref)


def test_extreme_points_identical():
    """At and behind the camera, exactly at the near plane, on pixel borders, exact duplicates and equal depths,
    NaN/inf rows, far away and huge coordinates: each case the reference decides, the fast path decides alike."""
    rows = [[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [1.0, 1.0, -5.0],              # at and behind the camera
            [0.0, 0.0, float(np.float32(0.05))], [0.0, 0.0, 0.05000001],      # at the near plane and just past it
            [np.nan, 0.0, 2.0], [0.0, np.inf, 2.0], [0.0, 0.0, np.inf], [-np.inf, 1.0, 1.0],
            [1e5, 1e5, 1e5], [1e5, -3e4, 2e5], [0.0, 0.0, 1e30], [1e-30, 1e-30, 1e-30]]
    # pixel borders: u = 60 x / z + 32 is exactly an integer (x a multiple of 1/60 is not exact, so use z = 60:
    # u = x + 32), and the image edges u = 0, u = W, v = 0, v = H
    for u in (0.0, 1.0, 31.0, 32.0, 63.0, 64.0, -1.0):
        for v in (0.0, 23.0, 24.0, 47.0, 48.0):
            rows.append([u - 32.0, v - 24.0, 60.0])
    rows += [[0.5, 0.5, 3.0]] * 3 + [[0.5 + 1e-4, 0.5, 3.0]]                 # duplicates: the lowest index wins
    rows += [[0.0, 0.0, 7.0], [0.01, 0.0, 7.0], [0.02, 0.0, 7.0]]             # one pixel, equal depth
    xyz = np.array(rows)
    rgb = np.random.default_rng(0).random((len(xyz), 3))
    for radius in (0, 1, 2):
        fast, ref = both(xyz, rgb, radius_px=radius)
        assert_identical(fast, ref)
    fast, ref = both(xyz, rgb)
    win = ref[2].numpy()
    assert {0, 1, 2, 3, 5, 6, 7, 8}.isdisjoint(set(win[win >= 0].tolist()))  # culled rows never win


def test_exact_pixel_borders():
    """A point whose float32 u is exactly an integer lands in that pixel; one a float32 step below lands in the
    pixel before (pixel (u, v) covers [u, u+1) x [v, v+1))."""
    K1 = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    below = float(np.nextafter(np.float32(5.0), np.float32(0.0)))
    xyz = np.array([[5.0, 1.5, 1.0], [below, 2.5, 1.0]])
    fast, ref = both(xyz, np.ones((2, 3)), K1, EYE, 8, 8)
    assert_identical(fast, ref)
    assert ref[2][1, 5] == 0 and ref[2][2, 4] == 1


def test_empty_and_all_culled_inputs():
    for xyz in (np.zeros((0, 3)), np.array([[0.0, 0.0, -1.0], [np.nan] * 3])):
        fast, ref = both(xyz, np.zeros((len(xyz), 3)), radius_px=1)
        assert_identical(fast, ref)
        assert torch.all(fast[2] == -1) and torch.all(torch.isinf(fast[1])) and torch.all(fast[0] == 0)


def test_colour_dtypes_and_strided_input():
    """uint8, float16 and float64 colours convert to float32 as torch converts them; a non-contiguous xyz is read
    right."""
    rng = np.random.default_rng(5)
    xyz = rng.uniform([-3, -2, 1], [3, 2, 9], (3000, 3))
    for rgb in ((rng.random((3000, 3)) * 255).astype(np.uint8), rng.random((3000, 3)),
                rng.random((3000, 3)).astype(np.float16)):
        assert_identical(*both(xyz, rgb))
    wide = torch.as_tensor(np.concatenate([xyz, xyz], 1), dtype=torch.float32)[:, ::2]
    wide[:] = torch.as_tensor(xyz, dtype=torch.float32)
    rgb = torch.rand(3000, 3)
    fast = PT.render_points(wide, rgb, K, EYE, W, H)
    ref = PT.render_points_torch(wide.contiguous(), rgb, K, EYE, W, H)
    assert_identical(fast, ref)


def test_thread_count_does_not_change_the_result():
    """Bands of rows are the only writers of their pixels: 1, 2 or more bands give the same image."""
    rng = np.random.default_rng(9)
    xyz = rng.uniform([-3, -2, 1], [3, 2, 9], (30000, 3))
    rgb = rng.random((30000, 3)).astype(np.float32)
    before = numba.get_num_threads()
    outs = []
    try:
        for n in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS), numba.config.NUMBA_NUM_THREADS}):
            numba.set_num_threads(n)
            outs.append(PC.render_points(torch.as_tensor(xyz, dtype=torch.float32), torch.as_tensor(rgb), K, EYE,
                                         W, H, radius_px=2))
    finally:
        numba.set_num_threads(before)
    for o in outs[1:]:
        assert_identical(o, outs[0])


def test_wide_image_identical():
    """4096 x 64 with a rotated camera: u in the thousands, where a float32 step is ~2e-4 px, so an operation done
    in another order or precision moves some of the 60 k points across a pixel border; the paths still agree."""
    rng = np.random.default_rng(3)
    Kw = np.array([[2000.0, 0, 2048.0], [0, 2000.0, 32.0], [0, 0, 1]])
    w2c = np.eye(4)
    Q, Rq = np.linalg.qr(np.eye(3) + 0.2 * rng.normal(size=(3, 3)))
    w2c[:3, :3] = Q * np.sign(np.diag(Rq))  # a rotation near the identity with no zero entry
    assert np.linalg.det(w2c[:3, :3]) > 0
    w2c[:3, 3] = [0.37, -0.011, 0.73]
    xyz = rng.uniform([-5, -0.1, 2], [5, 0.1, 6], (60000, 3)) @ w2c[:3, :3] - w2c[:3, :3].T @ w2c[:3, 3]
    fast, ref = both(xyz, rng.random((60000, 3)), Kw, w2c, 4096, 64)
    assert (ref[2] >= 0).sum() > 30000
    assert_identical(fast, ref)
