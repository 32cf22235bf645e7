"""``bench/train_throughput.py --smoke`` keeps working: the tiny model's step before and after issue 44 on the CPU,
timed, each row with the peak of its tracked allocations; the table's rows are in its JSON."""

import importlib.util
import json
import math
import os

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _bench():
    spec = importlib.util.spec_from_file_location("train_throughput", os.path.join(ROOT, "bench", "train_throughput.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_smoke_times_both_settings_and_estimates_their_peaks(tmp_path):
    _bench().main(["--smoke", "--out", str(tmp_path)])
    got = json.loads((tmp_path / "train_tiny_cpu.json").read_text())
    rows = got["rows"]
    assert [(r["setting"], r["batch"], r["checkpointing"], r["resolution"]) for r in rows] == \
        [("before", 1, True, "128x64"), ("after", 1, True, "128x64")]
    for r in rows:
        for k in ("step_s", "samples_per_s", "peak_gib"):
            assert math.isfinite(r[k]) and r[k] > 0, (k, r)
        assert r["loss_finite"] and r["peak_source"] == "tracked allocations"
    assert rows[1]["peak_gib"] < rows[0]["peak_gib"]
    assert got["env"]["trained_parameters"] > 0 and got["paper_schedule"]["128x64"]["best"]["setting"] == "after"
