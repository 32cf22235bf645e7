"""``blender -c scpainter batch ...`` (``cli/batch.py``): scenes, job files and lists run headless, one summary;
also on a Ray cluster."""

import json
import os
import sys

import bpy

from tests.cli import cli_support as CS


def test_render_generate_and_batch_headless(addon, street, tmp_path, capsys, tiny_checkpoint):
    import hashlib

    cli = CS.cli(addon)
    blend = CS.street_blend(street, tmp_path)
    digest = hashlib.sha256(open(blend, "rb").read()).hexdigest()
    common = ["--device", "cpu", "--backend-python", sys.executable]
    code = cli.execute(["render", blend, *common])
    ev = CS.last_event(capsys)
    assert code == 0, ev
    out = tmp_path / "scpainter" / "Scene" / CS.CAM_DIR  # the default: //scpainter/<scene name>/<scene camera>/
    assert ev["output_dir"] == str(out) and ev["frames"] == 3 and len(list((out / "conditions").glob("*.exr"))) == 3
    # no checkpoint (none given, none in the preferences): the OpenCV inpainting baseline, said in the output
    code = cli.execute(["generate", blend, *common, "--inpaint", "navier-stokes", "--output", str(tmp_path / "gen")])
    ev = CS.last_event(capsys)
    assert code == 0, ev
    assert ev["model"] == "baseline" and "OpenCV Navier-Stokes inpainting" in ev["description"], ev
    assert os.path.isfile(ev["video"]) and ev["video"].startswith(str(tmp_path / "gen"))
    job = json.load(open(tmp_path / "gen" / CS.CAM_DIR / "job.json"))       # --output: the scene's output folder
    assert job["generate"] == {"inpaint": "navier-stokes"}                 # the scene's setting, for this run
    code = cli.execute(["generate", blend, *common, "--checkpoint", tiny_checkpoint, "--output",
                        str(tmp_path / "gen")])
    ev = CS.last_event(capsys)
    assert code == 0, ev
    assert ev["model"] == "scpainter" and ev["description"].startswith("SCPainter model")
    assert os.path.isfile(ev["video"]) and ev["video"].startswith(str(tmp_path / "gen"))
    # a batch over a scene, a missing scene and the job file the first run wrote: one summary, exit 1
    (tmp_path / "list.txt").write_text(f"scpainter/Scene/{CS.CAM_DIR}/job.json\n")
    # the job file reads the street's predictions from the cache, outside its folder: refused unless allowed
    code = cli.execute(["batch", "--list", str(tmp_path / "list.txt"), "--command", "render", *common])
    ev = CS.last_event(capsys)
    assert code == 1 and "scene.predictions" in ev["items"][0]["error"] and "--allow-outside" in ev["items"][0]["hint"]
    # ... or with the folders it reads named as data roots (passed on to the backend's batch)
    exported = json.load(open(out / "job.json"))
    roots = {os.path.dirname(os.path.join(out, p))
             for p in [exported["scene"]["predictions"], *(a["ply"] for a in exported["assets"])]}
    code = cli.execute(["batch", "--list", str(tmp_path / "list.txt"), "--command", "render", *common,
                        *[a for r in sorted(roots) for a in ("--data-root", r)]])
    ev = CS.last_event(capsys)
    assert code == 0 and ev["items"][0]["status"] == "ok", ev
    # ... or by the list itself (its data-root: lines, as vary writes them), beside a scene
    (tmp_path / "rooted.txt").write_text("".join(f"data-root: {r}\n" for r in sorted(roots))
                                         + f"scpainter/Scene/{CS.CAM_DIR}/job.json\n")
    code = cli.execute(["batch", blend, "--list", str(tmp_path / "rooted.txt"), "--command", "render", *common])
    ev = CS.last_event(capsys)
    assert code == 0 and [r["status"] for r in ev["items"]] == ["ok", "ok"], ev
    code = cli.execute(["batch", blend, str(tmp_path / "missing.blend"), "--list", str(tmp_path / "list.txt"),
                        "--command", "render", "--allow-outside", *common])
    ev = CS.last_event(capsys)
    assert code == 1 and ev["failed"] == 1 and [r["status"] for r in ev["items"]] == ["ok", "failed", "ok"]
    assert "missing.blend" in ev["items"][1]["error"] and ev["items"][2]["skipped"] == 3   # already rendered
    code = cli.execute(["batch", blend, str(tmp_path / "missing.blend"), "--shard", "0/2", "--command", "render",
                        *common])
    ev = CS.last_event(capsys)
    assert code == 0 and [r["item"] for r in ev["items"]] == [blend] and ev["shard"] == "0/2"
    # batch generate without a checkpoint (a fresh process has only the preferences, here emptied): the baseline for
    # the scene, and its job file (the same job: run once, its item repeats the scene's result) says so too
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.checkpoint_dir = ""
    code = cli.execute(["batch", blend, "--list", str(tmp_path / "list.txt"), "--command", "generate",
                        "--allow-outside", *common])
    ev = CS.last_event(capsys)
    assert code == 0, ev
    assert [(r["status"], r["model"], r["skipped"]) for r in ev["items"]] == [("ok", "baseline", False)] * 2
    assert ev["items"][1]["seconds"] == ev["items"][0]["seconds"]   # one run, both items its result
    assert hashlib.sha256(open(blend, "rb").read()).hexdigest() == digest   # the .blend is never written
    prefs.backend_python, prefs.device, prefs.checkpoint_dir = "", "AUTO", ""
    bpy.ops.wm.read_homefile(use_empty=True)


def test_batch_on_ray_exports_the_scenes_and_runs_every_job_as_one_ray_batch(addon, street, tmp_path, capsys,
                                                                              ray_cluster):
    import hashlib
    import shutil

    from tests_support import small_job

    cli = CS.cli(addon)
    os.makedirs(tmp_path / "a")
    a = CS.street_blend(street, tmp_path / "a")
    b = str(tmp_path / "b" / "street.blend")               # a second scene, its own output folder beside it
    shutil.copytree(tmp_path / "a", tmp_path / "b")         # the project folder: the .blend names car.ply as //car.ply
    digest = hashlib.sha256(open(a, "rb").read()).hexdigest()
    job = small_job(tmp_path / "job")                       # a job file: straight to the backend, as given
    common = ["--device", "cpu", "--backend-python", sys.executable, "--ray", ray_cluster]
    items = [a, str(tmp_path / "missing.blend"), job, b]
    code = cli.execute(["batch", *items, "--command", "render", *common])
    captured = capsys.readouterr()
    ev = json.loads([line for line in captured.out.splitlines() if line.startswith("{")][-1])
    assert code == 1 and ev["failed"] == 1, [r.get("error") for r in ev["items"]]  # the missing scene, and only it
    assert [r["item"] for r in ev["items"]] == items
    assert [r["status"] for r in ev["items"]] == ["ok", "failed", "ok", "ok"]
    assert "missing.blend" in ev["items"][1]["error"] and "worker" not in ev["items"][1]   # never sent to Ray
    for r, out, frames in ((ev["items"][0], tmp_path / "a" / "scpainter" / "Scene" / CS.CAM_DIR, 3),
                           (ev["items"][2], tmp_path / "job" / "out", 2),
                           (ev["items"][3], tmp_path / "b" / "scpainter" / "Scene" / CS.CAM_DIR, 3)):
        assert r["output_dir"] == str(out) and r["frames"] == frames and r["skipped"] == 0, r
        assert len(list((out / "conditions").glob("*.exr"))) == frames
        assert r["attempts"] == 1 and int(r["worker"].rsplit(":", 1)[1]) != os.getpid()   # in a Ray worker
    assert "scpainter: batch 3/3" in captured.err                               # the backend's progress, as it came
    assert ev["ray"] == ray_cluster and ev["jobs"] == 4 and ev["counts"] == {"ok": 3, "failed": 1}
    # again, generating: the conditions are up to date; without a checkpoint each scene's video is the baseline
    bpy.context.preferences.addons[addon].preferences.checkpoint_dir = ""
    code = cli.execute(["batch", a, b, "--command", "generate", *common])
    ev = CS.last_event(capsys)
    assert code == 0, ev
    assert [(r["status"], r["model"], r["skipped"]) for r in ev["items"]] == [("ok", "baseline", False)] * 2
    assert all(os.path.isfile(r["video"]) for r in ev["items"])
    # two scenes naming one output folder: the second is refused before anything runs; --shard is not for Ray
    code = cli.execute(["batch", a, a, "--command", "render", *common])
    ev = CS.last_event(capsys)
    assert code == 1 and [r["status"] for r in ev["items"]] == ["ok", "failed"]
    assert ev["items"][0]["skipped"] == 3 and ev["items"][1]["field"] == "scene.scpainter_output_dir"
    assert cli.execute(["batch", a, "--shard", "0/2", *common]) == 2 and CS.last_event(capsys)["field"] == "--shard"
    for option, value in (("--retries", "1000"), ("--cpus-per-job", "inf")):   # refused before any export
        assert cli.execute(["batch", a, option, value, *common]) == 2 and CS.last_event(capsys)["field"] == option
    assert hashlib.sha256(open(a, "rb").read()).hexdigest() == digest       # the .blend is never written
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.backend_python, prefs.device, prefs.checkpoint_dir = "", "AUTO", ""
    bpy.ops.wm.read_homefile(use_empty=True)
