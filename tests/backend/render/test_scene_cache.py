"""scene_cache: what is kept is served again only for the same file, unchanged: a predictions file replaced, or
written again in place with the same size and its old mtime put back, is read again; and the cleaned cloud a job
places at its own origin is the one it would have made itself (``frames.KeptCloud``)."""

import os

import numpy as np

from backend.render import frames as fr
from backend.render import scene_cache
from scpainter_blender.core.geometry import point_cloud


def _loads(path, settings, made):
    return scene_cache.points(str(path), settings, lambda: made.append(1) or len(made))


def test_a_file_changed_in_place_with_its_old_size_and_mtime_is_read_again(tmp_path):
    path = tmp_path / "predictions.npz"
    path.write_bytes(b"a" * 64)
    made = []
    with scene_cache.shared("test", "an earlier load"):
        assert _loads(path, {"c": 1}, made) == 1
        assert _loads(path, {"c": 1}, made) == 1 and len(made) == 1     # the same file and settings: kept
        assert _loads(path, {"c": 2}, made) == 2                        # other settings: made again
        st = os.stat(path)
        with open(path, "r+b") as f:                                    # new content, same size ...
            f.write(b"b" * 64)
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))              # ... and its old mtime put back
        assert os.stat(path).st_size == st.st_size and os.stat(path).st_mtime_ns == st.st_mtime_ns
        assert _loads(path, {"c": 1}, made) == 3                        # read again (its ctime moved)
        new = tmp_path / "new.npz"
        new.write_bytes(b"c" * 64)
        os.utime(new, ns=(st.st_atime_ns, st.st_mtime_ns))
        os.replace(new, path)                                           # replaced by another file
        assert _loads(path, {"c": 1}, made) == 4
    assert _loads(path, {"c": 1}, made) == 5  # outside the block nothing is kept


def test_a_kept_cloud_placed_at_an_origin_is_the_cloud_placed_by_hand():
    rng = np.random.default_rng(0)
    n = 3000
    frame = np.repeat(np.arange(3), n // 3)
    offsets = np.array([0, n // 3, 2 * n // 3, n])
    cloud = point_cloud.FramePoints(positions=rng.normal(0, 50, (n, 3)) + [1e4, -2e3, 30.0],
                                    colors=rng.uniform(0, 1, (n, 3)).astype(np.float32), frame=frame, offsets=offsets)
    keep = rng.uniform(size=n) > 0.2
    kept = fr.KeptCloud.of(cloud, keep, {"removed_points": 7, "cloud_s": 0.1})
    assert kept.removed_points == 7 and kept.stats == {"cloud_s": 0.1}
    for origin in (np.zeros(3), np.array([1e4 + 0.123456789, -2e3 + 7.7, 31.3])):
        xyz = (cloud.positions[keep] - origin).astype(np.float32)
        slices, boxes = fr.frame_index(frame[keep], xyz)
        assert kept.slices == slices
        got = kept.boxes(origin)
        assert set(got) == set(boxes) and all(np.array_equal(got[f], boxes[f]) for f in boxes)
    shuffled = fr.KeptCloud.of(point_cloud.FramePoints(cloud.positions, cloud.colors, frame[::-1].copy(), offsets), keep, {
        "removed_points": 0})
    assert shuffled.slices is None and shuffled.boxes(np.zeros(3)) is None  # frames not contiguous: none
