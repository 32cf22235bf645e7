"""``bench/inputs_round3.py`` keeps running: every case of issue 42's inputs from the field, its table printed
and its JSON written, each case as the issue asks."""

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_inputs_round3_bench_runs(tmp_path):
    out = tmp_path / "bench.json"
    r = subprocess.run([sys.executable, os.path.join(ROOT, "bench", "inputs_round3.py"), "--label", "smoke",
                        "--json", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    got = json.loads(out.read_text())
    assert got["label"] == "smoke" and len(got["rows"]) == 10
    assert [row["case"] for row in got["rows"] if not row["ok"]] == [], r.stdout
    assert "10 of 10 cases as the issue asks" in r.stdout
