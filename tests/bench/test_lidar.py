"""``bench/lidar.py --smoke`` keeps working: its smallest sizes (one accuracy row, the speed of a 200 k-point street)
print both tables and write the JSON, in seconds."""

from bench_support import finite, run_smoke


def test_lidar_bench_smoke(tmp_path, capsys):
    got = run_smoke("lidar", tmp_path)
    out = capsys.readouterr().out
    assert "error against time" in out and "speed" in out
    assert got["smoke"] and len(got["accuracy"]) == 1 and [(s["model"], s["order"]) for s in got["speed"]] == [
        ("nuscenes-32", "frames"), ("nuscenes-32", "shuffled"), ("velodyne-64", "frames")]
    row = got["accuracy"][0]
    assert row["returns"] > 1000 and row["box_analytic"] > 500 and abs(row["box_count_error"]) < 0.1
    assert finite(row["seconds"], row["box_count_error"])
    assert all(s["returns"] > 0 and s["car_returns"] > 0 and s["sweep_median_s"] > 0 for s in got["speed"])
    assert all(finite(s["sweep_median_s"], s["first_call_s"]) for s in got["speed"])
