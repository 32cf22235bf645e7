"""``bench/proposals.py --smoke`` keeps working: one round on the street; its table printed and its JSON written, the
street's parked cars proposed when nothing labels them and nothing proposed when its cars are recorded objects."""

from bench_support import finite, run_smoke


def test_proposals_bench_runs(tmp_path, street, capsys):
    got = run_smoke("proposals", tmp_path)
    assert "box proposals on the street" in capsys.readouterr().out
    bare, recorded = got["cases"]["street, no labels"], got["cases"]["street, its cars recorded"]
    assert got["label"] == "smoke" and len(bare["total_s"]) == 1 and bare["points"] > 100_000
    assert finite(*bare["total_s"], bare["median_total_s"], recorded["median_total_s"])
    assert [p["class"] for p in bare["proposals"]] == ["car"] * 3 and recorded["proposals"] == []
