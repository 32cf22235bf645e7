"""``bench/fuzz_inputs.py --smoke`` keeps running: the first two PLY fuzz cases on one worker, its table printed and
its JSON written with the summary row per kind and the valid job accepted. A process of its own: the bench sets its
thread counts as the fuzz's workers' before torch loads."""

import json
import os
import subprocess
import sys

from bench_support import ROOT, finite


def test_fuzz_inputs_bench_smoke(tmp_path):
    r = subprocess.run([sys.executable, os.path.join(ROOT, "bench", "fuzz_inputs.py"), "--smoke", "--quiet",
                        "--out", str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "| input kind | cases | accepted |" in r.stdout
    got = json.loads((tmp_path / "fuzz_inputs.json").read_text())
    assert got["summary"]["ply"]["cases"] == got["summary"]["total"]["cases"] == 2
    assert sum(got["summary"]["ply"][k] for k in ("accepted", "clean", "unclear", "traceback", "hang", "escape",
                                                  "misread")) == 2
    assert got["base"]["job"]["outcome"] == "accepted" and finite(got["seconds"], got["base"]["job"]["seconds"])
