"""backend/lidar/sweep.py: nuScenes' num_lidar_pts rule (strictly inside), the .pcd.bin rows written atomically and
read back, and a truncated file refused by name."""

import os

import numpy as np
import pytest

from backend.lidar import sweep as sw
from scpainter_blender.core import errors


def _sweep(points, lidar_to_world=None):
    n = len(points)
    return sw.Sweep(points=np.asarray(points, np.float32), range_m=np.linalg.norm(points, axis=1).astype(np.float32),
                    intensity=np.arange(n, dtype=np.float32), ring=np.arange(n, dtype=np.int32) % 32,
                    column=np.zeros(n, np.int32), source=np.zeros(n, np.int32),
                    lidar_to_world=np.eye(4) if lidar_to_world is None else lidar_to_world, model="nuscenes-32")


def test_counts_are_the_returns_strictly_inside_each_box_in_the_world():
    T = np.eye(4)
    T[:3, 3] = (100.0, 200.0, 1.0)  # the sensor in the world
    s = _sweep([[0, 10, 0], [0.5, 10, 0], [1.0, 10, 0], [0, 10, 0.99], [5, 5, 5]], T)
    box = np.eye(4)
    box[:3, 3] = (100.0, 210.0, 1.0)
    turned = box.copy()
    turned[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # width along world y now
    got = sw.counts(s, [(box, (2.0, 4.0, 2.0)), (turned, (2.0, 4.0, 2.0)), (box, (0.1, 0.1, 0.1))])
    # x = 1.0 lies on the first box's face: not strictly inside; the turned box is 4 m wide along x
    assert list(got) == [3, 4, 1] and got.dtype == np.int64
    assert list(s.counts([])) == [] and list(sw.counts(_sweep(np.zeros((0, 3))), [(box, (1, 1, 1))])) == [0]


def test_pcd_bin_round_trip_is_nuscenes_layout(tmp_path):
    s = _sweep([[1.5, 2.5, -0.5], [3, 4, 5]])
    path = tmp_path / "sweep_000001.pcd.bin"
    sw.write_pcd_bin(path, s)
    assert os.path.getsize(path) == 2 * 5 * 4 and os.listdir(tmp_path) == [path.name]  # no temporary left
    rows = np.fromfile(path, "<f4").reshape(-1, 5)  # what nuScenes' LidarPointCloud.from_file reads
    assert np.array_equal(rows, sw.read_pcd_bin(path))
    assert np.array_equal(rows[:, :3], s.points) and list(rows[:, 3]) == [0, 1] and list(rows[:, 4]) == [0, 1]


def test_a_file_that_is_not_whole_rows_is_an_input_error(tmp_path):
    path = tmp_path / "bad.pcd.bin"
    path.write_bytes(b"\0" * 24)
    with pytest.raises(errors.InputError) as e:
        sw.read_pcd_bin(path)
    assert e.value.path == str(path) and "24 bytes" in e.value.message


def test_a_fifo_or_a_folder_is_refused_at_once_never_waited_on(tmp_path):
    import os

    os.mkfifo(tmp_path / "fifo.pcd.bin")
    (tmp_path / "dir.pcd.bin").mkdir()
    for name in ("fifo.pcd.bin", "dir.pcd.bin"):
        with pytest.raises(errors.InputError) as e:
            sw.read_pcd_bin(tmp_path / name)
        assert e.value.path == str(tmp_path / name)


def test_world_points_apply_the_pose():
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = (1e5, -1e5, 2.0)
    got = _sweep([[1.0, 0, 0]], T).world_points()
    assert got.dtype == np.float64 and np.allclose(got, [[1e5, -1e5 + 1, 2.0]], atol=1e-9)
