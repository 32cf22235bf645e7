"""``bench/mesh_assets.py --smoke`` keeps running: the procedural car converted to 2,000 Gaussians at the default σ
factor and one other, rendered from two views at 128 x 72 against its own silhouette; each row in the JSON with
finite figures and a mask that matches the silhouette."""

from bench_support import finite, load_bench, run_smoke


def test_mesh_assets_smoke(tmp_path):
    got = run_smoke("mesh_assets", tmp_path)
    default = load_bench("mesh_assets").ma.SIGMA_FACTOR
    assert sorted(r["factor"] for r in got["rows"]) == sorted([default, 0.7]) and got["views"] == 2
    for r in got["rows"]:
        assert r["mesh"] == "procedural car" and r["res"] == "128x72" and r["count"] == 2000
        assert finite(r["iou"], r["iou_min"], r["mean_abs"], r["sigma_px"], r["convert_s"], r["render_s"])
        assert r["iou"] > 0.7
