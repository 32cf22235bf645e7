"""``bench/render_writes.py --smoke`` keeps running: the street's drive with a parked car, two frames at 128 x 72,
the working tree's worker (its own process) timing the frame alone, the whole ``render`` and each write; its rows
and write components in the JSON with finite figures."""

from bench_support import finite, run_smoke


def test_render_writes_smoke(tmp_path, street):
    got = run_smoke("render_writes", tmp_path)
    (row,) = got["rows"]
    assert row["resolution"] == "128x72" and row["arm"] == "after" and got["baseline"] is None
    assert finite(row["frame_alone_ms"], row["render_ms"], row["render_cpu_ms"], row["render_over_alone"])
    assert row["frame_alone_ms"] > 0 and row["render_ms"] > 0
    comps = got["components"]["128x72"]
    assert finite(*(comps[k] for k in ("exr_s", "png_s", "png_level6_s", "labels_s", "exr_gil_wait_s")))
