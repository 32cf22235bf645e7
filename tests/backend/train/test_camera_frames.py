"""Lens distortion of a clip's camera: OpenCV's model against a plain reference, synthetic round trips (points and
images, radial and tangential terms) within 0.1 px, frames unchanged without it, bad coefficients refused."""

import os

import cv2
import numpy as np
import pytest
import torch
from PIL import Image

from backend.train import camera_frames as cf
from backend.train import clip as clip_mod
from backend.train import pairs
from scpainter_blender.core.job import JobError
from tests_support import copy_clip

#: Waymo-like coefficients: radial k1, k2 and tangential p1, p2 (k3 0, as Waymo's calibrations have)
WAYMO = [-0.3, 0.1, 1e-3, -1e-3, 0.0]
#: One value per coefficient of OpenCV's 14: k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y
ALL14 = [-0.28, 0.09, 1e-3, -8e-4, -0.01, 0.02, 0.01, 0.005, 1e-3, -2e-4, -1e-3, 3e-4, 0.01, -0.015]
#: A fisheye calibration (Kannala–Brandt k1..k4, the shape of a wide action camera's): with the street's f 300 px at
#: 518 px wide, 82° across
FISHEYE = [-0.013, 0.021, -0.017, 0.004]
#: Where a fisheye view's undistorted pixels may land off the pinhole projection (measured: 0.003 px)
FISHEYE_BOUND_PX = 0.01


def waymo_K(W, H, cx_off=3.1, cy_off=-2.4):
    """Waymo's front camera (f 2055 px at 1920 wide) scaled to W x H, principal point off the centre (ours)."""
    f = 2055.0 * W / 1920
    return np.array([[f, 0, W / 2 + cx_off], [0, f, H / 2 + cy_off], [0, 0, 1.0]])


def undistort_normalised(u, v, K, dist, model=cf.OPENCV):
    """Normalised undistorted (x, y) of distorted pixel positions (ours): the test's own inverse of the plain model
    (``cf.distort``), Newton's method with a central-difference Jacobian, checked by distorting back (no OpenCV
    inverse: OpenCV 5 removed ``undistortPointsIter``, and the reference should not be the code under test)."""
    dist = np.asarray(dist, np.float64)
    xt, yt = (np.ravel(u) - K[0, 2]) / K[0, 0], (np.ravel(v) - K[1, 2]) / K[1, 1]
    x, y, h = xt.copy(), yt.copy(), 1e-7
    for _ in range(30):
        fx, fy = cf.distort(x, y, dist, model)
        ax, ay = cf.distort(x + h, y, dist, model)
        bx, by = cf.distort(x - h, y, dist, model)
        cx, cy = cf.distort(x, y + h, dist, model)
        dx, dy = cf.distort(x, y - h, dist, model)
        j11, j21, j12, j22 = (ax - bx) / (2 * h), (ay - by) / (2 * h), (cx - dx) / (2 * h), (cy - dy) / (2 * h)
        rx, ry, det = fx - xt, fy - yt, j11 * j22 - j12 * j21
        x, y = x - (j22 * rx - j12 * ry) / det, y - (j11 * ry - j21 * rx) / det
    xd, yd = cf.distort(x, y, dist, model)
    residual = np.hypot(K[0, 0] * xd + K[0, 2] - np.ravel(u), K[1, 1] * yd + K[1, 2] - np.ravel(v)).max()
    assert residual < 1e-6, residual
    return x.reshape(np.shape(u)), y.reshape(np.shape(u))


def bilinear(image, u, v):
    """image (H, W) sampled at pixel positions (ours: centres at +0.5) by bilinear interpolation."""
    x, y = np.asarray(u) - 0.5, np.asarray(v) - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    im = image.astype(np.float64)
    return ((1 - fx) * (1 - fy) * im[y0, x0] + fx * (1 - fy) * im[y0, x0 + 1] + (1 - fx) * fy * im[y0 + 1, x0]
            + fx * fy * im[y0 + 1, x0 + 1])


def random_points(n, seed=0):
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-4, 4, n), rng.uniform(-2.5, 2.5, n), rng.uniform(4, 40, n)], -1)


@pytest.mark.parametrize("n", [4, 5, 8, 12, 14])
def test_reference_model_is_opencvs_projection(n):
    """distort_reference (numpy, written plainly) equals cv2.projectPoints for every coefficient count."""
    W, H = 480, 320
    K, dist = waymo_K(W, H), np.array(ALL14[:n])
    X = random_points(200)
    cv_px, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), cf.to_opencv(K), dist)
    xd, yd = cf.distort_reference(X[:, 0] / X[:, 2], X[:, 1] / X[:, 2], dist)
    ours = np.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], -1)
    np.testing.assert_allclose(ours - 0.5, cv_px[:, 0], atol=1e-7)


@pytest.mark.parametrize("dist", [WAYMO, ALL14], ids=["waymo", "all14"])
def test_opencv_maps_equal_the_reference_maps(dist):
    W, H = 160, 96
    K, dist = waymo_K(W, H), np.array(dist)
    K_new = cf.undistorted_K(K, dist, (W, H))
    fast = cf.undistortion_maps(K, dist, K_new, (W, H))
    ref = cf.undistortion_maps_reference(K, dist, K_new, (W, H))
    for a, b in zip(fast, ref):
        assert a.dtype == np.float32 and a.shape == (H, W)
        np.testing.assert_allclose(a, b, atol=2e-3)


@pytest.mark.parametrize("dist", [WAYMO, ALL14], ids=["waymo", "all14"])
def test_points_round_trip_through_the_undistortion_maps(dist):
    """Each 3D point's pinhole pixel in the undistorted frame (new K) is sent by the maps to where OpenCV projects
    it in the recorded frame (K + distortion): the point-level round trip, well within 0.1 px."""
    W, H = 480, 320
    K, dist = waymo_K(W, H), np.array(dist)
    K_new = cf.undistorted_K(K, dist, (W, H))
    assert cf.distortion_problem(K, dist, K_new, (W, H)) is None
    assert K_new[0, 0] / K_new[1, 1] == pytest.approx(K[0, 0] / K[1, 1])  # the pixel aspect is kept
    map_x, map_y = cf.undistortion_maps(K, dist, K_new, (W, H))
    # alpha 0: every undistorted pixel shows recorded pixels (no black border; sub-pixel spill at most)
    assert map_x.min() > -0.5 - 0.2 and map_x.max() < W - 0.5 + 0.2
    assert map_y.min() > -0.5 - 0.2 and map_y.max() < H - 0.5 + 0.2
    # ... and the frame is cropped no more than it must be: the maps reach the recorded frame's edges
    assert min(map_x.min(), map_y.min()) < 2 or max(W - map_x.max(), H - map_y.max()) < 2

    X = random_points(2000, seed=1)
    cv_px, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), cf.to_opencv(K), dist)
    recorded = cv_px[:, 0] + 0.5  # ours
    u, v = K_new[0, 0] * X[:, 0] / X[:, 2] + K_new[0, 2], K_new[1, 1] * X[:, 1] / X[:, 2] + K_new[1, 2]
    inside = (u > 1) & (u < W - 1) & (v > 1) & (v < H - 1)
    assert inside.sum() > 300
    mapped = np.stack([bilinear(map_x, u[inside], v[inside]), bilinear(map_y, u[inside], v[inside])], -1) + 0.5
    err = np.hypot(*(mapped - recorded[inside]).T)
    assert err.max() < 0.01, err.max()


# -- the fisheye model ------------------------------------------------------------------------------------------

def test_fisheye_reference_is_cv2_fisheyes_projection():
    W, H = 518, 294
    K, dist = waymo_K(W, H) @ np.diag([0.3, 0.3, 1.0]), np.array(FISHEYE)
    X = random_points(200)
    cv_px, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cf.to_opencv(K), dist)
    xd, yd = cf.distort_fisheye_reference(X[:, 0] / X[:, 2], X[:, 1] / X[:, 2], dist)
    ours = np.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], -1)
    np.testing.assert_allclose(ours - 0.5, cv_px[:, 0], atol=1e-7)


def street_fisheye_K(W=518, H=294):
    """The street's f 300 px at 518 x 294, principal point off the centre (ours)."""
    return np.array([[300.0 * W / 518, 0, W / 2 + 2.1], [0, 300.0 * W / 518, H / 2 - 1.3], [0, 0, 1]])


def test_fisheye_maps_equal_the_reference_maps():
    W, H = 160, 96
    K, dist = street_fisheye_K(W, H), np.array(FISHEYE)
    K_new = cf.undistorted_K(K, dist, (W, H), cf.FISHEYE)
    fast = cf.undistortion_maps(K, dist, K_new, (W, H), cf.FISHEYE)
    ref = cf.undistortion_maps_reference(K, dist, K_new, (W, H), cf.FISHEYE)
    for a, b in zip(fast, ref):
        assert a.dtype == np.float32 and a.shape == (H, W)
        np.testing.assert_allclose(a, b, atol=2e-3)


def _landing_error(K, dist, model, W, H, X):
    """For 3D points X seen through the fisheye (K, dist): how far from where cv2.fisheye projects each point the
    undistortion maps of ``model`` fetch the pixel at its pinhole projection through the undistorted K."""
    K_new = cf.undistorted_K(K, dist, (W, H), model)
    map_x, map_y = cf.undistortion_maps(K, dist, K_new, (W, H), model)
    cv_px, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cf.to_opencv(K), dist)
    recorded = cv_px[:, 0] + 0.5  # ours
    u, v = K_new[0, 0] * X[:, 0] / X[:, 2] + K_new[0, 2], K_new[1, 1] * X[:, 1] / X[:, 2] + K_new[1, 2]
    inside = (u > 1) & (u < W - 1) & (v > 1) & (v < H - 1)
    assert inside.sum() > 300
    mapped = np.stack([bilinear(map_x, u[inside], v[inside]), bilinear(map_y, u[inside], v[inside])], -1) + 0.5
    return np.hypot(*(mapped - recorded[inside]).T), K_new


def test_a_fisheye_view_lands_where_the_pinhole_projects_it_and_not_when_read_as_opencvs():
    """3D points in a fisheye view (cv2.fisheye.projectPoints): the undistorted frame (cv2.fisheye's maps, to the
    undistorted K) shows each where the pinhole projection puts it. The same four numbers read as OpenCV's k1, k2,
    p1, p2 (what a clip without distortion_model did) fetch most pixels from tens of pixels away."""
    W, H = 518, 294
    K, dist = street_fisheye_K(), np.array(FISHEYE)
    X = random_points(4000, seed=2)
    err, K_new = _landing_error(K, dist, cf.FISHEYE, W, H, X)
    assert cf.distortion_problem(K, dist, K_new, (W, H), cf.FISHEYE) is None
    assert K_new[0, 0] == pytest.approx(K_new[1, 1]) and K_new[0, 0] < K[0, 0]  # zoomed out: the edges stretch
    assert err.max() < FISHEYE_BOUND_PX, err.max()
    wrong, _ = _landing_error(K, dist, cf.OPENCV, W, H, X)
    # measured: 60 % of the points more than 0.1 px off (22 % more than 1 px), up to 56 px
    assert np.mean(wrong > 0.1) > 0.5 and wrong.max() > 40.0, (np.mean(wrong > 0.1), wrong.max())


@pytest.mark.parametrize("f", [150.0, 120.0])
def test_a_fisheye_too_wide_for_a_pinhole_frame_is_refused(f):
    """Equidistant lenses (k = 0) at 518 x 294: f 150 px sees 99° off axis at the side edges, f 120 px 124°: no
    pinhole frame holds a ray 90° off axis."""
    W, H = 518, 294
    K, dist = np.array([[f, 0, 259], [0, f, 147], [0, 0, 1]]), np.zeros(4)
    problem = cf.distortion_problem(K, dist, cf.undistorted_K(K, dist, (W, H), cf.FISHEYE), (W, H), cf.FISHEYE)
    assert problem is not None and "too wide for a pinhole frame" in problem, problem


# -- clip folders ------------------------------------------------------------------------------------------------

_copy = copy_clip  # tests_support: a copy of the street clip with clip.json edited


def _set_poses_K(folder, K):
    with np.load(folder / "poses.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["K"] = np.asarray(K, np.float64)
    np.savez(folder / "poses.npz", **arrays)


def _write_rgb(path, rgb):
    os.remove(path)  # the copy's own file, never one it might share with the cached street
    Image.fromarray(rgb).save(path)


def test_no_distortion_gives_todays_frames_bit_identical(street_clip_path, tmp_path):
    c = clip_mod.load(street_clip_path)
    zero = clip_mod.load(_copy(street_clip_path, tmp_path, lambda d, f: d.update(distortion=[0, 0, 0, 0, 0])))
    for clip in (c, zero):
        assert clip.distortion is None and clip.K is clip.K_recorded
        for W, H in ((259, 147), (518, 294), (200, 120)):
            got = clip.load_frames(W, H, [0, 7, 15])
            for i, t in enumerate((0, 7, 15)):
                today = pairs.load_resized(c.frame_paths[t], W, H).permute(1, 2, 0).numpy()
                assert np.array_equal(got[i], today)
    maker = pairs.PairMaker(c, pairs.PairSettings(width=259, height=147, frames=3))
    assert torch.equal(maker.target(4), pairs.load_resized(c.frame_paths[4], 259, 147).float() / 255.0)
    view = c.load_frame(3, 259, 147, view=2.0)
    assert np.array_equal(view, pairs.load_resized(c.views[2.0][3], 259, 147).permute(1, 2, 0).numpy())


def _blob_image(K, dist, W, H, centres, sigma, model=cf.OPENCV):
    """A recorded (distorted) frame of Gaussian blobs that are round in the undistorted image: centres (N, 2) and
    sigma in normalised coordinates; each recorded pixel shows the point of the undistorted plane it images."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    x, y = undistort_normalised(u, v, K, dist, model)
    image = np.zeros((H, W))
    for cx, cy in centres:
        image += np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma ** 2))
    return np.repeat(np.clip(np.round(250 * image), 0, 255).astype(np.uint8)[..., None], 3, -1)


def _centroids(image, pixels, r):
    """Intensity centroids (ours) of the blobs expected at ``pixels``, in windows of radius r."""
    out = []
    for px, py in pixels:
        x0, y0 = int(px), int(py)
        win = image[y0 - r:y0 + r + 1, x0 - r:x0 + r + 1].astype(np.float64)
        yy, xx = np.mgrid[y0 - r:y0 + r + 1, x0 - r:x0 + r + 1] + 0.5
        out.append([(win * xx).sum() / win.sum(), (win * yy).sum() / win.sum()])
    return np.array(out)


def test_image_round_trip_puts_blobs_where_the_new_K_projects_them(street_clip_path, tmp_path):
    """The image-level round trip through a clip: blobs drawn in distorted frames (two calibrations: K differs
    between frames) come out of ``load_frame`` where the clip's (undistorted) K projects their directions — within
    0.1 px at the frames' size and at half of it (``K_for``)."""
    W, H = 518, 294
    K_a, K_b = waymo_K(W, H), waymo_K(W, H, cx_off=-4.2, cy_off=1.7) @ np.diag([1.02, 1.02, 1.0])
    K_rec = np.array([K_a] * 8 + [K_b] * 8)
    # blob directions: a grid over the middle 85 % of the frame; sigma 2 px
    gx = (np.linspace(16, W - 16, 6) - W / 2) / K_a[0, 0] * 0.85
    gy = (np.linspace(16, H - 16, 4) - H / 2) / K_a[1, 1] * 0.85
    centres = np.array([(x, y) for x in gx for y in gy])
    sigma = 2.0 / K_a[0, 0]
    images = {0: _blob_image(K_a, np.array(WAYMO), W, H, centres, sigma),
              8: _blob_image(K_b, np.array(WAYMO), W, H, centres, sigma)}

    def edit(d, folder):
        d["distortion"] = WAYMO
        _set_poses_K(folder, K_rec)
        for t in range(16):
            _write_rgb(folder / "frames" / f"frame_{t:06d}.png", images[0 if t < 8 else 8])

    c = clip_mod.load(_copy(street_clip_path, tmp_path, edit))
    assert np.array_equal(c.distortion, WAYMO) and np.array_equal(c.K_recorded, K_rec)
    assert not np.allclose(c.K[0], c.K[8])  # one undistorted K per calibration
    for t in (0, 8, 12):
        for (w, h), r, tol in (((W, H), 9, 0.1), ((W // 2, H // 2), 5, 0.1)):
            K = c.K_for(w, h)[t]
            expected = np.stack([K[0, 0] * centres[:, 0] + K[0, 2], K[1, 1] * centres[:, 1] + K[1, 2]], -1)
            got = _centroids(c.load_frame(t, w, h)[..., 0], expected, r)
            err = np.hypot(*(got - expected).T)
            assert err.max() <= tol, (t, (w, h), err.max())  # measured: 0.022 px at most
    assert len(c._undistort._maps) == 2  # maps cached per distinct K (the frames are undistorted at full size)


def test_a_fisheye_clip_puts_blobs_where_the_new_K_projects_them(street_clip_path, tmp_path):
    """The image-level round trip of a fisheye clip (distortion_model "fisheye"): blobs drawn through the fisheye
    come out of ``load_frame`` where the clip's undistorted K projects their directions."""
    W, H = 518, 294
    K_f = street_fisheye_K()
    gx = (np.linspace(16, W - 16, 6) - W / 2) / K_f[0, 0] * 0.8
    gy = (np.linspace(16, H - 16, 4) - H / 2) / K_f[1, 1] * 0.8
    centres = np.array([(x, y) for x in gx for y in gy])
    image = _blob_image(K_f, np.array(FISHEYE), W, H, centres, 2.0 / K_f[0, 0], cf.FISHEYE)

    def edit(d, folder):
        d["distortion"], d["distortion_model"] = FISHEYE, "fisheye"
        _set_poses_K(folder, np.array([K_f] * 16))
        for t in (0, 5):
            _write_rgb(folder / "frames" / f"frame_{t:06d}.png", image)

    c = clip_mod.load(_copy(street_clip_path, tmp_path, edit))
    assert c.distortion_model == "fisheye" and np.array_equal(c.distortion, FISHEYE)
    for t in (0, 5):
        K = c.K_for(W, H)[t]
        expected = np.stack([K[0, 0] * centres[:, 0] + K[0, 2], K[1, 1] * centres[:, 1] + K[1, 2]], -1)
        got = _centroids(c.load_frame(t, W, H)[..., 0], expected, 7)
        err = np.hypot(*(got - expected).T)
        assert err.max() <= 0.1, (t, err.max())
    # the same numbers stated as OpenCV's: loaded (a valid pinhole calibration), and the blobs land elsewhere
    c_cv = clip_mod.load(_copy(street_clip_path, tmp_path, lambda d, f: [edit(d, f), d.update(
        distortion_model="opencv")], "as_opencv"))
    K = c_cv.K_for(W, H)[0]
    expected = np.stack([K[0, 0] * centres[:, 0] + K[0, 2], K[1, 1] * centres[:, 1] + K[1, 2]], -1)
    with np.errstate(invalid="ignore"):  # blobs cropped away (the other K): empty windows
        err = np.hypot(*(_centroids(c_cv.load_frame(0, W, H)[..., 0], expected, 7) - expected).T)
    assert np.nanmax(err) > 3.0, err


def _warp(image, map_u, map_v):
    """image sampled at pixel positions (ours) with Lanczos: cv2.remap with OpenCV coordinates."""
    return cv2.remap(image, (map_u - 0.5).astype(np.float32), (map_v - 0.5).astype(np.float32),
                     cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REPLICATE)


def test_training_target_of_a_distorted_clip_equals_the_undistorted_reference(street_clip_path, tmp_path):
    """The street's frames (pinhole, K_street) seen through a lens: recorded frames synthesised with Waymo-like
    distortion. The training target (and a ground-truth view) of that clip equals the street frame resampled to
    the clip's undistorted K — the reference — to within interpolation."""
    W, H = 518, 294
    c0 = clip_mod.load(street_clip_path)
    K_street = c0.K[0]
    K_rec = K_street @ np.diag([1.1, 1.1, 1.0])  # a longer lens: what it sees lies inside the street frame
    dist = np.array(WAYMO)
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    x, y = undistort_normalised(u, v, K_rec, dist)
    to_street = (K_street[0, 0] * x + K_street[0, 2], K_street[1, 1] * y + K_street[1, 2])
    ts = (3, 4, 5)

    def edit(d, folder):
        d["distortion"] = WAYMO
        _set_poses_K(folder, np.array([K_rec] * 16))
        for t in ts:
            for sub in ("frames", "views/left_2m"):
                p = folder / sub / f"frame_{t:06d}.png"
                _write_rgb(p, _warp(np.asarray(Image.open(p).convert("RGB")), *to_street))

    c = clip_mod.load(_copy(street_clip_path, tmp_path, edit))
    maker = pairs.PairMaker(c, pairs.PairSettings(width=259, height=147, frames=3, confidence_percentile=0.0))
    np.testing.assert_allclose(maker.K, c.K_for(259, 147))
    assert not np.allclose(c.K, K_rec)
    K_new = c.K[4]
    x, y = (u - K_new[0, 2]) / K_new[0, 0], (v - K_new[1, 2]) / K_new[1, 1]
    new_to_street = (K_street[0, 0] * x + K_street[0, 2], K_street[1, 1] * y + K_street[1, 2])
    for t in ts:
        for view, path in ((None, c0.frame_paths[t]), (2.0, c0.views[2.0][t])):
            reference = cf.resized(_warp(np.asarray(Image.open(path).convert("RGB")), *new_to_street), 259, 147)
            got = maker.target(t) if view is None else torch.from_numpy(c.load_frame(t, 259, 147, view)).permute(
                2, 0, 1).float() / 255.0
            if view is None:
                assert torch.equal(got, torch.from_numpy(c.load_frame(t, 259, 147)).permute(2, 0, 1).float() / 255)
            diff = got.permute(1, 2, 0).numpy() * 255.0 - reference.astype(np.float64)
            psnr = 10 * np.log10(255.0 ** 2 / np.mean(diff ** 2))
            untouched = cf.resized(np.asarray(Image.open(path).convert("RGB")), 259, 147).astype(np.float64)
            psnr_untouched = 10 * np.log10(255.0 ** 2 / np.mean((got.permute(1, 2, 0).numpy() * 255 - untouched) ** 2))
            assert psnr > 40.0 and np.abs(diff).mean() < 1.2, (t, view, psnr)  # measured: 45 dB, 0.9
            assert psnr_untouched < 25.0  # the comparison can tell: the street frame itself is far off


def _distortion_edit(value, poses=True, model=None):
    def edit(d, folder):
        d["distortion"] = value
        if model is not None:
            d["distortion_model"] = model
        if not poses:
            d.pop("poses")
            d.pop("views")
    return edit


@pytest.mark.parametrize("edit, field, words", [
    (_distortion_edit("k1"), "distortion", "4, 5, 8, 12 or 14 numbers"),
    (_distortion_edit([-0.3, 0.1, 0.0]), "distortion", "4, 5, 8, 12 or 14 numbers"),
    (_distortion_edit([-0.3] * 6), "distortion", "4, 5, 8, 12 or 14 numbers"),
    (_distortion_edit([True, 0, 0, 0]), "distortion", "numbers"),
    (_distortion_edit([[0.1], 0, 0, 0]), "distortion", "numbers"),
    (_distortion_edit([1e9, 0, 0, 0]), "distortion", "within"),
    (_distortion_edit([-3.0, 0, 0, 0, 0]), "distortion", "folds over"),
    (_distortion_edit([0.0, 0, 0, 0, 3.0]), "distortion", "zoom"),
    (_distortion_edit(WAYMO, poses=False), "distortion", "needs poses"),
    (_distortion_edit(FISHEYE), "distortion_model", "four numbers: OpenCV's k1, k2, p1, p2 or a fisheye's"),
    (_distortion_edit([0, 0, 0, 0]), "distortion_model", "four numbers"),
    (_distortion_edit(FISHEYE, model="kannala-brandt"), "distortion_model", "expected 'opencv'"),
    (_distortion_edit(FISHEYE, model=["fisheye"]), "distortion_model", "expected 'opencv'"),
    (_distortion_edit(WAYMO, model="fisheye"), "distortion", "Kannala–Brandt [k1, k2, k3, k4] distortion "
                                                             "coefficients: a list of 4 numbers, got a list of 5"),
    (lambda d, f: [d.update(distortion=[0, 0, 0, 0], distortion_model="fisheye"),
                   _set_poses_K(f, np.array([[[150.0, 0, 259], [0, 150, 147], [0, 0, 1]]] * 16))],
     "distortion", "too wide for a pinhole frame"),
    (lambda d, f: [d.update(distortion=WAYMO), _set_poses_K(f, np.array([[[300, 0.5, 259], [0, 300, 147],
                                                                          [0, 0, 1]]] * 16))], "K", "skew"),
])
def test_bad_distortion_is_refused_naming_the_field(street_clip_path, tmp_path, edit, field, words):
    folder = _copy(street_clip_path, tmp_path, edit)
    with pytest.raises(JobError) as info:
        clip_mod.load(folder)
    assert info.value.field == field and words in info.value.message, str(info.value)
    assert str(info.value).startswith(("clip.json: ", "poses.npz: ")), str(info.value)


def test_four_numbers_with_the_model_stated_are_taken(street_clip_path, tmp_path):
    for model in ("opencv", "fisheye"):
        c = clip_mod.load(_copy(street_clip_path, tmp_path, _distortion_edit(FISHEYE, model=model), model))
        assert c.distortion_model == model and np.array_equal(c.distortion, FISHEYE)
    c = clip_mod.load(_copy(street_clip_path, tmp_path, _distortion_edit(WAYMO), "five"))  # unstated: OpenCV's
    assert c.distortion_model == "opencv" and np.array_equal(c.distortion, WAYMO)


def test_nan_distortion_is_refused_naming_the_coefficient(street_clip_path, tmp_path):
    folder = _copy(street_clip_path, tmp_path, lambda d, f: None)
    text = (folder / "clip.json").read_text().replace('"fps"', '"distortion": [-0.3, NaN, 0, 0], "fps"')
    (folder / "clip.json").write_text(text)
    with pytest.raises(JobError, match="distortion"):
        clip_mod.load(folder)
