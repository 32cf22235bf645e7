"""``bench/fuzz_inputs.py --smoke`` keeps running: the first two PLY fuzz cases on one worker, its table printed and
its JSON written with the summary row per kind and the valid job accepted. A process of its own: the bench sets its
thread counts as the fuzz's workers' before torch loads."""

import json

from bench_support import finite, run_smoke_process


def test_fuzz_inputs_bench_smoke(tmp_path):
    r = run_smoke_process("fuzz_inputs", tmp_path, "--quiet")
    assert "| input kind | cases | accepted |" in r.stdout
    got = json.loads((tmp_path / "fuzz_inputs.json").read_text())
    assert got["summary"]["ply"]["cases"] == got["summary"]["total"]["cases"] == 2
    assert sum(got["summary"]["ply"][k] for k in ("accepted", "clean", "unclear", "traceback", "hang", "escape",
                                                  "misread")) == 2
    assert got["base"]["job"]["outcome"] == "accepted" and finite(got["seconds"], got["base"]["job"]["seconds"])
