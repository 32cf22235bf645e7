"""``bench/bench_gaussians.py`` keeps working: ``--smoke`` imports one 2 000-Gaussian car through the real operator
and evaluates both previews, in a process of its own (Blender's user folder is set before bpy is imported)."""

import json
import math
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_bench_gaussians_smoke(tmp_path):
    r = subprocess.run([sys.executable, os.path.join(ROOT, "bench", "bench_gaussians.py"), "--smoke", "--out",
                        str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "ellipsoids_eval_s" in r.stdout
    got = json.loads((tmp_path / "gaussians.json").read_text())
    (row,) = got["rows"]
    assert row["gaussians"] == 2000 and row["file_mb"] > 0.05 and got["machine"]["blender"]
    for key in ("import_s", "sprites_eval_s", "ellipsoids_eval_s"):
        assert math.isfinite(row[key]) and row[key] > 0, key
