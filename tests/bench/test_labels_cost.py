"""``bench/labels_cost.py`` keeps running: its smoke size (a 128 x 72 frame of three small cars and 20 k points, in
this process) prints its table and writes its JSON, the amodal counts of the kernel's walk equal to the render per
car's (the full before/after run against main is the benchmark's, not CI's)."""

import importlib.util
import json
import math
import os

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_labels_cost_smoke_prints_and_saves_its_rows(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("labels_cost", os.path.join(ROOT, "bench", "labels_cost.py"))
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--smoke", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "labels %" in printed and "amodal counts equal before/after: True" in printed
    got = json.loads((tmp_path / "labels_cost.json").read_text())
    assert got["amodal_equal"] is True and got["batch"] is None
    for name in ("before", "after"):
        row = got["frame"][name]
        for k in ("render_ms", "amodal_ms", "writes_ms", "labels_ms", "total_ms", "alone_total_ms", "labels_share",
                  "ratio_to_alone"):
            assert math.isfinite(row[k]) and (row[k] > 0 or k in ("amodal_ms", "labels_share")), (name, k, row)
        assert len(row["amodal"]) == 3 and sum(row["amodal"]) > 0
    assert got["frame"]["before"]["amodal_method"] == "second_render"
    assert got["frame"]["after"]["amodal_method"] == "tree"
    assert set(got["targets"]) == {"labels_share_le_0.10", "ratio_to_alone_le_1.3"}


def test_labels_cost_refuses_to_compare_the_code_with_itself(capsys):
    """On main, or once a branch is merged, the default before (merge-base main HEAD) is HEAD: the run compared the
    code with itself and printed a before/after table of noise. A before whose code is HEAD's is refused at once
    (exit 2 naming the option), before anything is built."""
    import pytest

    spec = importlib.util.spec_from_file_location("labels_cost", os.path.join(ROOT, "bench", "labels_cost.py"))
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    with pytest.raises(SystemExit) as stop:
        bench.main(["--before", "HEAD", "--variants", "0"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "--before HEAD" in err and "compare the code with itself" in err and "--before-tree" in err
    commit, problem = bench.before_revision("no-such-revision-here")
    assert commit is None and "no such commit" in problem
