"""``bench/fuzz_case_cost.py --smoke`` keeps working: on the fuzz's 2-asset job case, one round, it measures the case
as accepted, prints its table and writes its JSON (the many-asset cases themselves are the benchmark's, not CI's).
A process of its own: the bench sets its thread counts as a fuzz worker's."""

import json

from bench_support import finite, run_smoke_process


def test_fuzz_case_cost_bench_measures_the_two_asset_case(tmp_path):
    r = run_smoke_process("fuzz_case_cost", tmp_path, "--label", "smoke")
    assert "assets: two assets on one PLY" in r.stdout
    got = json.loads((tmp_path / "fuzz_case_cost.json").read_text())
    assert got["label"] == "smoke" and got["budget_cpu_s"] > 0
    (case,) = got["cases"]
    assert case["assets"] == 2 and case["description"] == "assets: two assets on one PLY"
    assert case["outcomes"] == ["accepted"] and len(case["cpu_s"]) == len(case["wall_s"]) == 1
    assert case["cpu_s"][0] > 0 and case["wall_s"][0] > 0 and finite(*case["cpu_s"], *case["wall_s"])
