"""``bench/clean_points.py --smoke`` keeps running: its cleaning section on the street's first two frames, the
recorded and the 2 m left view, exact depth against VGGT-like depth with and without the depth-edge filter; every
row and its summary in the JSON with finite figures, and exact depth showing no wrong surface."""

from bench_support import finite, run_smoke


def test_clean_points_smoke(tmp_path, street):
    got = run_smoke("clean_points", tmp_path)
    assert got["frames"] == 2 and got["window"] == 1 and "sweep" not in got and "timing" not in got
    rows = got["cleaning"]
    assert sorted({r["shift_m"] for r in rows}) == [0.0, 2.0] and len(rows) == 6
    for r in rows:
        assert finite(r["psnr_covered_db"], r["hole_fraction"], r["nearer_fraction"], r["farther_fraction"],
                      r["frame_ms"], r["cleaning_ms_per_frame"]) and r["points"] > 100_000
    exact = [r for r in rows if r["setting"] == "exact depth, no filter"]
    assert all(r["nearer_fraction"] == r["farther_fraction"] == 0 for r in exact)
    assert [s["setting"] for s in got["cleaning_summary"]] == list(dict.fromkeys(r["setting"] for r in rows))
