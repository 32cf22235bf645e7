"""Training pairs clean their points as the renderer cleans a job's (pairs.point_cleaning = scene.point_cleaning):
the same points, and so the same condition layers, as ``frames.load_scene`` for the same predictions and settings.

A tiny clip (4 frames of 24 x 20, metric poses through a similarity) whose depth maps are blocks at different depths
(depth edges between them) with a few spikes (floaters); renders at 64 x 64."""

import json

import numpy as np
import pytest
import torch
from PIL import Image

from backend.render import frames as fr
from backend.train import clip as clip_mod
from backend.train import config as C
from backend.train import pairs
from scpainter_blender.core import job as J
from scpainter_blender.core.geometry import point_cloud, similarity
from scpainter_blender.core.vggt import predictions as vggt, npz as vggt_io

S, H, W = 4, 20, 24
SIZE = 64           # the training resolution (a multiple of 64, as the config requires)
VGGT_TO_WORLD = similarity.similarity_matrix(2.5, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], [100.0, -40.0, 3.0])
STATISTICAL = {"method": "statistical", "neighbours": 8, "std_ratio": 1.0}


@pytest.fixture(scope="module")
def clip_path(tmp_path_factory):
    """clip.json of the tiny clip; frames are 2x the predictions' size, so K_for scales a K that is not VGGT's."""
    folder = tmp_path_factory.mktemp("clip")
    rng = np.random.default_rng(4)
    depth = np.kron(rng.uniform(3, 12, (S, 4, 4)), np.ones((1, 5, 6)))   # 4 x 4 blocks: edges between them
    depth[rng.random((S, H, W)) < 0.02] *= 0.5                             # spikes: floaters
    K = np.array([[20.0, 0, W / 2], [0, 20.0, H / 2], [0, 0, 1]])
    ext = np.tile(np.eye(4)[:3], (S, 1, 1))
    ext[:, 0, 3] = -0.2 * np.arange(S)                                     # a camera moving sideways
    vggt_io.save_predictions(folder / "predictions.npz", rng.random((S, H, W, 3)), depth, 1 + rng.random((S, H, W)),
                             ext, np.tile(vggt.ours_K_to_vggt(K), (S, 1, 1)))
    w2c_vggt = np.tile(np.eye(4), (S, 1, 1))
    w2c_vggt[:, :3] = ext
    np.savez(folder / "poses.npz", world_to_camera=similarity.transform_world_to_camera(w2c_vggt, VGGT_TO_WORLD),
             K=np.tile(np.diag([2.0, 2.0, 1.0]) @ K, (S, 1, 1)), vggt_to_world=VGGT_TO_WORLD)
    (folder / "frames").mkdir()
    for i in range(S):
        Image.fromarray(rng.integers(0, 256, (2 * H, 2 * W, 3), dtype=np.uint8)).save(folder / "frames" / f"{i}.png")
    clip_mod.save(folder / "clip.json", {"schema": clip_mod.SCHEMA, "predictions": "predictions.npz",
                                         "frames": "frames/{}.png", "poses": "poses.npz"})
    return str(folder / "clip.json")


def _settings(tmp_path, point_cleaning=...):
    """PairSettings as a train.json gives them (the field absent when ``point_cleaning`` is ...)."""
    p = {"width": SIZE, "height": SIZE, "frames": 2, "source_window": 2, "confidence_percentile": 0.0}
    if point_cleaning is not ...:
        p["point_cleaning"] = point_cleaning
    data = {"schema": C.SCHEMA, "checkpoint": "c", "clips": ["x"], "output_dir": "o", "pairs": p}
    return C.from_dict(data, str(tmp_path / "train.json")).pairs


def _job_scene(tmp_path, clip, settings):
    """frames.load_scene of a job whose scene is the clip's predictions with the pairs' settings (its first frame
    at the clip's first camera: the same scene origin as the pair maker's)."""
    scene = {"predictions": clip.predictions.path, "vggt_to_world": clip.vggt_to_world.tolist(),
             "confidence_percentile": settings.confidence_percentile,
             "point_cleaning": settings.point_cleaning.to_dict()}
    K = clip.K_for(SIZE, SIZE)
    job = {"schema": J.SCHEMA, "resolution": [SIZE, SIZE], "output_dir": "out", "scene": scene,
           "frames": [{"frame": t, "K": K[t].tolist(), "world_to_camera": clip.world_to_camera[t].tolist(),
                       "source_frames": list(range(S))} for t in range(S)]}
    path = tmp_path / "job.json"
    path.write_text(json.dumps(job))
    return J.load(path), fr.load_scene(J.load(path), str(path), "cpu")


@pytest.mark.parametrize("cleaning", [..., None, {"depth_edge_ratio": 0.1},
                                      {"depth_edge_ratio": None, "outliers": STATISTICAL},
                                      {"outliers": {"method": "radius", "radius_m": 0.5, "min_points": 3}}])
def test_pair_points_are_the_renderers(tmp_path, clip_path, cleaning):
    """For the defaults (field absent), off, and each filter: the pair maker holds exactly load_scene's points
    (positions bit for bit, colours, each source frame's slice) and reports the same counts dropped."""
    clip = clip_mod.load(clip_path)
    settings = _settings(tmp_path, cleaning)
    maker = pairs.PairMaker(clip, settings)
    _, scene = _job_scene(tmp_path, clip, settings)
    assert torch.equal(maker.xyz, scene.xyz) and torch.equal(maker.rgb, scene.rgb)
    for f in range(S):
        a, b = scene.frame_slices.get(f, (0, 0))
        assert int(maker.offsets[f + 1] - maker.offsets[f]) == b - a
    assert maker.cleaning == {k: scene.cleaning[k] for k in ("depth_edge_points", "outlier_points")}
    if isinstance(cleaning, dict) and cleaning.get("outliers"):
        assert maker.cleaning["outlier_points"] > 0              # the rule ran and removed something


def test_cleaning_changes_the_pairs(tmp_path, clip_path):
    """On depth maps with edges the default cleaning drops exactly point_cloud's depth-edge pixels (at the job's
    default ratio), and so the points and the rendered condition differ from uncleaned pairs."""
    clip = clip_mod.load(clip_path)
    default, off = pairs.PairMaker(clip, _settings(tmp_path)), pairs.PairMaker(clip, _settings(tmp_path, None))
    ratio = J.POINT_CLEANING["depth_edge_ratio"]
    cleaned = point_cloud.point_cloud(clip.predictions, 0.0, vggt_to_world=VGGT_TO_WORLD, depth_edge_ratio=ratio)
    everything = point_cloud.point_cloud(clip.predictions, 0.0, vggt_to_world=VGGT_TO_WORLD)
    assert len(default.xyz) == len(cleaned) < len(off.xyz) == len(everything)
    assert default.cleaning["depth_edge_points"] == len(everything) - len(cleaned) > 0
    a = default.sample(np.random.default_rng(0), t0=1, asset=False)
    b = off.sample(np.random.default_rng(0), t0=1, asset=False)
    assert a["sources"] == b["sources"]                         # same draws: only the points differ
    assert float(a["valid"].mean()) < float(b["valid"].mean())  # the edge pixels' points are gone: more holes


def test_pair_condition_equals_the_render(tmp_path, clip_path):
    """A novel-view pair's condition layers are render_frame's for a job with the same scene and sources."""
    clip = clip_mod.load(clip_path)
    settings = _settings(tmp_path, {"outliers": STATISTICAL})
    maker = pairs.PairMaker(clip, settings)
    job, scene = _job_scene(tmp_path, clip, settings)
    s = maker.sample(np.random.default_rng(2), t0=1, asset=False)
    for i, t in enumerate(range(1, 3)):
        entry = J.Frame(t, job.frames[t].K, job.frames[t].world_to_camera, s["sources"][i])
        layers = fr.render_frame(scene, entry, SIZE, SIZE)
        np.testing.assert_array_equal(s["image"][i].numpy(), np.stack([layers["R"], layers["G"], layers["B"]]))
        np.testing.assert_array_equal(s["valid"][i, 0].numpy(), 1.0 - layers["hole"])
        assert 0.0 < float(s["valid"][i].mean()) < 1.0
