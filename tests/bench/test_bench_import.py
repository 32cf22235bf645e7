"""``bench/bench_import.py --smoke`` keeps running: two frames of synthetic VGGT predictions through the real import
operator in Blender, a row with the points kept and finite phase times. A process of its own: the bench imports bpy
with a private user folder and installs the add-on there. (Before issue 44 it had rotted: its random world points
no longer passed the import's check against the depth, and its per-pixel random depth left no point after
cleaning.)"""

import json

import pytest

from bench_support import finite, run_smoke_process


def test_bench_import_smoke(tmp_path):
    pytest.importorskip("bpy")
    r = run_smoke_process("bench_import", tmp_path, timeout=300)
    (row,) = json.loads((tmp_path / "import.json").read_text())["rows"]
    assert row["frames"] == 2 and row["percentile"] == 50.0
    assert 0.3 * 2 * 518 * 294 < row["points"] <= 0.5 * 2 * 518 * 294 + 1   # the confidence median keeps half
    assert finite(row["operator_s"], row["load_s"], row["unproject_s"], row["points_per_s"]) and row["points_per_s"] > 0
