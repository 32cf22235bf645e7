"""``bench/export_dataset.py`` keeps working: two variants of the street, two frames each at 32 x 18, one
single-job export against one merged export of both in all three formats; its table printed and its JSON written
(the 100-variant run is the benchmark's, not CI's)."""

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_export_dataset_bench_measures_before_and_after(tmp_path, street):
    out = tmp_path / "bench.json"
    r = subprocess.run([sys.executable, os.path.join(ROOT, "bench", "export_dataset.py"), "--variants", "2",
                        "--frames", "2", "--resolution", "32x18", "--before-calls", "1", "--label", "smoke",
                        "--out", str(tmp_path / "work"), "--json", str(out)],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "after: one dataset, 3 formats (measured)" in r.stdout
    got = json.loads(out.read_text())
    assert got["label"] == "smoke" and got["formats"] == ["kitti", "coco", "openlabel"]
    assert got["before"]["calls"] == 1 and got["before"]["per_call_s"] > 0
    assert got["after"]["seconds"] > 0 and got["after"]["rendered"] == 0     # the build rendered every frame
    assert got["after"]["frames"] == got["frames"] == 2 * got["variants"] and got["variants"] >= 1
    assert all(n > 0 for n in got["after"]["objects"].values())
    assert os.path.isfile(tmp_path / "work" / "dataset" / "manifest.json")
