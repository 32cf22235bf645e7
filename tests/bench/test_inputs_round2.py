"""``bench/inputs_round2.py --smoke`` keeps running: its first glTF case through ``backend mesh-asset`` and its first
clip case through ``train.clip``, both controls read correctly; the table printed and the JSON written with its
bounds and summary."""

from bench_support import finite, run_smoke


def test_inputs_round2_smoke(tmp_path, capsys):
    got = run_smoke("inputs_round2", tmp_path)
    rows = {r["class"]: r for r in got["rows"]}
    assert set(rows) == {"glTF", "splats", "clips"} and rows["splats"]["outcome"] == "skipped"
    assert rows["glTF"]["outcome"] == rows["clips"]["outcome"] == "correct" and rows["glTF"]["ok"] and rows["clips"]["ok"]
    assert got["summary"] == {"correct": 2, "skipped": 1} and finite(got["seconds"], *got["bounds"].values())
    assert "2 of 3 as the issue asks" in capsys.readouterr().out
