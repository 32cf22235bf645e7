"""``bench/proposals.py`` keeps working: one round on the street; its table printed and its JSON written, the
street's parked cars proposed when nothing labels them and nothing proposed when its cars are recorded objects."""

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_proposals_bench_runs(tmp_path, street):
    out = tmp_path / "bench.json"
    r = subprocess.run([sys.executable, os.path.join(ROOT, "bench", "proposals.py"), "--rounds", "1", "--label",
                        "smoke", "--json", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "box proposals on the street" in r.stdout
    got = json.loads(out.read_text())
    bare, recorded = got["cases"]["street, no labels"], got["cases"]["street, its cars recorded"]
    assert got["label"] == "smoke" and len(bare["total_s"]) == 1 and bare["points"] > 100_000
    assert [p["class"] for p in bare["proposals"]] == ["car"] * 3 and recorded["proposals"] == []
