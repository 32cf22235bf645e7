"""The ground-truth street: VGGT's layout, exact depth and poses, shifted views, determinism, caching."""

import json
import os
import time

import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core.geometry import point_cloud, similarity, trajectory, unproject
from scpainter_blender.core.vggt import npz as vggt_io
from scpainter_blender.street import build, predictions
from scpainter_blender.street.dataset import StreetParams, ensure_street, view_name


def test_predictions_layout_is_vggts(street):
    p = street.params
    S, H, W = p.num_frames, p.height, p.width
    with np.load(street.predictions_path) as z:
        shapes = {k: z[k].shape for k in z.files}
        dtypes = {z[k].dtype for k in z.files}
        ext, intr, conf = z["extrinsic"], z["intrinsic"], z["depth_conf"]
    assert shapes == {"images": (S, 3, H, W), "depth": (S, H, W, 1), "depth_conf": (S, H, W),
                      "extrinsic": (S, 3, 4), "intrinsic": (S, 3, 3), "world_points": (S, H, W, 3),
                      "world_points_conf": (S, H, W)}
    assert dtypes == {np.dtype(np.float32)}
    assert np.array_equal(ext[0], np.eye(3, 4))           # the first camera is the world origin
    assert np.allclose(intr[:, 0, 2], W / 2 - 0.5) and np.allclose(intr[:, 1, 2], H / 2 - 0.5)  # VGGT's pixels
    assert conf.min() >= 1.0                              # 1 + exp(x)
    assert H % 14 == 0


def test_scale_normalised_like_vggt(street):
    """Mean distance of the scene's points from the first camera is one VGGT unit."""
    pred = vggt_io.load_predictions(street.predictions_path)
    hit = np.isfinite(street.metric()["depth"])
    pts = point_cloud.point_cloud(pred, 0.0)
    keep = hit.reshape(-1)
    assert np.linalg.norm(pts.positions[keep], axis=1).mean() == pytest.approx(1.0, rel=1e-4)


def test_metric_ground_truth_is_consistent(street):
    pred = vggt_io.load_predictions(street.predictions_path)
    m = street.metric()
    w2c = similarity.transform_world_to_camera(C.orthonormalize(pred.world_to_camera), m["vggt_to_world"])
    assert np.abs(w2c - m["world_to_camera"]).max() < 1e-5
    assert np.allclose(C.camera_centers(m["world_to_camera"])[:, 2], street.params.camera_height_m)
    # VGGT-unit depth times the scale is the metric depth
    hit = np.isfinite(m["depth"])
    assert np.allclose(pred.depth[hit] * m["metres_per_unit"], m["depth"][hit], rtol=1e-5)


def test_depth_is_exact_at_pixel_centres(street):
    """Road pixels unproject onto z = 0 (or the 4 mm lane paint); car pixels land inside their car's box."""
    m = street.metric()
    S, H, W = m["depth"].shape
    for i in (0, S // 2, S - 1):
        rows, cols = np.meshgrid(np.arange(H - 40, H), np.arange(W // 2 - 30, W // 2 + 30), indexing="ij")
        p = unproject.unproject_pixels(m["depth"][i], m["K"][i], m["world_to_camera"][i], rows.ravel(), cols.ravel())
        z = p[:, 2]
        on_road = np.abs(z) < 1e-3
        on_paint = np.abs(z - 0.004) < 1e-3
        assert np.all(on_road | on_paint), z[~(on_road | on_paint)][:5]
    for car in street.info["cars"]:
        sel = m["instance"] == car["instance"]
        if not sel.any():
            continue
        frames, rows, cols = np.nonzero(sel)
        B = np.array(car["box_to_world"])
        half = np.array(car["size"]) / 2 + 0.02
        for i in np.unique(frames):
            f = frames == i
            p = unproject.unproject_pixels(m["depth"][i], m["K"][i], m["world_to_camera"][i], rows[f], cols[f])
            local = (p - B[:3, 3]) @ B[:3, :3]
            assert np.all(np.abs(local) <= half), (car["name"], np.abs(local).max(0))


def test_shifted_views(street):
    m = street.metric()
    rec = m["world_to_camera"]
    heading = trajectory.heading_directions(C.camera_centers(rec))
    left = trajectory.left_directions(heading)
    for s in street.params.shifts_m:
        name = view_name(s)
        poses = m[f"world_to_camera_{name}"]
        d = C.camera_centers(poses) - C.camera_centers(rec)
        assert np.allclose(d, s * left, atol=1e-9)
        assert np.allclose(poses[:, :3, :3], rec[:, :3, :3])
        for i in range(street.params.num_frames):
            assert os.path.getsize(street.frame_path(name, i)) > 1000
    assert street.views == ["recorded", "left_2m", "right_2m", "left_3m", "right_3m"]


def test_images_are_the_recorded_renders(street):
    """predictions images are the recorded PNGs' bytes / 255 (what VGGT reads from disk)."""
    pred = vggt_io.load_predictions(street.predictions_path)
    H, W = pred.height, pred.width
    px = _pixels(street.frame_path("recorded", 3))
    assert np.abs(px.reshape(H, W, 4)[::-1, :, :3] - pred.images[3]).max() < 1e-6
    assert pred.images[3].std() > 0.05  # a real picture, not a flat colour


def test_cache_hit_is_instant(street):
    t = time.perf_counter()
    again = ensure_street(street.params, cache_dir=os.path.dirname(street.root))
    assert time.perf_counter() - t < 1.0 and again.root == street.root


def test_generation_is_deterministic(tmp_path):
    params = StreetParams(num_frames=2, width=70, height=42, focal_px=40.0, shifts_m=(2.0,), samples=2,
                          num_parked_cars=2, seed=3)
    a = ensure_street(params, cache_dir=str(tmp_path / "a"))
    b = ensure_street(params, cache_dir=str(tmp_path / "b"))
    with np.load(a.predictions_path) as za, np.load(b.predictions_path) as zb:
        for k in za.files:
            assert np.array_equal(za[k], zb[k]), k
    for view in a.views:
        for i in range(2):  # the pixels (Cycles writes its render time into the PNG's metadata)
            assert np.array_equal(_pixels(a.frame_path(view, i)), _pixels(b.frame_path(view, i))), (view, i)
    info = json.load(open(os.path.join(a.root, "street.json")))
    assert info["params"]["seed"] == 3 and len(info["cars"]) == 2
    # no temporary folder left (outputs.atomic_folder's ".<name>.<random>.tmp"), the street folder whole
    left = os.listdir(tmp_path / "a")
    assert os.path.basename(a.root) in left and not [d for d in left if d.startswith(".") and d.endswith(".tmp")]


def _pixels(path):
    import bpy

    img = bpy.data.images.load(path)
    px = np.empty(img.size[0] * img.size[1] * 4, np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px


def test_recorded_path_is_a_gentle_forward_drive():
    p = StreetParams()
    T = build.recorded_path(p)
    c = C.camera_centers(T)
    assert np.allclose(np.diff(c[:, 1]), p.frame_spacing_m)
    assert np.allclose(c[:, 2], p.camera_height_m)
    fwd = T[:, 2, :3]
    assert np.all(fwd[:, 1] > 0.99)
    assert np.allclose(np.linalg.det(T[:, :3, :3]), 1.0)


def test_drive_files_give_back_the_metric_points(tmp_path):
    """predictions.npz in VGGT's layout + metric.npz's vggt_to_world = the metric points, without rendering: a
    drive over a wall (and a sky pixel per frame) written by write_drive, read back as the import reads it."""
    S, H, W = 3, 6, 8
    K = np.array([[8.0, 0, W / 2], [0, 8.0, H / 2], [0, 0, 1]])
    w2c = build.recorded_path(StreetParams(num_frames=S, frame_spacing_m=1.5))
    depth = np.full((S, H, W), 12.0, np.float32) + np.arange(W, dtype=np.float32)
    depth[:, 0, 0] = np.inf  # sky: far, least confident, left out by the percentile
    images = np.random.default_rng(0).random((S, H, W, 3), dtype=np.float32)
    views = {"recorded": w2c, "left_2m": trajectory.shift_trajectory(w2c, left_m=2.0)}
    m = predictions.write_drive(str(tmp_path), images, depth, np.zeros((S, H, W), np.uint8), K, views, 1.6)
    with np.load(tmp_path / "metric.npz") as z:
        assert z["metres_per_unit"] == m and np.array_equal(z["world_to_camera_left_2m"], views["left_2m"])
        M = z["vggt_to_world"]
    pred = vggt_io.load_predictions(tmp_path / "predictions.npz", extrinsic_convention="auto")
    assert pred.report.convention_checked and np.allclose(pred.world_to_camera[0], np.eye(4))
    pts = point_cloud.point_cloud(pred, 5.0, vggt_to_world=M)  # 3 sky pixels of 144: below the 5th percentile
    hit = np.isfinite(depth)
    truth = np.concatenate([unproject.unproject_pixels(depth[i], K, w2c[i], *np.nonzero(hit[i])) for i in range(S)])
    assert len(pts) == hit.sum() and np.abs(pts.positions - truth).max() < 1e-4
    # VGGT's normalisation: mean distance of the valid points from the first camera is one unit
    assert np.linalg.norm(truth - C.camera_centers(w2c[0]), axis=1).mean() == pytest.approx(m)


def test_the_streets_cars_as_an_objects_file(tmp_path):
    """``Street.write_objects``: the parked cars as scpainter.objects/1 in the street's world; read back and mapped
    through the street's own cameras they are the ground truth again (no bpy: the cached street only)."""
    from scpainter_blender.core.recording import plain, reader
    from scpainter_blender.street.dataset import cached_street

    street = cached_street()
    if street is None:
        pytest.skip("the ground-truth street is not in the cache")
    path = street.write_objects(str(tmp_path / "objects.json"))
    mapped = reader.recorded_objects(plain.read(path), street.metric()["world_to_camera"], 1)
    assert not mapped.warnings
    assert [o.id for o in mapped.objects] == [f"street_car_{c['instance']}" for c in street.info["cars"]]
    for o, c in zip(mapped.objects, street.info["cars"]):
        assert sorted(o.boxes) == list(range(1, street.params.num_frames + 1))
        np.testing.assert_allclose(o.boxes[7], c["box_to_world"], atol=1e-5)
        np.testing.assert_allclose(o.size, c["size"])
