"""bpy.ops.scpainter.import_vggt on the ground-truth street, checked against the street's known answers."""

import json
import os

import bpy
import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core import job as J
from scpainter_blender.core.geometry import metric_scale, point_cloud, similarity, unproject
from scpainter_blender.core.vggt import npz as vggt_io
from scpainter_blender.core.vggt import predictions as V
from tests_support import evaluated_counts


#: The depth-edge ratio an import uses when none is given: the job's default.
EDGE_RATIO = J.POINT_CLEANING["depth_edge_ratio"]


def _metric_path(street):
    return os.path.join(street.root, "metric.npz")


def _import(street, **kw):
    kw.setdefault("scale_mode", "TRAJECTORY")
    if kw["scale_mode"] == "TRAJECTORY":
        kw.setdefault("trajectory_path", _metric_path(street))
    r = bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, **kw)
    assert r == {"FINISHED"}
    pts = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "points")
    cam = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "recorded_camera")
    return pts, cam


def _world_vertices(obj):
    n = len(obj.data.vertices)
    co = np.empty(n * 3, np.float32)
    obj.data.attributes["position"].data.foreach_get("vector", co)
    M = np.array(obj.matrix_world)
    return co.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3]


def test_import_matches_ground_truth(empty_scene, street):
    scene = empty_scene
    pts_obj, cam = _import(street)
    metric = street.metric()
    pred = vggt_io.load_predictions(street.predictions_path)

    # metric scale from the trajectory: the ground truth, with a tiny residual
    M = np.array(pts_obj["scpainter_vggt_to_world"]).reshape(4, 4)
    assert np.abs(M - metric["vggt_to_world"]).max() < 1e-4
    assert pts_obj["scpainter_scale_residual_m"] < 1e-4
    assert pts_obj["scpainter_source"] == os.path.abspath(street.predictions_path)
    assert pts_obj["scpainter_scale_method"] == "trajectory"
    assert pts_obj["scpainter_depth_edge_ratio"] == EDGE_RATIO   # the job's default, when none is given

    # the points: exactly the core's point cloud (depth edges left out), in metric Blender world, on the street's
    # true surfaces
    ref = point_cloud.point_cloud(pred, 50.0, vggt_to_world=M, depth_edge_ratio=EDGE_RATIO)
    assert len(pts_obj.data.vertices) == len(ref) > 100_000 and ref.depth_edge_points > 1000
    world = _world_vertices(pts_obj)
    assert np.abs(world - ref.positions).max() < 1e-4
    frames = np.empty(len(ref), np.int32)
    pts_obj.data.attributes["vggt_frame"].data.foreach_get("value", frames)
    assert np.array_equal(frames, ref.frame)
    gt = unproject.unproject_depth(np.where(np.isfinite(metric["depth"]), metric["depth"], 0), metric["K"],
                                   metric["world_to_camera"])
    conf = pred.depth_conf
    keep = (conf >= np.percentile(conf, 50)) & (conf > 1e-5) & (pred.depth > 0)
    keep &= ~np.stack([point_cloud.depth_edges(d, EDGE_RATIO) for d in pred.depth])
    assert np.abs(world - gt[keep]).max() < 2e-3  # float32 depth in VGGT units, float32 vertices

    # colours: the source image values, as 8-bit sRGB
    col = np.empty(len(ref) * 4, np.float32)
    pts_obj.data.color_attributes["point_color"].data.foreach_get("color_srgb", col)
    assert np.abs(col.reshape(-1, 4)[:, :3] - ref.colors).max() <= 0.5 / 255 + 1e-6

    # the recorded camera: pose and intrinsics at every frame
    S = pred.num_frames
    assert (scene.frame_start, scene.frame_end) == (1, S)
    assert (scene.render.resolution_x, scene.render.resolution_y) == (pred.width, pred.height)
    assert scene.camera == cam
    assert cam.rotation_mode == "QUATERNION"
    from scpainter_blender.scene.camera import K_of_camera_object  # the repo's copy of the installed module

    for i in range(S):
        scene.frame_set(1 + i)
        expected = C.blender_matrix_world(metric["world_to_camera"][i])
        assert np.abs(np.array(cam.matrix_world) - expected).max() < 2e-4, i
        K = K_of_camera_object(scene, cam)
        assert np.abs(K - metric["K"][i]).max() < 1e-3, i


def test_current_frame_only_shows_that_frame(empty_scene, street):
    pts_obj, _ = _import(street, current_frame_only=True, frame_window=0)
    ref = point_cloud.point_cloud(vggt_io.load_predictions(street.predictions_path), 50.0,
                                  depth_edge_ratio=EDGE_RATIO)
    counts = np.diff(ref.offsets)
    from scpainter_blender.scene import node_groups, points

    mod = points.points_modifier(pts_obj)
    for frame_index, window in ((0, 0), (5, 0), (5, 1), (15, 2)):
        node_groups.set_input(mod, "Frame Window", window)
        pts_obj.update_tag()
        empty_scene.frame_set(1 + frame_index)
        lo, hi = max(0, frame_index - window), min(len(counts), frame_index + window + 1)
        assert _evaluated_points(pts_obj) == counts[lo:hi].sum(), (frame_index, window)
    node_groups.set_input(mod, "Current Frame Only", False)
    pts_obj.update_tag()
    assert _evaluated_points(pts_obj) == len(ref)


def _evaluated_points(obj):
    """Points in the evaluated geometry (Mesh to Points gives a point-cloud component)."""
    return evaluated_counts(obj)[0]


def test_import_renders_in_colour(empty_scene, street, tmp_path):
    """Cycles renders the points in their colours from the recorded camera: they reproduce the drive's frame."""
    _import(street, point_radius=0.04)
    scene = empty_scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.render.film_transparent = True
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.frame_set(1)
    scene.render.filepath = str(tmp_path / "points.png")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(tmp_path / "points.png"))
    W, H = img.size
    px = np.empty(W * H * 4, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(H, W, 4)[::-1]
    gt = bpy.data.images.load(street.frame_path("recorded", 0))
    g = np.empty(W * H * 4, np.float32)
    gt.pixels.foreach_get(g)
    g = g.reshape(H, W, 4)[::-1]
    covered = px[..., 3] > 0.99
    assert covered.mean() > 0.5  # the near, confident half of the frame is covered by points
    diff = (px[..., :3] - g[..., :3])[covered]
    # points are disks a few pixels wide: texture detail blurs, but colours are neither shifted nor scaled
    assert np.median(np.abs(diff)) < 0.04, np.median(np.abs(diff))
    assert np.abs(diff.mean(axis=0)).max() < 0.01, diff.mean(axis=0)


def test_camera_height_scale_in_process(addon, empty_scene, street):
    """The camera-height scale is fitted inside Blender's process (core.geometry.fits's RANSAC): with the backend's
    interpreter pointing nowhere the import still works, recovers the street's true scale, and is repeatable."""
    prefs = _installed(addon, "runs.preferences").get(bpy.context)
    before = prefs.backend_python
    prefs.backend_python = os.path.join(street.root, "no-such-python")  # a backend run would fail on this
    try:
        pts_obj, cam = _import(street, scale_mode="CAMERA_HEIGHT", camera_height=1.6)
    finally:
        prefs.backend_python = before
    metric = street.metric()
    truth = float(metric["metres_per_unit"])
    M = np.array(pts_obj["scpainter_vggt_to_world"]).reshape(4, 4)
    s, _, _ = similarity.decompose_similarity(M)
    assert s == pytest.approx(truth, rel=0.005)
    assert pts_obj["scpainter_scale_method"] == "camera_height"
    assert pts_obj["scpainter_scale_residual_m"] < 0.01
    for f in (1, 8, 16):  # the levelled world: the camera 1.6 m over the road (z = 0) all along
        empty_scene.frame_set(f)
        assert cam.matrix_world.translation.z == pytest.approx(1.6, abs=0.01)

    # the fit on its own: seeded (the same matrix every time, the one the objects carry), its report, its time
    importer = _installed(addon, "scene.importer")
    fit = _installed(addon, "core.geometry.metric_scale")
    options = _installed(addon, "core.import_options")
    pred = vggt_io.load_predictions(street.predictions_path)
    a = fit.camera_height_fit(pred, 1.6)
    b = fit.camera_height_fit(pred, 1.6)
    assert np.array_equal(a.vggt_to_world, b.vggt_to_world) and a.details == b.details
    assert np.allclose(a.vggt_to_world, M, rtol=1e-6, atol=1e-6)  # (the custom property holds float32)
    d = a.details
    assert d["candidates"] == 200_000 and d["inliers"] > 0.9 * d["candidates"] and d["nonfinite_candidates"] == 0
    assert d["tilt_deg"] < 5 and d["plane_inlier_rms_m"] < 0.005
    assert d["inlier_rms_vggt"] * a.scale == pytest.approx(d["plane_inlier_rms_m"])
    assert d["threshold_vggt"] > d["inlier_rms_vggt"]
    empty_scene.frame_set(1)
    result = importer.import_vggt(bpy.context, street.predictions_path,
                                  options.ImportOptions(scale_mode="CAMERA_HEIGHT", camera_height=1.6))
    assert np.array_equal(result.fit.vggt_to_world, a.vggt_to_world)  # the import's own fit, bit for bit
    # measured on 2 busy cores: ~0.2 s of a ~2 s import (the RANSAC itself ~0.1 s); the bound only catches a
    # fit that would freeze Blender's UI
    print(f"camera-height fit {result.timings['metric_fit']:.3f} s of an import of {result.timings['total']:.2f} s")
    assert result.timings["metric_fit"] < 10.0


def test_camera_height_refusals_name_the_file_and_field(addon, empty_scene, tmp_path, capsys):
    """No usable road: an InputError naming the predictions file and the field, with a hint; nothing created."""
    from tests_support import synthetic_predictions

    fit = _installed(addon, "core.geometry.metric_scale")
    arrays = synthetic_predictions(S=1, H=40, W=60)
    arrays["depth"][:] = 2.0  # a wall 2 units in front of the camera fills the image: nothing level
    wall = str(tmp_path / "wall.npz")
    np.savez(wall, **arrays)
    few = str(tmp_path / "few.npz")
    np.savez(few, **synthetic_predictions(S=1, H=14, W=21))  # 6 lower rows × 21, half confident: under 100 points
    n = len(bpy.data.objects)
    for path, field, confidence in ((wall, "(camera height)", 0.0), (few, "depth", 50.0)):
        with pytest.raises(RuntimeError, match=os.path.basename(path)) as e:
            bpy.ops.scpainter.import_vggt(filepath=path, scale_mode="CAMERA_HEIGHT", camera_height=1.6,
                                          confidence_percentile=confidence, extrinsic_convention="world_to_camera")
        assert f"'{field}'" in str(e.value) and "factor or a metric trajectory" in str(e.value)  # the hint
        pred = vggt_io.load_predictions(path, extrinsic_convention="world_to_camera")
        with pytest.raises(fit.GroundPlaneError) as e:
            fit.camera_height_fit(pred, 1.6, confidence)
        assert e.value.path == path and e.value.field == field and e.value.hint
        assert isinstance(e.value, _installed(addon, "core.files").InputError)
    assert len(bpy.data.objects) == n
    with pytest.raises(fit.GroundPlaneError, match="positive number of metres") as e:
        fit.camera_height_fit(pred, -1.0)
    assert e.value.field == "(camera height)"
    # headless: exit 2 and an error event naming file and field
    cli = _installed(addon, "cli")
    capsys.readouterr()
    assert cli.execute(["import", wall, "--camera-height", "1.6", "--confidence-percentile", "0",
                        "--extrinsic-convention", "world_to_camera"]) == 2
    event = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert event["event"] == "error" and event["file"] == wall and event["field"] == "(camera height)"
    assert event["hint"]


def test_one_undo_step(empty_scene, street):
    """One operator call = one undo step, provided nothing inside calls other operators (each would push its own).

    Blender disables undo in background mode (ed.undo's poll fails), so the property is checked structurally.
    """
    import ast

    assert {"REGISTER", "UNDO"} <= set(bpy.types.SCPAINTER_OT_import_vggt.bl_options)
    root = os.path.join(os.path.dirname(__file__), "..", "..", "scpainter_blender", "scene")
    for name in ("importer.py", "points.py", "camera.py", "compat.py", "proposals.py"):
        tree = ast.parse(open(os.path.join(root, name)).read())
        calls = [n for n in ast.walk(tree) if isinstance(n, ast.Attribute) and n.attr == "ops"
                 and isinstance(n.value, ast.Name) and n.value.id == "bpy"]
        assert not calls, f"{name} calls bpy.ops"
    n_before = len(bpy.data.objects)
    _import(street)
    # the points, the recorded camera and the box proposals made after the import (scene/proposals.py): one per
    # parked car the reconstruction shows
    proposed = [o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "proposal"]
    assert len(proposed) == 3 and len(bpy.data.objects) == n_before + 2 + len(proposed)


def _synthetic(**kw):
    """tests_support.synthetic_predictions with world_points that agree with the depth, as VGGT's do (the
    import checks the extrinsic convention against them)."""
    from tests_support import synthetic_predictions

    arrays = synthetic_predictions(**kw)
    wp = unproject.unproject_depth(arrays["depth"][..., 0], V.vggt_K_to_ours(arrays["intrinsic"]),
                                   C.as_matrix4(arrays["extrinsic"]))
    arrays["world_points"] = wp.astype(np.float32)
    return arrays


@pytest.mark.parametrize("problem", ["truncated", "nan_extrinsic", "missing_key", "nan_frame"])
def test_bad_file_reports_and_creates_nothing(empty_scene, tmp_path, problem):
    path = str(tmp_path / "predictions.npz")
    arrays = _synthetic()
    if problem == "nan_extrinsic":
        arrays["extrinsic"][1, 2, 3] = np.nan
    if problem == "nan_frame":
        arrays["depth"][2] = np.nan
    if problem == "missing_key":
        del arrays["intrinsic"]
    np.savez(path, **arrays)
    if problem == "truncated":
        data = open(path, "rb").read()
        open(path, "wb").write(data[: len(data) // 3])
    n = len(bpy.data.objects)
    with pytest.raises(RuntimeError, match="predictions.npz") as e:
        bpy.ops.scpainter.import_vggt(filepath=path)
    if problem == "nan_extrinsic":
        assert "'extrinsic'" in str(e.value) and "NaN" in str(e.value) and "frame 1" in str(e.value)
    if problem == "nan_frame":
        assert "'depth': frame 2 has no pixel with a finite depth" in str(e.value)
    if problem == "missing_key":
        assert "'intrinsic'" in str(e.value)
    assert len(bpy.data.objects) == n


def test_import_menu_and_large_coordinates(empty_scene, tmp_path):
    """A clip 1e5 m from the origin keeps millimetres: vertices are stored relative to the object origin."""
    path = str(tmp_path / "far.npz")
    np.savez(path, **_synthetic())
    traj = str(tmp_path / "traj.npz")
    pred = vggt_io.load_predictions(path)
    M = similarity.similarity_matrix(10.0, metric_scale.OPENCV_TO_BLENDER_AXES, [1e5, 2e5, 50.0])
    np.savez(traj, world_to_camera=similarity.transform_world_to_camera(pred.world_to_camera, M))
    # (random depth per pixel is all depth edges: the test off, as for every synthetic file below)
    assert bpy.ops.scpainter.import_vggt(filepath=path, scale_mode="TRAJECTORY", trajectory_path=traj,
                                         confidence_percentile=0.0, depth_edge_ratio=0.0) == {"FINISHED"}
    obj = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "points")
    ref = point_cloud.point_cloud(pred, 0.0, vggt_to_world=M)
    local = np.empty(len(ref) * 3, np.float32)
    obj.data.attributes["position"].data.foreach_get("vector", local)
    origin = np.array(obj.location, dtype=np.float64)  # float32 in Blender, but an integer here: exact
    assert np.abs(local.reshape(-1, 3) + origin - ref.positions).max() < 1e-3


def test_empty_reconstruction_imports_camera_and_no_points(empty_scene, tmp_path):
    """Every depth behind the camera: an empty point cloud (no crash), the camera still comes in."""
    arrays = _synthetic()
    arrays["depth"][:] = -1.0
    path = str(tmp_path / "empty.npz")
    np.savez(path, **arrays)
    assert bpy.ops.scpainter.import_vggt(filepath=path) == {"FINISHED"}
    pts = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "points")
    assert len(pts.data.vertices) == 0
    assert bpy.context.scene.camera.get("scpainter_kind") == "recorded_camera"
    empty_scene.frame_set(2)
    pts.evaluated_get(bpy.context.evaluated_depsgraph_get())  # the node tree evaluates on nothing


# -- files as other tools write them --------------------------------------------------------------------------

def _installed(addon, module):
    import sys

    return sys.modules[f"{addon}.scpainter_blender.{module}"]


def _job_scene_points(tmp_path, with_scene=False):
    """The job the scene exports, and the points the backend loads from it (world metres) (and its Scene)."""
    from backend.render import frames

    from scpainter_blender.scene import job_export

    path = str(tmp_path / "job.json")
    job = job_export.export_job(bpy.context, path)
    scene = frames.load_scene(job, path, "cpu")
    points = scene.xyz.numpy().astype(np.float64) + scene.origin
    return (job, points, scene) if with_scene else (job, points)


def test_camera_to_world_file_refused_then_imported(empty_scene, tmp_path):
    from vggt_cases import drive, write

    arrays, w2c, intr = drive()
    arrays["extrinsic"] = C.rigid_inverse(w2c)
    path = write(tmp_path, arrays)
    n = len(bpy.data.objects)
    with pytest.raises(RuntimeError) as e:
        bpy.ops.scpainter.import_vggt(filepath=path, scale_factor=2.0)
    msg = str(e.value)
    assert "predictions.npz: 'extrinsic': holds camera-to-world poses" in msg and " m from the file's" in msg
    assert "Extrinsic Convention" in msg and "camera_to_world" in msg
    assert len(bpy.data.objects) == n  # nothing half-imported

    # the drive's depth is random per pixel, every pixel a depth edge: imported with the test off
    assert bpy.ops.scpainter.import_vggt(filepath=path, scale_factor=2.0, confidence_percentile=0.0,
                                         extrinsic_convention="camera_to_world", depth_edge_ratio=0.0) == {"FINISHED"}
    pts = next(o for o in empty_scene.objects if o.get("scpainter_kind") == "points")
    cam = empty_scene.camera
    for o in (pts, cam):
        assert o["scpainter_extrinsic_convention"] == "camera_to_world" and list(o["scpainter_crop"]) == [0] * 4
    M = metric_scale.vggt_to_world_by_factor(2.0).vggt_to_world
    true_w2c = similarity.transform_world_to_camera(w2c, M)
    for i in range(4):
        empty_scene.frame_set(1 + i)
        assert np.abs(np.array(cam.matrix_world) - C.blender_matrix_world(true_w2c[i])).max() < 1e-4, i
    truth = unproject.unproject_depth(arrays["depth"], V.vggt_K_to_ours(intr), w2c).reshape(-1, 3)
    truth = 2.0 * truth @ metric_scale.OPENCV_TO_BLENDER_AXES.T
    assert np.abs(_world_vertices(pts) - truth).max() < 1e-4
    # the job carries the convention; the backend loads the very same points
    job, backend_points = _job_scene_points(tmp_path)
    assert job.scene.extrinsic_convention == "camera_to_world" and job.scene.crop == [0, 0, 0, 0]
    assert job.scene.point_cleaning.depth_edge_ratio is None     # off at import: off in the job
    assert np.abs(backend_points - truth).max() < 1e-4


def test_padded_file_cropped_camera_and_job(empty_scene, tmp_path):
    from vggt_cases import drive, pad, write

    arrays, w2c, intr = drive(H=22, W=32)
    padded = write(tmp_path, pad(arrays, 5, 5))
    assert bpy.ops.scpainter.import_vggt(filepath=padded, confidence_percentile=0.0,
                                         depth_edge_ratio=0.0) == {"FINISHED"}   # random depth: all edges
    scene = empty_scene
    assert (scene.render.resolution_x, scene.render.resolution_y) == (32, 22)
    pts = next(o for o in scene.objects if o.get("scpainter_kind") == "points")
    assert list(pts["scpainter_crop"]) == [0, 5, 0, 5] and pts["scpainter_extrinsic_convention"] == "world_to_camera"
    from scpainter_blender.scene.camera import K_of_camera_object

    scene.frame_set(2)
    assert np.abs(K_of_camera_object(scene, scene.camera) - V.vggt_K_to_ours(intr[1])).max() < 1e-3
    truth = unproject.unproject_depth(arrays["depth"], V.vggt_K_to_ours(intr), w2c).reshape(-1, 3)
    truth = truth @ metric_scale.OPENCV_TO_BLENDER_AXES.T
    assert np.abs(_world_vertices(pts) - truth).max() < 1e-4   # none of the padding's points
    job, backend_points = _job_scene_points(tmp_path)
    assert job.scene.crop == [0, 5, 0, 5] and job.scene.point_cleaning.depth_edge_ratio is None
    assert np.abs(backend_points - truth).max() < 1e-4
    # explicit crop, and no crop at all
    for crop, size in (("0 5 0 5", (32, 22)), ("none", (32, 32))):
        bpy.ops.wm.read_homefile(use_empty=True)
        assert bpy.ops.scpainter.import_vggt(filepath=padded, crop=crop) == {"FINISHED"}
        assert (bpy.context.scene.render.resolution_x, bpy.context.scene.render.resolution_y) == size
    with pytest.raises(RuntimeError, match="crop '1 2': expected 'auto', 'none' or four"):
        bpy.ops.scpainter.import_vggt(filepath=padded, crop="1 2")


def test_nan_pixels_and_unchecked_convention_in_the_report(addon, empty_scene, tmp_path):
    from vggt_cases import drive, write

    arrays, _, _ = drive()
    del arrays["world_points"], arrays["world_points_conf"]
    arrays["depth"][3, 0, :4] = np.inf
    arrays["depth_conf"][1, 7, 7] = np.nan
    path = write(tmp_path, arrays)
    importer = _installed(addon, "scene.importer")
    options = _installed(addon, "core.import_options")
    result = importer.import_vggt(bpy.context, path,
                                  options.ImportOptions(confidence_percentile=0.0, depth_edge_ratio=None))
    assert result.num_points == 4 * 24 * 32 - 5 and result.depth_edge_points == 0
    assert any("extrinsic convention not checked (the file has no world_points)" in w for w in result.warnings)
    assert any("dropped 5 pixels with NaN/inf depth or confidence (frame 1: 1, frame 3: 4)" in w
               for w in result.warnings)
    assert result.load_report.nonfinite == {"depth": [0, 0, 0, 4], "depth_conf": [0, 1, 0, 0]}
    bpy.ops.wm.read_homefile(use_empty=True)           # one points object: the one the job is exported from
    assert bpy.ops.scpainter.import_vggt(filepath=path, depth_edge_ratio=0.0) == {"FINISHED"}  # reports, imports
    _, backend_points = _job_scene_points(tmp_path)     # the backend drops the same pixels
    pts = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "points")
    assert len(backend_points) == len(pts.data.vertices) > 0 and np.all(np.isfinite(backend_points))


def test_camera_height_with_convention_and_crop(empty_scene, street, tmp_path):
    """The camera-height fit uses the file as the import read it: camera-to-world poses and a padded image.

    The street's world is re-posed by a tilt (as a tool that re-centres the world writes it): read as
    world-to-camera, those poses put the cameras at the wrong heights over the road (scale 11 % off, 0.8 m
    residual)."""
    from vggt_cases import pad

    S = 8
    with np.load(street.predictions_path) as z:
        a = {k: z[k][:S] for k in z.files}
    tilt, yaw = np.radians(25.0), np.radians(30.0)
    G = np.eye(4)
    G[:3, :3] = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]]) @ \
        np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
    G[:3, 3] = [1.0, -0.5, 2.0]
    w2c = C.as_matrix4(a["extrinsic"]) @ C.rigid_inverse(G)
    arrays = dict(images=np.moveaxis(a["images"], 1, -1), depth=a["depth"][..., 0], depth_conf=a["depth_conf"],
                  extrinsic=C.rigid_inverse(w2c), intrinsic_vggt=a["intrinsic"],
                  world_points=(a["world_points"] @ G[:3, :3].T + G[:3, 3]).astype(np.float32),
                  world_points_conf=a["world_points_conf"])
    H, W = arrays["depth"].shape[1:]
    top = (W - H) // 2
    path = str(tmp_path / "predictions.npz")
    vggt_io.save_predictions(path, **pad(arrays, top, W - H - top))
    with pytest.raises(RuntimeError, match="holds camera-to-world poses"):
        bpy.ops.scpainter.import_vggt(filepath=path, scale_mode="CAMERA_HEIGHT", camera_height=1.6)
    assert bpy.ops.scpainter.import_vggt(filepath=path, scale_mode="CAMERA_HEIGHT", camera_height=1.6,
                                         extrinsic_convention="camera_to_world") == {"FINISHED"}
    pts = next(o for o in empty_scene.objects if o.get("scpainter_kind") == "points")
    cam = empty_scene.camera
    assert list(pts["scpainter_crop"]) == [0, top, 0, W - H - top]
    M = np.array(pts["scpainter_vggt_to_world"]).reshape(4, 4)
    s, _, _ = similarity.decompose_similarity(M)
    assert s == pytest.approx(float(street.metric()["metres_per_unit"]), rel=0.01)
    assert pts["scpainter_scale_residual_m"] < 0.02
    for f in (1, S):
        empty_scene.frame_set(f)
        assert cam.matrix_world.translation.z == pytest.approx(1.6, abs=0.02)


# -- depth edges: one setting for the viewport and the render -------------------------------------------------

def _stepped_drive(S, H, W):
    """``vggt_cases.drive`` with a real depth edge: a near wall (depth 2) on the left half of every frame, a far one
    (4) on the right, the column between them smeared to 3 as a network's depth is, 0.3 % noise on all; the
    world_points from that depth (so the convention check passes). For any ratio in (0.015, 0.25) the depth-edge
    test takes 3 columns (the smeared one and one on each side); at 0.3, 2 (the far side's jump, 1/4, is under it)."""
    from vggt_cases import drive

    arrays, w2c, intr = drive(S=S, H=H, W=W)
    depth = np.where(np.arange(W) < W // 2, 2.0, 4.0) * np.ones((S, H, 1))
    depth[:, :, W // 2] = 3.0
    depth *= 1.0 + np.random.default_rng(1).uniform(-0.003, 0.003, depth.shape)
    arrays["depth"] = depth.astype(np.float32)
    arrays["world_points"] = unproject.unproject_depth(arrays["depth"], V.vggt_K_to_ours(intr), w2c).astype(np.float32)
    return arrays


def test_depth_edges_left_out_as_the_render_loads_them(addon, empty_scene, tmp_path):
    """The import leaves out the depth-edge pixels with the ratio it is given (default: the job's), stores it on
    the points, and the exported job carries it: the backend loads exactly the points the viewport shows."""
    from vggt_cases import write

    S, H, W = 3, 16, 24
    path = write(tmp_path, _stepped_drive(S, H, W))
    assert 0.015 < EDGE_RATIO < 0.25  # (what _stepped_drive's 3 columns assume)
    importer = _installed(addon, "scene.importer")
    options = _installed(addon, "core.import_options")
    result = importer.import_vggt(bpy.context, path, options.ImportOptions(confidence_percentile=0.0))
    assert result.depth_edge_ratio == EDGE_RATIO and result.depth_edge_points == S * H * 3
    assert result.num_points == S * H * (W - 3)
    assert not [w for w in result.warnings if "depth-edge" in w]
    # a ratio so small that every pixel is an edge leaves nothing, and says so
    bpy.ops.wm.read_homefile(use_empty=True)
    tiny = importer.import_vggt(bpy.context, path, options.ImportOptions(confidence_percentile=0.0,
                                                                         depth_edge_ratio=1e-4))
    assert tiny.num_points < tiny.depth_edge_points and any("depth-edge test left out" in w for w in tiny.warnings)
    for kw, ratio, columns in (({}, EDGE_RATIO, 3), ({"depth_edge_ratio": 0.3}, 0.3, 2),
                               ({"depth_edge_ratio": 0.0}, None, 0)):
        bpy.ops.wm.read_homefile(use_empty=True)
        assert bpy.ops.scpainter.import_vggt(filepath=path, confidence_percentile=0.0, **kw) == {"FINISHED"}
        pts = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "points")
        cam = bpy.context.scene.camera
        assert pts["scpainter_depth_edge_ratio"] == cam["scpainter_depth_edge_ratio"] == (ratio or 0.0)
        assert len(pts.data.vertices) == S * H * (W - columns), kw
        job, backend_points, scene = _job_scene_points(tmp_path, with_scene=True)
        clean = J.load(tmp_path / "job.json").scene.point_cleaning
        assert clean.depth_edge_ratio == job.scene.point_cleaning.depth_edge_ratio == ratio   # exact: 0.3, not float32
        assert clean.to_dict()["outliers"] == J.PointCleaning().to_dict()["outliers"]       # the job's default
        assert scene.cleaning["depth_edge_points"] == S * H * columns
        # the same points in the same order (frame by frame, pixel order), float32 on both sides
        assert np.abs(backend_points - _world_vertices(pts)).max() < 1e-4, kw


def test_depth_edge_ratio_checked_before_reading(addon, empty_scene, tmp_path):
    """A ratio no job can hold is bad input named "(import options)" / depth_edge_ratio, before any file is read;
    None and 0 are off."""
    options = _installed(addon, "core.import_options")
    errors = _installed(addon, "core.errors")
    for bad in (-0.1, 1e-5, 101.0, float("nan"), float("inf"), True, "0.05"):
        with pytest.raises(errors.InputError) as e:
            options.ImportOptions(depth_edge_ratio=bad).check()
        assert (e.value.path, e.value.field) == ("(import options)", "depth_edge_ratio") and e.value.hint, bad
    for off in (None, 0, 0.0):
        assert options.ImportOptions(depth_edge_ratio=off).check().edge_ratio is None
    lo, hi = J.DEPTH_EDGE_RATIO_BOUNDS
    assert [options.ImportOptions(depth_edge_ratio=r).check().edge_ratio for r in (lo, 1, hi)] == [lo, 1.0, hi]
    assert options.ImportOptions().depth_edge_ratio == EDGE_RATIO == options.DEPTH_EDGE_RATIO
    with pytest.raises(RuntimeError, match=r"\(import options\): depth_edge_ratio: expected a fraction"):
        bpy.ops.scpainter.import_vggt(filepath=str(tmp_path / "never-read.npz"), depth_edge_ratio=1e-5)
    # the operator's property: the job's default, 0 = off, and a tooltip saying what it does
    prop = bpy.ops.scpainter.import_vggt.get_rna_type().properties["depth_edge_ratio"]
    assert prop.default == pytest.approx(EDGE_RATIO) and prop.hard_min == 0.0
    assert "flying pixels" in prop.description and "0 turns it off" in prop.description


def test_multi_camera_recording(empty_scene, tmp_path):
    """VGGT run on two cameras at once (frames interleaved: F0 B0 F1 B1 ...) with its sensors sidecar beside the
    predictions: one recorded camera per sensor, each keyed at its own frames' scene frames with its own poses; the
    reference (CAM_FRONT) is the scene camera; the recording's rig is stored with the points and read back. A
    sidecar whose frame count differs from the predictions' is refused before anything is made."""
    from scpainter_blender.core import errors, import_options
    from scpainter_blender.core.vggt import sensors as S
    from scpainter_blender.scene import compat, importer, recording_rig
    from tests.core.geometry.rig_cases import predictions, small_rig

    rig = small_rig()
    arrays, sensors, c2w = predictions(rig)
    folder = tmp_path / "drive"
    folder.mkdir()
    path = str(folder / "predictions.npz")
    vggt_io.save_predictions(path, **arrays)
    short = S.Sensors(sensors.sensor[:6], sensors.timestamp_us[:6])
    S.write(tmp_path / "short.json", short)
    with pytest.raises(errors.InputError) as e:
        importer.import_vggt(bpy.context, path, import_options.ImportOptions(sensors=str(tmp_path / "short.json")))
    assert e.value.field == "frames" and "6 frames, but the predictions predictions.npz hold 8" in e.value.message
    assert len(bpy.data.objects) == 0

    S.write(S.default_path(path), sensors)          # found beside the predictions
    assert bpy.ops.scpainter.import_vggt(filepath=path, propose_boxes=False) == {"FINISHED"}
    scene = bpy.context.scene
    cams = [o for o in scene.objects if o.get("scpainter_kind") == "recorded_camera"]
    assert sorted(c.name for c in cams) == ["drive CAM_BACK", "drive CAM_FRONT"]
    assert scene.camera.name == "drive CAM_FRONT" and (scene.frame_start, scene.frame_end) == (1, 4)
    for cam in cams:
        name = cam["scpainter_sensor"]
        idx = sensors.frames_of(name)            # VGGT frames 0, 2, 4, 6 (front) and 1, 3, 5, 7 (back)
        assert list(idx) == list(range(0 if name == "CAM_FRONT" else 1, 8, 2))
        assert cam["scpainter_frame_start"] == 1 and len(cam["scpainter_intrinsics"]) == 4 * 9
        frames = sorted({int(k.co[0]) for fc in compat.fcurves(cam) for k in fc.keyframe_points})
        assert frames == [1, 2, 3, 4]            # its own four frames, at scene frames 1-4
        for f, j in zip(frames, idx):
            scene.frame_set(f)
            np.testing.assert_allclose(C.world_to_camera_from_blender(np.array(cam.matrix_world)),
                                       C.rigid_inverse(c2w[j]), atol=1e-4)
    pts = next(o for o in scene.objects if o.get("scpainter_kind") == "points")
    assert pts["scpainter_num_frames"] == 8
    # scene frame k groups each sensor's k-th frame: stored per VGGT frame, and per point for the viewport
    assert list(pts["scpainter_scene_frames"]) == [0, 0, 1, 1, 2, 2, 3, 3] == list(sensors.scene_frames())
    assert list(pts["scpainter_frame_sensors"]) == sensors.sensor   # which camera each VGGT frame is
    n = len(pts.data.vertices)
    vggt_frame, scene_frame = np.empty(n, np.int32), np.empty(n, np.int32)
    pts.data.attributes["vggt_frame"].data.foreach_get("value", vggt_frame)
    pts.data.attributes["scene_frame"].data.foreach_get("value", scene_frame)
    np.testing.assert_array_equal(scene_frame, vggt_frame // 2)
    stored = recording_rig.recording_rig(scene)
    assert stored.name == "recording" and [c.name for c in stored.cameras] == ["CAM_FRONT", "CAM_BACK"]
    for c in stored.cameras:
        assert c.resolution == (16, 12)
        np.testing.assert_allclose(c.K, rig.camera(c.name).K, atol=1e-5)
    # CAM_BACK relative to CAM_FRONT as mounted; CAM_FRONT's height over the road (z = 0 of this world)
    rel = np.linalg.inv(stored.camera("CAM_FRONT").camera_to_ego) @ stored.camera("CAM_BACK").camera_to_ego
    true = np.linalg.inv(rig.camera("CAM_FRONT").camera_to_ego) @ rig.camera("CAM_BACK").camera_to_ego
    np.testing.assert_allclose(rel, true, atol=2e-3)
    assert abs(stored.camera("CAM_FRONT").camera_to_ego[2, 3] - rig.camera("CAM_FRONT").camera_to_ego[2, 3]) < 1e-3

