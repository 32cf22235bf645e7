"""``bench/exr_sizes.py --smoke`` keeps running: every compression variant on two synthetic condition frames, each
row in the JSON with finite size, speed and error; lossless variants exact, half variants within half's rounding,
and the ZIP ones byte-identical to ``channels.write`` (the bench asserts it)."""

from bench_support import finite, load_bench, run_smoke


def test_exr_sizes_smoke(tmp_path):
    got = run_smoke("exr_sizes", tmp_path)
    variants = load_bench("exr_sizes").VARIANTS
    assert [r["variant"] for r in got["rows"]] == list(variants) and got["frames"] == 2
    for r in got["rows"]:
        assert finite(r["total_mb"], r["ratio_to_uncompressed"], r["write_ms_per_frame"], r["read_ms_per_frame"])
        errors = r["max_abs_error"].values()
        assert max(errors) < (1e-3 if variants[r["variant"]][1] else 1e-12), r
