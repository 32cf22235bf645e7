"""``bench/vary.py`` keeps working: four variants of the street, two of them rendered at 32 x 18 by one batch
worker; its table printed and its JSON written (the 1,000-variant run is the benchmark's, not CI's)."""

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_vary_bench_places_renders_and_reports(tmp_path, street):
    out = tmp_path / "bench.json"
    r = subprocess.run([sys.executable, os.path.join(ROOT, "bench", "vary.py"), "--variants", "4", "--workers", "1",
                        "--resolution", "32x18", "--render-variants", "2", "--out", str(tmp_path / "work"),
                        "--json", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "variants/s" in r.stdout and "idle %" in r.stdout
    got = json.loads(out.read_text())
    assert got["variants"] == 4 and got["placed"] + got["unplaced"] == 4 and got["placed"] >= 2
    assert got["vary_s"] > 0
    assert got["render"]["jobs"] == 2 and [w["failed"] for w in got["render"]["workers"]] == [0]
