"""frames: a worker's jobs that place one kept cloud at one origin share the points' z-buffers (``PointLayers``): a
view rendered once is copied, not projected again, and gives the same layers bit for bit as a scene that keeps
nothing; another camera, another origin or another frame set renders; what is kept stays within its byte bound,
and a caller writing into a served copy does not change what is kept."""

import numpy as np
import torch

from backend.render import frames as fr
from backend.render import points as pts
from scpainter_blender.core import job as job_mod
from scpainter_blender.core.geometry import point_cloud

W, H = 40, 30
K = np.array([[30.0, 0, 20], [0, 30.0, 15], [0, 0, 1]])


def _kept():
    rng = np.random.default_rng(3)
    n = 3000
    u, v = rng.uniform(-8, 8, n), rng.uniform(-5, 5, n)
    positions = np.stack([u, v, rng.uniform(6, 30, n)], 1) + [100.0, -20.0, 0.0]
    frame = np.repeat(np.arange(3), n // 3)
    cloud = point_cloud.FramePoints(positions=positions, colors=rng.uniform(0, 1, (n, 3)).astype(np.float32),
                                    frame=frame, offsets=np.array([0, n // 3, 2 * n // 3, n]))
    return fr.KeptCloud.of(cloud, np.ones(n, bool), {"removed_points": 0})


def _placed(kept, origin, share=True):
    """A scene with ``kept`` placed at ``origin`` as ``frames.load_points`` places it (``share=False``: placed by
    hand, as the code before the shared z-buffers did, keeping nothing)."""
    scene = fr.Scene(origin=np.asarray(origin, np.float64), device=torch.device("cpu"))
    if share:
        scene.xyz, scene.rgb, scene.frame = kept.place(scene.origin, scene.device)
        scene.point_layers, scene.placement = kept.views, kept.placement(scene.origin, scene.device)
    else:
        scene.xyz = torch.as_tensor((kept.positions - scene.origin).astype(np.float32))
        scene.rgb = torch.as_tensor(np.array(kept.colors))
        scene.frame = torch.as_tensor(np.array(kept.frame))
    scene.frames_present, scene.frame_slices = kept.frames_present, dict(kept.slices)
    scene.frame_boxes = kept.boxes(scene.origin)
    return scene


def _entry(shift=0.0, frames=(0, 1, 2)):
    w2c = np.eye(4)
    w2c[:3, 3] = (-100.0 + shift, 20.0, 0.0)  # the camera at world (100 - shift, -20, 0), looking down +z
    return job_mod.Frame(0, K, w2c, list(frames))


def _counting(monkeypatch):
    calls = []
    real = pts.render_points

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(pts, "render_points", counted)
    return calls


def test_a_second_job_at_the_same_origin_reuses_the_view_with_the_same_layers(monkeypatch):
    kept = _kept()
    origin = np.array([100.0, -20.0, 0.0])
    alone = fr.render_frame(_placed(kept, origin, share=False), _entry(), W, H)
    calls = _counting(monkeypatch)
    first = fr.render_frame(_placed(kept, origin), _entry(), W, H)
    second = fr.render_frame(_placed(kept, origin), _entry(), W, H)   # another job, the same view
    assert len(calls) == 1
    for layers in (first, second):
        assert set(layers) == set(alone)
        assert all(np.array_equal(layers[k], alone[k]) and layers[k].dtype == alone[k].dtype for k in alone)
    assert np.isfinite(alone["Z"]).any() and not alone["hole"].all()  # the points do land
    fr.render_frame(_placed(kept, origin), _entry(shift=0.5), W, H)           # another camera
    fr.render_frame(_placed(kept, origin), _entry(frames=(0, 1)), W, H)       # other source frames
    fr.render_frame(_placed(kept, origin + [0.25, 0, 0]), _entry(), W, H)     # another origin: other points
    assert len(calls) == 4


def test_a_placement_is_made_once_per_origin_equal_to_one_made_by_hand_and_bounded(monkeypatch):
    kept = _kept()
    cpu = torch.device("cpu")
    origin = np.array([100.0, -20.0, 0.0])
    xyz, rgb, frame = kept.place(origin, cpu)
    assert torch.equal(xyz, torch.as_tensor((kept.positions - origin).astype(np.float32)))
    assert torch.equal(rgb, torch.as_tensor(kept.colors)) and torch.equal(frame, torch.as_tensor(kept.frame))
    again = kept.place(origin.copy(), cpu)
    assert again[0] is xyz and again[1] is rgb and again[2] is frame             # the same origin: shared
    other = kept.place(origin + 1e-9, cpu)                                        # any other origin: its own
    assert other[0] is not xyz and other[1] is rgb
    assert torch.equal(other[0], torch.as_tensor((kept.positions - (origin + 1e-9)).astype(np.float32)))
    monkeypatch.setattr(fr, "PLACED_BYTES", 2 * xyz.numel() * 4)                 # room for two placements
    kept.place(origin + 2.0, cpu)                                                 # a third: the oldest dropped
    assert kept.place(origin + 1e-9, cpu)[0] is other[0] and kept.place(origin, cpu)[0] is not xyz


def test_what_is_kept_is_bounded_and_a_served_copy_can_be_written(monkeypatch):
    layers = fr.PointLayers()
    image, depth = torch.rand(H, W, 3), torch.rand(H, W)
    one = image.numel() * 4 + depth.numel() * 4
    monkeypatch.setattr(fr, "ZBUFFER_BYTES", 2 * one)
    for k in range(3):
        layers.put(("view", k), image + k, depth + k)
    assert layers.get(("view", 0)) is None                     # the oldest dropped beyond two views
    got = layers.get(("view", 1))
    assert torch.equal(got[0], image + 1) and torch.equal(got[1], depth + 1)
    got[0].zero_()
    got[1].fill_(float("inf"))
    again = layers.get(("view", 1))
    assert torch.equal(again[0], image + 1) and torch.equal(again[1], depth + 1)
    monkeypatch.setattr(fr, "ZBUFFER_BYTES", one - 1)
    layers.put(("big", 0), image, depth)                       # larger than the whole bound: not kept
    assert layers.get(("big", 0)) is None
