"""``bench/sampler_stability.py --smoke`` keeps running: σ_max and σ_min at guidance 1 and 15, every path's row in
the JSON; our path (float32 math, only the UNet's input and output rounded) finite and close to float64 in every
dtype."""

from bench_support import finite, run_smoke


def test_sampler_stability_smoke(tmp_path):
    rows = run_smoke("sampler_stability", tmp_path)
    paths = {f"{a}-{d}" for a in ("all", "ours") for d in ("fp16", "bf16", "fp32")}
    assert {r["path"] for r in rows} == paths and len(rows) == 2 * 2 * len(paths)
    ours = [r for r in rows if r["path"].startswith("ours")]
    assert all(r["finite"] and finite(r["max_abs_err_input"], r["max_abs_err_x0"]) for r in ours)
    assert all(r["max_abs_err_x0"] < 0.5 for r in ours)   # x_0 ~ N(0, 1); bf16 at guidance 15: ~0.2
