"""``bench/fuzz_case_cost.py`` keeps working: on the fuzz's 2-asset job case, one round, it measures the case as
accepted, prints its table and writes its JSON (the many-asset cases themselves are the benchmark's, not CI's)."""

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_fuzz_case_cost_bench_measures_the_two_asset_case(tmp_path):
    out = tmp_path / "cost.json"
    r = subprocess.run([sys.executable, os.path.join(ROOT, "bench", "fuzz_case_cost.py"), "--cases", "2",
                        "--rounds", "1", "--label", "smoke", "--out", str(out)], cwd=ROOT, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "assets: two assets on one PLY" in r.stdout
    got = json.loads(out.read_text())
    assert got["label"] == "smoke" and got["budget_cpu_s"] > 0
    (case,) = got["cases"]
    assert case["assets"] == 2 and case["description"] == "assets: two assets on one PLY"
    assert case["outcomes"] == ["accepted"] and len(case["cpu_s"]) == len(case["wall_s"]) == 1
    assert case["cpu_s"][0] > 0 and case["wall_s"][0] > 0
