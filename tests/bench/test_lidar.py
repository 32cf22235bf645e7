"""``bench/lidar.py`` keeps working: its smallest sizes (one accuracy row, the speed of a 200 k-point street)
print both tables and write the JSON, in seconds."""

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_lidar_bench_smoke(tmp_path):
    out = tmp_path / "lidar.json"
    r = subprocess.run([sys.executable, os.path.join(ROOT, "bench", "lidar.py"), "--smoke", "--repeats", "1",
                        "--json", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "error against time" in r.stdout and "speed" in r.stdout
    got = json.loads(out.read_text())
    assert got["smoke"] and len(got["accuracy"]) == 1 and [(s["model"], s["order"]) for s in got["speed"]] == [
        ("nuscenes-32", "frames"), ("nuscenes-32", "shuffled"), ("velodyne-64", "frames")]
    row = got["accuracy"][0]
    assert row["returns"] > 1000 and row["box_analytic"] > 500 and abs(row["box_count_error"]) < 0.1
    assert all(s["returns"] > 0 and s["car_returns"] > 0 and s["sweep_median_s"] > 0 for s in got["speed"])
