"""``bench/ply_load.py --smoke`` keeps running: a 2,000-Gaussian INRIA PLY through our reader and Open3D (and
plyfile where installed); every loader's row in the JSON with finite times, and the loaders' values agree."""

from bench_support import finite, run_smoke


def test_ply_load_smoke(tmp_path):
    got = run_smoke("ply_load", tmp_path)
    assert got["gaussians"] == 2000 and got["baseline"] is None
    assert {"ours read", "ours load", "open3d t.io"} <= set(got["loaders"])
    assert all(finite(r["median_s"], r["best_s"]) and r["median_s"] > 0 for r in got["loaders"].values())
    assert finite(got["ours_load_over_fastest"]) and got["checks"]["open3d raw == read"] is True
    if "plyfile raw == read" in got["checks"]:
        assert got["checks"]["plyfile raw == read"] and got["checks"]["plyfile + decode ~ load (max abs diff)"] < 1e-5
