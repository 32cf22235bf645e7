"""``bench/input_kinds.py --smoke`` keeps running: every synthetic input kind of issue 13 through the add-on's real
import operators in Blender, one row each with what happened: the well-formed kinds imported, the two ill-formed
ones refused with the file named. A process of its own: the bench imports bpy with a private user folder."""

import json

import pytest

from bench_support import run_smoke_process


def test_input_kinds_smoke(tmp_path):
    pytest.importorskip("bpy")
    r = run_smoke_process("input_kinds", tmp_path, timeout=300)
    rows = {row["kind"]: row for row in json.loads((tmp_path / "input_kinds.json").read_text())["rows"]}
    refused = {k for k, row in rows.items() if row["status"] == "refused"}
    assert len(rows) >= 10 and refused == {"VGGT camera-to-world under 'extrinsic'",
                                           "ushort properties mixed with float"}, rows
    assert all(row["status"] == "imported" for k, row in rows.items() if k not in refused), rows
    assert all(("vggt_c2w.npz" if "VGGT" in k else "mixed.ply") in rows[k]["what"] for k in refused)
