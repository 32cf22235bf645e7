"""``bench/ground_plane.py --smoke`` keeps running: one seed of the core fit and open3d's on a tenth of the street's
ground candidates; both rows in the JSON with finite figures, both planes the street's road."""

from bench_support import finite, run_smoke


def test_ground_plane_smoke(tmp_path, street):
    got = run_smoke("ground_plane", tmp_path)
    assert [r["fit"] for r in got["rows"]] == ["core numpy", "open3d"] and got["iterations"] == 200
    for r in got["rows"]:
        assert finite(r["seconds"], r["normal_error_deg"], r["scale_rel_error"]) and r["inliers"] > 1000
        assert r["normal_error_deg"] < 0.5 and r["scale_rel_error"] < 1e-2
    assert finite(got["median_seconds"]["core"], got["median_seconds"]["open3d"], got["threshold"])
