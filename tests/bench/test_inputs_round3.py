"""``bench/inputs_round3.py --smoke`` keeps running: every case of issue 42's inputs from the field, its table
printed and its JSON written, each case as the issue asks."""

from bench_support import finite, run_smoke


def test_inputs_round3_bench_runs(tmp_path, capsys):
    got = run_smoke("inputs_round3", tmp_path, "--label", "smoke")
    out = capsys.readouterr().out
    assert got["label"] == "smoke" and len(got["rows"]) == 10
    assert [row["case"] for row in got["rows"] if not row["ok"]] == [], out
    assert "10 of 10 cases as the issue asks" in out
