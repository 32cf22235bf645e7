"""``bench/artist_loop.py --smoke`` keeps running: the artist's four clicks through the real operators in Blender
(two synthetic frames, a 2,000-Gaussian car), each click's row in the JSON with finite seconds, the unchanged click
rendering nothing. Marked slow (run with --run-slow): the first click starts the warm backend, ~20 s of CPU and
35-45 s of wall on the shared 2-core machine, over the suite's budget; a process of its own (bpy with a private user
folder)."""

import json

import pytest

from bench_support import finite, run_smoke_process


@pytest.mark.slow
def test_artist_loop_smoke(tmp_path):
    pytest.importorskip("bpy")
    r = run_smoke_process("artist_loop", tmp_path)
    rows = {row["click"]: row for row in json.loads((tmp_path / "artist_loop.json").read_text())["rows"]}
    assert list(rows) == ["cold", "unchanged", "moved", "moved back"] and {r["arm"] for r in rows.values()} == {"now"}
    assert all(finite(r["seconds"], r["overhead_s"]) for r in rows.values())
    assert rows["cold"]["frames_rendered"] == 2 and rows["unchanged"]["frames_rendered"] == 0
