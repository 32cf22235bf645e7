"""``python -m backend vary``, then the variants through ``batch`` (no --allow-outside: the list's data roots),
labelled, and ``contact-sheet``."""

import json
import os
import shutil

import cv2

from scpainter_blender.core import shapes
from scpainter_blender.core.output_layout import VariationLayout
from tests_support import run_backend, street_base_job


def test_vary_batch_and_contact_sheet(street, tmp_path):
    lib = tmp_path / "cars"
    lib.mkdir()
    shapes.save_as_amodal3r(str(lib / "blue.ply"), shapes.procedural_car_gaussians(count=4000, seed=7,
                                                                                  paint=(0.1, 0.3, 0.8)))
    base = tmp_path / "base" / "job.json"
    street_base_job(street, str(base))
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"variants": 5, "seed": 4, "resolution": [64, 36], "camera": {"shifts_m": [-2, 2]},
                                "cars": {"count": [1, 2]}}))
    out = tmp_path / "variants"
    code, events, err = run_backend("vary", str(base), "--out", str(out), "--spec", str(spec), "--library", str(lib),
                                    "--data-root", street.root)   # the recording the base reads: trusted
    assert code == 0, err
    assert [e["done"] for e in events if e["event"] == "progress" and e["stage"] == "vary"] == [1, 2, 3, 4, 5]
    done = events[-1]
    assert done["event"] == "done" and done["summary"]["variants"] == 5 and done["list"] == str(out / "variants.txt")
    manifest = json.loads((out / "variation.json").read_text())
    placed = [e for e in manifest["variants"] if e["outcome"] == "placed"]
    assert len(placed) >= 4

    assert done["base"] == str(base)
    code, events, err = run_backend("contact-sheet", str(out))   # nothing rendered yet: said so, tile by tile
    assert code == 0 and events[-1]["rendered"] == 0 and events[-1]["not_rendered"] == len(placed)

    # the variants lead into the street's cache and the run's folder: the list's data roots allow exactly that,
    # wherever the run's folder is moved to
    moved = tmp_path / "moved"
    shutil.move(str(out), str(moved))
    out = moved
    code, events, err = run_backend("batch", "--list", str(out / "variants.txt"), "--command", "render",
                                    "--device", "cpu")
    assert code == 0, err
    assert events[-1]["counts"] == {"ok": len(placed)}
    seen = 0
    for e in placed:
        layout = VariationLayout(str(out)).variant(int(e["id"][1:]))
        with open(layout.frame_labels(1)) as f:
            labels = json.load(f)
        names = {o["name"] for o in labels["objects"] if o["synthetic"]}
        assert names <= {c["name"] for c in e["cars"]}     # labelled: the variant's cars, by name
        seen += len(names)
        assert os.path.isfile(layout.labelled_preview(1))
    assert seen >= 1

    code, events, err = run_backend("contact-sheet", str(out))
    assert code == 0, err
    done = events[-1]
    assert done["rendered"] == len(placed) and done["rendered"] + done["unplaced"] == 5
    sheet = cv2.imread(done["path"])
    assert sheet is not None and sheet.shape[1] == 5 * (320 + 2)


def test_a_run_that_places_nothing_fails_and_says_why(street, tmp_path):
    lib = tmp_path / "cars"
    lib.mkdir()
    shapes.save_as_amodal3r(str(lib / "blue.ply"), shapes.procedural_car_gaussians(count=2000, seed=7))
    base = tmp_path / "base" / "job.json"
    street_base_job(street, str(base))
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"variants": 2, "cars": {"count": [12, 12]}, "placement": {"tries": 1}}))
    code, events, err = run_backend("vary", str(base), "--out", str(tmp_path / "v"), "--spec", str(spec),
                                    "--library", str(lib), "--data-root", street.root)
    assert code == 1, err
    warned = [e for e in events if e["event"] == "warning"]
    assert [w["code"] for w in warned] == ["variant_unplaced", "variant_unplaced", "variation"]
    assert "could not be placed: car" in warned[0]["message"] and "no variant" in warned[-1]["message"]
    assert events[-1]["event"] == "done" and events[-1]["summary"]["placed"] == 0
    code, events, err = run_backend("batch", "--list", str(tmp_path / "v" / "variants.txt"))
    assert code == 2 and "list no jobs" in events[-1]["message"] and "variation.json" in events[-1]["hint"]


def _main(*args):
    """(exit code, events) of ``python -m backend *args`` run in this process."""
    import contextlib
    import io

    from backend.__main__ import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = main([str(a) for a in args])
    return code, [json.loads(line) for line in out.getvalue().splitlines() if line.strip()]


def test_skip_bad_lists_the_library_files_left_out(street, tmp_path):
    """Issue 42: one unreadable library file aborted the whole run. With --skip-bad the run goes on with the good
    cars, the manifest's library_skipped names each bad file (a damaged one, one no car's shape) and why, and a
    warning event says so. In-process (``backend.__main__.main``)."""
    import numpy as np

    from scpainter_blender.core.splats import gaussians as splats, inria

    lib = tmp_path / "cars"
    lib.mkdir()
    shapes.save_as_amodal3r(str(lib / "blue.ply"), shapes.procedural_car_gaussians(count=2000, seed=7))
    (lib / "broken.spz").write_bytes(b"\x1f\x8b" + bytes(40))              # gzip magic, then nothing
    g = shapes.procedural_car_gaussians(count=2000, seed=1)                 # 9.2 x 5.8 m: no car
    k = (np.array([5.8, 9.2, 1.5]) / (g.means.max(0) - g.means.min(0))).astype(np.float32)
    inria.write_ply(lib / "wide.ply", splats.encode(splats.Gaussians(g.means * k, g.scales, g.quats, g.opacities,
                                                                     g.sh)))
    base = tmp_path / "base" / "job.json"
    street_base_job(street, str(base))
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"variants": 2, "seed": 1, "resolution": [32, 18], "cars": {"count": [1, 1]}}))
    # (without --skip-bad the first bad file's error stops the run, suggesting it: test_variants.py, in-process)
    code, events = _main("vary", base, "--out", tmp_path / "v", "--spec", spec, "--library", lib, "--skip-bad",
                         "--data-root", street.root)   # the recording the base reads: trusted
    assert code == 0, events[-1]
    manifest = json.loads((tmp_path / "v" / "variation.json").read_text())
    assert [a["name"] for a in manifest["library"]] == ["blue.ply"]
    skipped = manifest["library_skipped"]
    assert [s["file"] for s in skipped] == [str(lib / "broken.spz"), str(lib / "wide.ply")]
    assert all(s["reason"] and s["field"] for s in skipped) and "5.80 m wide" in skipped[1]["reason"]
    warned = [e["message"] for e in events if e["event"] == "warning" and e["code"] == "variation"]
    assert sum("left out (--skip-bad)" in w for w in warned) == 2
