"""``bench/render.py`` keeps working: ``--smoke`` (256 x 144, thousands of points and Gaussians, CPU) runs the
speed, accuracy and choice sections in-process and writes their JSON. The speed row runs the code the CUDA run
used to meet first on a GPU (the Gaussian pass's layers unpacked and compared, as against gsplat; the inputs gsplat
would get, shape-checked; the CPU-vs-device point winners), so a change in the rasterizer's return values fails
here, not after a GPU's set-up."""

import importlib.util
import json
import math
import os

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def load_bench(name):
    spec = importlib.util.spec_from_file_location(f"bench_{name}", os.path.join(ROOT, "bench", f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def finite(*values):
    return all(isinstance(v, (int, float)) and math.isfinite(v) for v in values)


def test_render_bench_smoke(tmp_path, capsys):
    from backend.render import raster_choice

    bench = load_bench("render")
    assert bench.main(["--smoke", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "compositor choice" in printed and "error against run time" in printed
    got = json.loads((tmp_path / "render_cpu_smoke.json").read_text())
    assert got["smoke"] and got["size"] == list(bench.SMOKE_SIZE)
    (speed,) = got["speed"]
    assert speed["device"] == "cpu" and speed["gaussians"] == bench.SIZES["smoke"]["speed"][1]
    assert finite(speed["frame_ms"], speed["frame_with_download_ms"], speed["points_ms"], speed["gaussians_ms"])
    assert speed["asset_pixels"] > 100 and speed["points_winner_mismatch_cpu_vs_device"] == 0
    # the tile kernel against the pair rasterizer, through the comparison the gsplat row uses
    assert speed["pairs_mean_abs_diff_rgb"] <= 1e-6 and speed["pairs_max_abs_diff_asset_mask"] <= 1e-5
    settings = [r["setting"] for r in got["accuracy"]]
    assert settings == ["default (raster_choice)", "tile 8", "tile 16", "tile 32", "pair rasterizer (the reference)"]
    for r in got["accuracy"]:
        assert finite(r["frame_ms"], r["max_abs_err_I"], r["mean_abs_err_I"]) and r["max_abs_err_I"] <= 1e-5, r
    # the choice table: per Gaussian count the pairs and three tile sizes, one pick (the CPU default), one fastest
    counts = bench.SIZES["smoke"]["choice"]
    assert sorted({r["gaussians"] for r in got["choice"]}) == sorted(counts)
    for n in counts:
        rows = [r for r in got["choice"] if r["gaussians"] == n]
        assert [(r["method"], r["tile"]) for r in rows] == [("pairs", None), ("tiles", 4), ("tiles", 8),
                                                            ("tiles", 16)]
        assert [(r["method"], r["tile"]) for r in rows if r["chosen"]] == [("tiles", raster_choice.TILE_CPU)]
        assert sum(r["fastest"] for r in rows) == 1
        for r in rows:
            assert finite(r["gaussians_ms"], r["max_abs_err_rgb"], r["max_abs_err_asset_mask"]), r
            assert r["max_abs_err_rgb"] <= 1e-5 and r["instance_differing_pixels"] == 0, r
