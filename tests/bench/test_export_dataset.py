"""``bench/export_dataset.py --smoke`` keeps working: two variants of the street, two frames each at 32 x 18, one
single-job export against one merged export of both in all three formats; its table printed and its JSON written
(the 100-variant run is the benchmark's, not CI's)."""

import os

from bench_support import finite, run_smoke


def test_export_dataset_bench_measures_before_and_after(tmp_path, street, capsys):
    got = run_smoke("export_dataset", tmp_path, "--work", str(tmp_path / "work"))
    assert "after: one dataset, 3 formats (measured)" in capsys.readouterr().out
    assert got["label"] == "smoke" and got["formats"] == ["kitti", "coco", "openlabel"]
    assert got["before"]["calls"] == 1 and got["before"]["per_call_s"] > 0
    assert finite(got["before"]["per_call_s"], got["before"]["estimated_all_formats_s"], got["after"]["seconds"])
    assert got["after"]["seconds"] > 0 and got["after"]["rendered"] == 0     # the build rendered every frame
    assert got["after"]["frames"] == got["frames"] == 2 * got["variants"] and got["variants"] >= 1
    assert all(n > 0 for n in got["after"]["objects"].values())
    assert os.path.isfile(tmp_path / "work" / "dataset" / "manifest.json")
