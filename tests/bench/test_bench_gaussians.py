"""``bench/bench_gaussians.py`` keeps working: ``--smoke`` imports one 2 000-Gaussian car through the real operator
and evaluates both previews, in a process of its own (Blender's user folder is set before bpy is imported)."""

import json
import math

from bench_support import run_smoke_process


def test_bench_gaussians_smoke(tmp_path):
    r = run_smoke_process("bench_gaussians", tmp_path, timeout=300)
    assert "ellipsoids_eval_s" in r.stdout
    got = json.loads((tmp_path / "gaussians.json").read_text())
    (row,) = got["rows"]
    assert row["gaussians"] == 2000 and row["file_mb"] > 0.05 and got["machine"]["blender"]
    for key in ("import_s", "sprites_eval_s", "ellipsoids_eval_s"):
        assert math.isfinite(row[key]) and row[key] > 0, key
