"""``bench/baseline_inpaint.py --smoke`` keeps running: the street exported as a clip, its four shifted evaluation
tasks rendered through the real ``render`` code at 64 x 36 (2 frames), each inpainting method against the naive
output; every row in the JSON with finite figures, and inpainting better than black holes."""

from bench_support import finite, run_smoke


def test_baseline_inpaint_smoke(tmp_path, street):
    got = run_smoke("baseline_inpaint", tmp_path)
    rows = {r["output"]: r for r in got["rows"]}
    assert got["resolution"] == [64, 36] and got["frames"] == 2 and len(got["shifts"]) == 4
    assert "naive (holes black)" in rows and len(rows) >= 3
    for r in rows.values():
        assert finite(r["psnr"], r["psnr_holes"], r["warping_error"], r["ms_per_frame"])
    assert all(r["psnr_holes"] > rows["naive (holes black)"]["psnr_holes"] for k, r in rows.items() if "r=3" in k)
    assert finite(got["hole_fraction"], got["ground_truth_warping_error"])
