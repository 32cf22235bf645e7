"""Point cleaning: open3d's outlier rules as stated (against brute force), and a job's ``scene.point_cleaning``
applied once per scene by ``frames.load_scene``, in the render's job key."""

import json

import numpy as np
import pytest

from backend.render import cleaning
from backend.render import command as render_cmd
from backend.render import frames as fr
from scpainter_blender.core import job as J
from scpainter_blender.core.geometry import point_cloud
from scpainter_blender.core.vggt import predictions as vggt, npz as vggt_io


def _cloud(rng):
    """A dense patch of surface (1 m², 5 mm noise) and a few floaters around it, metres, 1e5 m from the origin."""
    surface = np.column_stack([rng.uniform(0, 1, (500, 2)), 0.005 * rng.standard_normal(500)])
    floaters = rng.uniform(-0.5, 1.5, (15, 3)) + [0, 0, 0.3]
    return np.concatenate([surface, floaters]) + [1e5, -2e5, 30.0], len(surface)


def _distances(p):
    return np.linalg.norm(p[:, None] - p[None], axis=2)


def statistical_reference(p, neighbours, std_ratio):
    """m_i = mean distance to the ``neighbours`` nearest points, i itself (distance 0) among them; keep
    m_i <= mean(m) + std_ratio · std(m) (sample standard deviation)."""
    m = np.sort(_distances(p), axis=1)[:, :neighbours].mean(1)
    return m <= m.mean() + std_ratio * m.std(ddof=1)


def radius_reference(p, radius_m, min_points):
    """Keep i when at least ``min_points`` other points lie within ``radius_m``."""
    return (_distances(p) <= radius_m).sum(1) - 1 >= min_points


@pytest.mark.parametrize("neighbours,std_ratio", [(4, 1.0), (16, 2.0), (30, 0.5)])
def test_statistical_rule(neighbours, std_ratio):
    p, n_surface = _cloud(np.random.default_rng(neighbours))
    keep = cleaning.outlier_keep(p, J.OutlierRemoval("statistical", neighbours=neighbours, std_ratio=std_ratio))
    np.testing.assert_array_equal(keep, statistical_reference(p - p[0], neighbours, std_ratio))
    if std_ratio >= 1.0:
        assert keep[:n_surface].mean() > 0.97 and keep[n_surface:].mean() < 0.5  # it removes floaters


@pytest.mark.parametrize("radius_m,min_points", [(0.05, 2), (0.1, 8), (0.3, 20)])
def test_radius_rule(radius_m, min_points):
    p, n_surface = _cloud(np.random.default_rng(7))
    keep = cleaning.outlier_keep(p, J.OutlierRemoval("radius", radius_m=radius_m, min_points=min_points))
    np.testing.assert_array_equal(keep, radius_reference(p - p[0], radius_m, min_points))


def test_nothing_to_clean():
    assert cleaning.outlier_keep(np.zeros((0, 3)), J.OutlierRemoval()).shape == (0,)
    assert cleaning.outlier_keep(np.ones((5, 3)), None).all()


# -- the job's setting, through load_scene ------------------------------------------------------------------------

def _predictions(path, rng, S=3, H=20, W=24):
    """Boxes at different depths (edges between them) with a few depth spikes (floaters); our K, identity poses
    moved sideways."""
    depth = np.kron(rng.uniform(3, 12, (S, 4, 4)), np.ones((1, 5, 6)))
    spikes = rng.random((S, H, W)) < 0.01
    depth[spikes] *= 0.5
    K = np.array([[20.0, 0, W / 2], [0, 20.0, H / 2], [0, 0, 1]])
    ext = np.tile(np.eye(4)[:3], (S, 1, 1))
    ext[:, 0, 3] = -0.2 * np.arange(S)
    vggt_io.save_predictions(path, rng.random((S, H, W, 3)), depth, 1 + rng.random((S, H, W)), ext,
                             np.tile(vggt.ours_K_to_vggt(K), (S, 1, 1)))
    return K


def _job(tmp_path, cleaning_field=...):
    K = _predictions(tmp_path / "predictions.npz", np.random.default_rng(2))
    scene = {"predictions": "predictions.npz", "vggt_to_world": np.eye(4).tolist(), "confidence_percentile": 0.0}
    if cleaning_field is not ...:
        scene["point_cleaning"] = cleaning_field
    job = {"schema": J.SCHEMA, "resolution": [24, 20], "output_dir": "out", "scene": scene,
           "frames": [{"frame": 1, "K": K.tolist(), "world_to_camera": np.eye(4).tolist(), "source_frames": [0, 1, 2]}]}
    path = tmp_path / "job.json"
    path.write_text(json.dumps(job))
    return str(path), J.load(path)


def test_load_scene_cleans_once_as_the_job_says(tmp_path):
    path, off = _job(tmp_path, None)                         # "point_cleaning": null: nothing cleaned
    assert off.scene.point_cleaning.depth_edge_ratio is None and off.scene.point_cleaning.outliers is None
    pred = vggt_io.load_predictions(str(tmp_path / "predictions.npz"), world_points=False)
    everything = point_cloud.point_cloud(pred, 0.0)
    scene = fr.load_scene(off, path, "cpu")
    assert len(scene.xyz) == len(everything) and scene.cleaning["depth_edge_points"] == 0
    # the defaults (a job without the field) clean, and are what the file's defaults say
    path, default = _job(tmp_path)
    assert default.scene.point_cleaning.to_dict() == J.POINT_CLEANING
    # each filter alone, on the same predictions: exactly its rule
    path, edges = _job(tmp_path, {"depth_edge_ratio": 0.1, "outliers": None})
    scene = fr.load_scene(edges, path, "cpu")
    kept = point_cloud.point_cloud(pred, 0.0, depth_edge_ratio=0.1)
    assert 0 < scene.cleaning["depth_edge_points"] == len(everything) - len(kept) == len(everything) - len(scene.xyz)
    np.testing.assert_array_equal(scene.xyz.numpy(), (kept.positions - scene.origin).astype(np.float32))
    stat = {"method": "statistical", "neighbours": 8, "std_ratio": 1.0}
    path, outl = _job(tmp_path, {"depth_edge_ratio": None, "outliers": stat})
    scene = fr.load_scene(outl, path, "cpu")
    want = statistical_reference(everything.positions - everything.positions[0], 8, 1.0)
    assert scene.cleaning["outlier_points"] == int((~want).sum()) > 0
    np.testing.assert_array_equal(scene.xyz.numpy(), (everything.positions[want] - scene.origin).astype(np.float32))
    # the per-frame slices and boxes the frame skip uses describe the cleaned points
    for f, (a, b) in scene.frame_slices.items():
        assert (scene.frame[a:b] == f).all()
        np.testing.assert_array_equal(scene.frame_boxes[f], np.stack([scene.xyz[a:b].min(0).values.numpy(),
                                                                      scene.xyz[a:b].max(0).values.numpy()]))


def test_changed_cleaning_renders_again(tmp_path):
    """The render's job key hashes the job as resolved: a changed setting is a new key, an absent field is the
    defaults written out."""
    path, default = _job(tmp_path)
    keys = {render_cmd.job_key(path, default, 0)}
    for setting in ({"depth_edge_ratio": 0.2}, None, {"outliers": {"method": "radius"}},
                    {"outliers": {"method": "statistical", "std_ratio": 3.0}}):
        p, job = _job(tmp_path, setting)
        keys.add(render_cmd.job_key(p, job, 0))
    assert len(keys) == 5
    p, explicit = _job(tmp_path, J.POINT_CLEANING)
    assert render_cmd.job_key(p, explicit, 0) == render_cmd.job_key(path, default, 0)


def test_render_logs_what_cleaning_dropped_and_warns_when_it_dropped_most():
    import torch

    lines = []
    stats = {"depth_edge_points": 900, "outlier_points": 50, "cloud_s": 0.1, "outliers_s": 2.0}
    scene = fr.Scene(origin=np.zeros(3), device=torch.device("cpu"), xyz=torch.zeros((100, 3)), cleaning=stats)
    render_cmd._log_cleaning(scene, lines.append)
    assert "900 points on depth edges and 50 outliers" in lines[0]
    assert lines[1].startswith("warning: point cleaning left out 950 of 1,050 points")
    lines.clear()
    scene.xyz = torch.zeros((5000, 3))
    render_cmd._log_cleaning(scene, lines.append)
    assert len(lines) == 1 and "warning" not in lines[0]
