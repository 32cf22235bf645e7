"""``bench/vary.py --smoke`` keeps working: four variants of the street, two of them rendered at 32 x 18 by one batch
worker; its table printed and its JSON written (the 1,000-variant run is the benchmark's, not CI's)."""

from bench_support import finite, run_smoke


def test_vary_bench_places_renders_and_reports(tmp_path, street, capsys):
    got = run_smoke("vary", tmp_path)
    printed = capsys.readouterr().out
    assert "variants/s" in printed and "idle %" in printed
    assert got["variants"] == 4 and got["placed"] + got["unplaced"] == 4 and got["placed"] >= 2
    assert got["vary_s"] > 0 and finite(got["vary_s"], got["render"]["wall_s"], got["render"]["jobs_per_s"])
    assert got["render"]["jobs"] == 2 and [w["failed"] for w in got["render"]["workers"]] == [0]
    assert all(finite(w["busy_s"], w["idle_s"]) for w in got["render"]["workers"])
