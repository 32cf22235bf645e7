"""The tests mirror the code (docs/design.md §2): a shipped module ``<package path>/<module>.py`` is tested in
``tests/<package path>/test_<module>.py``, and every test file is either such a mirror, an aspect of one, or a
cross-cutting test listed here with what it checks.

The mirror of a module (``mirrored_test``): ``scpainter_blender/`` is dropped (``scpainter_blender/core/vggt/npz.py``
→ ``tests/core/vggt/test_npz.py``, ``scpainter_blender/runs/client.py`` → ``tests/runs/test_client.py``); the
other shipped folders keep their name (``backend/mesh/gltf.py`` → ``tests/backend/mesh/test_gltf.py``,
``operators/job.py`` → ``tests/operators/test_job.py``); a package's ``__init__.py`` is ``test_init.py`` in its
folder's mirror, a ``__main__.py`` is ``test_main.py`` (the root's ``__init__.py``: ``tests/test_init.py``).

The shipped modules (``shipped_modules``) are the git-tracked ``.py`` files of ``tests_support.SHIPPED``, less the
``__init__.py`` files that hold nothing but a docstring (a folder made a package has no behaviour to test).
``scpainter_blender/street/`` is counted: it is not in the extension zip, but it is code this repository ships and
its tests and demo stand on (the street's answers are every scene test's ground truth), so it is held to the same
layout.

A second test file of one module is named ``test_<module>_<aspect>.py`` beside the mirror
(``tests/backend/train/test_clip_video.py``: clip.py's frames given as a video). A module without a mirrored test is
in ``UNMIRRORED`` with where it is tested or why it needs no test of its own; the list cannot go stale: an entry for a
module that is gone, or that has its mirror now, fails, and an entry "tested by tests/X" must name a test file that
exists and mentions the module. Modelled on diffusers' ``utils/check_test_missing``.

``python tests/test_layout.py [COMMIT]`` prints the share of shipped modules with a mirrored test (at COMMIT: the
modules and tests tracked there).
"""

import ast
import os
import re
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))
from tests_support import SHIPPED  # noqa: E402

# -- modules without a test file of their mirrored name ------------------------------------------------------------
# "tested by tests/…: what" names the test file that tests the module (checked: it exists and names the module);
# "exercised by tests/…: how" one that runs it without naming it (checked: it exists);
# "pending: moved by the merge" marks a module whose tests other branches are moving or rewriting now (their test
# files are in PENDING_TESTS): the merge places them, and then drops the entry (or the test below says so).
UNMIRRORED = {
    # -- the add-on's top
    "__init__.py": "tested by tests/scene/test_extension.py: register()/unregister() of the installed zip, twice over",
    "operators/__init__.py": "no behaviour of its own: the operator classes register() walks (all registered in "
                             "tests/scene/test_extension.py)",
    "panels/__init__.py": "no behaviour of its own: the panel classes register() walks (all registered in "
                          "tests/scene/test_extension.py)",
    "scpainter_blender/runs/warm_process.py": "tested by tests/backend/test_serve.py: WarmBackend and WarmRun against "
                                              "a real serve process",
    "scpainter_blender/runs/all_cameras.py": "tested by tests/runs/test_camera_run.py: AllCameras over every camera "
                                             "path",
    # -- backend/commands/: thin handlers (check the arguments, call the work's module, emit its events), each run
    # end to end by the tests of the command it hands to; the registry and the shared options in test_init.py
    "backend/commands/batch.py": "exercised by tests/backend/batch/test_command.py: python -m backend batch",
    "backend/commands/contact_sheet.py": "exercised by tests/backend/vary/test_command.py: python -m backend "
                                         "contact-sheet",
    "backend/commands/evaluate.py": "exercised by tests/backend/evaluate/test_protocol.py: python -m backend evaluate",
    "backend/commands/export.py": "exercised by tests/backend/export/test_command.py: python -m backend export",
    "backend/commands/generate.py": "exercised by tests/backend/generate/test_command.py: python -m backend generate",
    "backend/commands/init_checkpoint.py": "exercised by tests/backend/generate/test_command.py: python -m backend "
                                           "init-checkpoint",
    "backend/commands/mesh_asset.py": "exercised by tests/backend/mesh/test_asset.py: python -m backend mesh-asset",
    "backend/commands/options.py": "tested by tests/backend/commands/test_init.py: the shared options and their choices",
    "backend/commands/render.py": "exercised by tests/backend/render/test_command.py: python -m backend render",
    "backend/commands/serve.py": "exercised by tests/backend/test_serve.py: python -m backend serve",
    "backend/commands/splat_asset.py": "exercised by tests/backend/test_splat_asset.py: python -m backend splat-asset",
    "backend/commands/train.py": "exercised by tests/backend/train/test_trainer.py: python -m backend train",
    "backend/commands/vary.py": "exercised by tests/backend/vary/test_command.py: python -m backend vary",
    # -- operators/, panels/: thin (read context, call scpainter_blender, report); run as an artist runs them
    "operators/asset_box.py": "tested by tests/scene/test_asset_box.py: the box operators on a Gaussian car",
    "operators/backend_run.py": "exercised by tests/runs/test_camera_run.py: the render/generate/export operators, "
                                "followed and cancelled",
    "operators/camera_path.py": "tested by tests/scene/test_camera.py: bpy.ops.scpainter.new_camera_path",
    "operators/drive_lane.py": "tested by tests/scene/test_drive_lane.py: *Drive Along Lane* on the street",
    "operators/import_gaussians.py": "tested by tests/scene/test_gaussians.py: bpy.ops.scpainter.import_gaussians",
    "operators/recorded_objects.py": "tested by tests/scene/test_recorded_objects.py: Import Recorded Objects and "
                                     "a removal box from one, on the street",
    "operators/import_vggt.py": "tested by tests/scene/test_importer.py: bpy.ops.scpainter.import_vggt",
    "operators/job.py": "tested by tests/scene/test_job_export.py: bpy.ops.scpainter.export_job",
    "operators/rig.py": "tested by tests/scene/test_rig.py: bpy.ops.scpainter.add_camera_rig / remove_camera_rig",
    "operators/placement.py": "tested by tests/scene/test_placement.py: fit, snap, removal boxes, replace a car",
    "operators/reports.py": "exercised by tests/scene/test_gaussians.py: bad files reported by the import "
                            "operator (test_bad_files_report_and_create_nothing)",
    "operators/selection.py": "exercised by tests/scene/test_gaussians.py: the imported object selected and active",
    "operators/variations.py": "tested by tests/scene/test_variations.py: *Make Variations*",
    "panels/main.py": "exercised by tests/scene/test_baseline_ui.py: the panel drawn, its Generate button and tooltip",
    # -- core
    "scpainter_blender/core/colors.py": "tested by tests/backend/mesh/test_colors.py: linear glTF factors to sRGB",
    "scpainter_blender/core/errors.py": "tested by tests/core/test_files.py: InputError and ArgumentError",
    "scpainter_blender/core/geometry/unproject.py": "tested by tests/core/geometry/test_point_cloud.py: VGGT's "
                                                    "unprojection formula, exactly",
    "scpainter_blender/core/geometry/visibility.py": "tested by tests/backend/render/test_frames_culling.py: the "
                                                     "skip tests against the projections they bound",
    "scpainter_blender/core/job_inputs.py": "tested by tests/core/test_job.py: job paths in the job folder or a "
                                            "data root",
    "scpainter_blender/core/splats/asset_frame.py": "exercised by tests/scene/test_gaussians.py: each import's data "
                                                    "frame and default length (TRELLIS axes, a millimetre car)",
    "scpainter_blender/core/splats/webp.py": "tested by tests/core/splats/test_sog.py: WebP headers (sizes, kinds)",
    "scpainter_blender/core/user_cache.py": "exercised by tests/scene/test_gaussians.py: converted assets of an "
                                            "unsaved .blend in $XDG_CACHE_HOME/scpainter",
    "scpainter_blender/core/variation/library.py": "tested by tests/core/variation/test_variants.py: the cars drawn",
    "scpainter_blender/core/variation/spec.py": "tested by tests/core/variation/test_variants.py: "
                                                "scpainter.variation/1 read and written",
    # -- cli (`blender -c scpainter`)
    "scpainter_blender/cli/generate.py": "tested by tests/cli/test_batch.py: `generate` of a scene with the "
                                         "baseline (--inpaint, --output) and a tiny checkpoint "
                                         "(test_render_generate_and_batch_headless)",
    "scpainter_blender/cli/vary.py": "tested by tests/scene/test_variations.py: `vary` from predictions and from a "
                                     "saved .blend (test_vary_headless_from_predictions_and_from_a_blend)",
    # -- scene
    "scpainter_blender/scene/compat.py": "tested by tests/scene/test_visibility.py: Blender 4.2 and later alike",
    "scpainter_blender/scene/materials.py": "exercised by tests/scene/test_gaussians.py: the imported car's "
                                            "emission material",
    "scpainter_blender/scene/points.py": "tested by tests/scene/test_importer.py: the points object of an import",
    "scpainter_blender/runs/preferences.py": "tested by tests/scene/test_baseline_ui.py: the checkpoint preference",
    # -- street (tests and demo only; counted: see the module's docstring)
    "scpainter_blender/street/__main__.py": "exercised by tests/street/test_street.py: ensure_street generates "
                                            "the street through `python -m scpainter_blender.street` "
                                            "(test_generation_is_deterministic, twice)",
    "scpainter_blender/street/build.py": "tested by tests/street/test_street.py: the street end to end",
    "scpainter_blender/street/dataset.py": "tested by tests/street/test_street.py: the street end to end, cached",
    "scpainter_blender/street/materials.py": "exercised by tests/street/test_street.py: the street generated "
                                             "(test_generation_is_deterministic)",
    "scpainter_blender/street/predictions.py": "tested by tests/street/test_street.py: VGGT's layout, exact depth",
    "scpainter_blender/street/render.py": "exercised by tests/street/test_street.py: the street rendered "
                                          "(test_generation_is_deterministic)",
    # -- backend
    "backend/events.py": "tested by tests/backend/test_errors.py: error events and log_scope",
    "backend/png.py": "tested by tests/backend/render/test_writer.py: previews written by the frame writer",
    "backend/webp.py": "tested by tests/core/splats/test_sog.py: the backend's WebP decoder on SOG images",
    "backend/evaluate/pictures.py": "tested by tests/backend/evaluate/test_protocol.py: the end-to-end run's pictures",
    "backend/export/common.py": "tested by tests/backend/export/test_kitti.py: conventions KITTI and OpenLABEL share",
    "backend/generate/video.py": "tested by tests/backend/generate/test_baseline.py: MP4s read back (read_mp4, "
                                 "mp4_metadata)",
    "backend/model/checkpoint_config.py": "tested by tests/backend/model/test_checkpoint.py: scpainter.json field by "
                                          "field, through checkpoint folders",
    "backend/model/checkpoint_init.py": "tested by tests/backend/model/test_checkpoint.py: the tiny checkpoint "
                                        "passes and loads",
    "backend/model/configs.py": "tested by tests/backend/train/test_vae_fit.py: tiny SVD components",
    "backend/render/frames.py": "tested by tests/backend/render/test_frames_culling.py: render_frame with and "
                                "without the skip tests (also test_gaussians_instance.py, test_cleaning.py)",
    "backend/render/labelled.py": "tested by tests/backend/render/test_command_labels.py: labelled previews of a "
                                  "render",
    "backend/render/points.py": "tested by tests/backend/render/test_points_cpu.py: the torch reference z-buffer",
    "backend/render/tiles.py": "tested by tests/backend/render/test_gaussians.py: tile binning, against the dense "
                               "render",
    "backend/render/tiles_cpu.py": "tested by tests/backend/render/test_project_cpu.py: the counting sort's tile lists",
    "backend/render/warmup.py": "tested by tests/backend/test_serve.py: the kernels made ready before the first frame",
    "backend/train/ema.py": "tested by tests/backend/train/test_trainer.py: the checkpoint holds the EMA weights",
    "backend/train/street_clip.py": "tested by tests/backend/train/test_clip.py: the street exported as a clip",
}

# -- test files that are no module's mirror -----------------------------------------------------------------------
CROSS_CUTTING = {
    "tests/test_demo.py": "the README's main command (tools/demo.py) end to end on the cached street",
    "tests/test_packaging.py": "the project installs as a package (pyproject.toml, `scpainter-backend`); the zip "
                               "leaves the packaging out",
    "tests/test_layout.py": "this file: the tests mirror the code",
    "tests/test_docs.py": "the documents' lists (design §2's module table, both programs' commands, the README's "
                          "format table) against the code",
    "tests/test_annotations.py": "the share of fully annotated public functions of core/ and backend/",
    "tests/bench/test_device_all.py": "bench/device_all.sh's command lines parse with each bench's parser; its dry "
                                      "run writes each part's JSON and summary.json",
    "tests/street/test_street.py": "the ground-truth street end to end: build, render, predictions, dataset cache",
    "tests/backend/test_fuzz_inputs.py": "hostile input files of every kind through every command "
                                         "(tests/fuzz_inputs.py, tests/fuzz_surfaces.py, tests/fuzz_round3.py)",
    "tests/backend/test_output_safety.py": "output folders across commands: confinement, one run per folder, "
                                           "clean-up of only our own files",
    "tests/scene/test_extension.py": "the extension as Blender sees it: built, validated, installed, registered; "
                                     "the import rules between the rooms (docs/design.md §2)",
    "tests/scene/test_import_option_surfaces.py": "the import operator's properties and `blender -c scpainter "
                                                  "import`'s flags agree with core.import_options",
    "tests/scene/test_baseline_ui.py": "what the panel, the tooltip, the progress text and the exported job say of "
                                       "the inpainting baseline",
}

# -- benchmarks: bench/<name>.py (a script with main) is smoke-tested by tests/bench/test_<name>.py -------------------
# Scripts without a smoke test yet, and why (the list can only shrink: an entry whose test exists fails).
BENCH_SMOKE_PENDING = {
}

# Test files other branches are moving or rewriting now; the merge places them (then each leaves this list).
PENDING_TESTS = {
}


def tracked_files(commit=None) -> list:
    """The paths of the checkout (or of ``commit``), relative, with "/": in the checkout the git-tracked files and the
    untracked ones git does not ignore (a new module or test counts before it is staged), less those deleted from
    disk. Skips outside a checkout."""
    cmd = ["git", "ls-files", "--cached", "--others", "--exclude-standard"] if commit is None else \
        ["git", "ls-tree", "-r", "--name-only", commit]
    try:
        listed = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    paths = listed.stdout.split()
    return paths if commit is not None else [p for p in paths if os.path.lexists(os.path.join(ROOT, p))]


def _read(path, commit=None) -> str:
    if commit is None:
        with open(os.path.join(ROOT, path), encoding="utf-8") as f:
            return f.read()
    return subprocess.run(["git", "show", f"{commit}:{path}"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout


def _has_code(source: str) -> bool:
    """Whether a module holds more than its docstring."""
    return any(not (isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant)) for n in ast.parse(source).body)


def shipped_modules(files, read=_read) -> list:
    """The shipped modules among ``files`` (tracked paths), sorted; ``read(path)``: a file's text."""
    out = []
    for path in files:
        if not path.endswith(".py") or path.startswith("tests/") or path.split("/")[0] not in SHIPPED:
            continue
        if os.path.basename(path) == "__init__.py" and not _has_code(read(path)):
            continue
        out.append(path)
    return sorted(out)


def mirrored_test(module: str) -> str:
    """The test file of ``module`` (a shipped path): see the module's docstring."""
    folder, name = os.path.split(module)
    if folder == "scpainter_blender" or folder.startswith("scpainter_blender/"):
        folder = folder[len("scpainter_blender"):].lstrip("/")
    stem = {"__init__.py": "init", "__main__.py": "main"}.get(name, name[:-3])
    return "/".join(p for p in ("tests", folder, f"test_{stem}.py") if p)


def listed_tests(files) -> list:
    """The pytest test files among ``files``."""
    return sorted(p for p in files if p.startswith("tests/") and os.path.basename(p).startswith("test_")
                  and p.endswith(".py"))


def coverage(commit=None):
    """(shipped modules, those with a test file at their mirrored path) in the checkout, or at ``commit``."""
    files = tracked_files(commit)
    modules = shipped_modules(files, read=lambda p: _read(p, commit))
    tests = set(listed_tests(files))
    return modules, [m for m in modules if mirrored_test(m) in tests]


def _is_mirror_or_aspect(test: str, mirrors: set) -> bool:
    """``test`` is a module's mirror, or ``test_<module>_<aspect>.py`` beside one."""
    if test in mirrors:
        return True
    folder, name = os.path.split(test)
    stem = name[len("test_"):-len(".py")]
    return any(f"{folder}/test_{stem[:i]}.py" in mirrors for i in range(len(stem)) if stem[i] == "_")


# -- the checks ------------------------------------------------------------------------------------------------------

def test_mirrors_and_aspects():
    assert mirrored_test("scpainter_blender/core/splats/inria.py") == "tests/core/splats/test_inria.py"
    assert mirrored_test("scpainter_blender/runs/client.py") == "tests/runs/test_client.py"
    assert mirrored_test("backend/mesh/gltf.py") == "tests/backend/mesh/test_gltf.py"
    assert mirrored_test("backend/errors.py") == "tests/backend/test_errors.py"
    assert mirrored_test("operators/job.py") == "tests/operators/test_job.py"
    assert mirrored_test("backend/__init__.py") == "tests/backend/test_init.py"
    assert mirrored_test("backend/__main__.py") == "tests/backend/test_main.py"
    assert mirrored_test("__init__.py") == "tests/test_init.py"
    mirrors = {"tests/backend/train/test_clip.py", "tests/backend/model/test_checkpoint.py"}
    assert _is_mirror_or_aspect("tests/backend/train/test_clip_video.py", mirrors)
    assert _is_mirror_or_aspect("tests/backend/model/test_checkpoint_clip_normalisation.py", mirrors)
    assert not _is_mirror_or_aspect("tests/backend/train/test_clipping.py", mirrors)
    assert not _is_mirror_or_aspect("tests/backend/test_clip_video.py", mirrors)


def test_every_shipped_module_has_its_mirrored_test_or_says_why():
    modules, mirrored = coverage()
    assert "scpainter_blender/core/job.py" in modules and "scpainter_blender/street/build.py" in modules
    assert "backend/render/__init__.py" not in modules and "backend/__init__.py" in modules  # docstring-only out
    missing = sorted(set(modules) - set(mirrored) - set(UNMIRRORED))
    assert not missing, "shipped modules without tests/<package path>/test_<module>.py (add the test, or an " \
                        f"UNMIRRORED entry saying where the module is tested): {missing}"


def test_the_unmirrored_list_is_not_stale():
    modules, mirrored = coverage()
    gone = sorted(set(UNMIRRORED) - set(modules))
    assert not gone, f"UNMIRRORED names modules that are not shipped (any more): {gone}"
    now_mirrored = sorted(set(UNMIRRORED) & set(mirrored))
    assert not now_mirrored, f"UNMIRRORED names modules that now have their mirrored test: {now_mirrored}"


def test_unmirrored_entries_name_where_the_module_is_tested():
    """Each "tested by tests/…" names a test file that exists and names the module (by its module name, its
    import path or its file name: a weak check that the entry was written for this file and stays true); each
    "exercised by tests/…" a test file that exists."""
    tests = set(listed_tests(tracked_files()))
    wrong = {}
    for module, why in UNMIRRORED.items():
        assert why.startswith(("tested by tests/", "exercised by tests/", "no behaviour of its own",
                               "pending: moved by the merge")), module
        if not why.startswith(("tested by ", "exercised by ")):
            continue
        where = why.split(" ", 2)[2].split(":")[0]
        if where not in tests:
            wrong[module] = f"{where} is not a test file"
            continue
        if why.startswith("exercised by "):  # run there without being named (an operator's helper, a cache)
            continue
        stem = os.path.basename(module)[:-3]
        if stem == "__init__":
            stem = os.path.dirname(module) or "register"
        if not re.search(rf"(?<![A-Za-z0-9]){re.escape(stem)}", _read(where)):  # bpy.ops.scpainter.make_variations
            wrong[module] = f"{where} never names {stem!r}"
    assert not wrong, wrong


def bench_scripts(files, read=_read) -> list:
    """The bench scripts among ``files``: ``bench/<name>.py`` defining ``main`` (helpers such as
    ``bench/provenance.py`` have none; they run inside the scripts that import them)."""
    return sorted(p for p in files if re.fullmatch(r"bench/\w+\.py", p)
                  and re.search(r"^def main\(", read(p), re.M))


def bench_smoke_test(script: str) -> str:
    """``bench/<name>.py`` -> ``tests/bench/test_<name>.py``."""
    return f"tests/bench/test_{os.path.basename(script)}"


def test_every_bench_script_has_a_smoke_test_that_runs_it_small():
    """docs/design.md §7: each bench script takes ``--smoke`` and ``--out`` and its test runs ``--smoke``, so a change
    that breaks a bench fails CI."""
    files = tracked_files()
    scripts = bench_scripts(files)
    assert "bench/lidar.py" in scripts and "bench/provenance.py" not in scripts
    problems = []
    for script in scripts:
        test = bench_smoke_test(script)
        if script in BENCH_SMOKE_PENDING:
            if test in files:
                problems.append(f"{script}: its smoke test exists, leave BENCH_SMOKE_PENDING")
            continue
        text = _read(script)
        if '"--smoke"' not in text and "add_smoke_and_out" not in text:
            problems.append(f"{script}: no --smoke option")
        if '"--out"' not in text and "add_smoke_and_out" not in text:
            problems.append(f"{script}: no --out option")
        if test not in files:
            problems.append(f"{script}: no {test}")
        elif "smoke" not in _read(test):
            problems.append(f"{test} does not run {script} --smoke")
    assert not problems, "\n".join(problems)
    assert not sorted(set(BENCH_SMOKE_PENDING) - set(scripts)), "BENCH_SMOKE_PENDING names no bench script"


def test_every_test_file_mirrors_a_module_or_is_listed():
    files = tracked_files()
    mirrors = {mirrored_test(m) for m in shipped_modules(files)} | {bench_smoke_test(b) for b in bench_scripts(files)}
    stray = [t for t in listed_tests(files)
             if not _is_mirror_or_aspect(t, mirrors) and t not in CROSS_CUTTING and t not in PENDING_TESTS]
    assert not stray, "test files that are no module's tests/<package path>/test_<module>[_<aspect>].py: move " \
                      f"them to their module's mirror, or list a cross-cutting test in CROSS_CUTTING: {stray}"
    listed = set(CROSS_CUTTING) | set(PENDING_TESTS)
    gone = sorted(listed - set(files))
    assert not gone, f"CROSS_CUTTING / PENDING_TESTS name files that do not exist: {gone}"
    mirrored_now = sorted(t for t in listed if _is_mirror_or_aspect(t, mirrors))
    assert not mirrored_now, f"CROSS_CUTTING / PENDING_TESTS name files that are a module's mirror: {mirrored_now}"


if __name__ == "__main__":
    modules, mirrored = coverage(sys.argv[1] if len(sys.argv) > 1 else None)
    print(f"{len(mirrored)} of {len(modules)} shipped modules have a test at the mirrored path "
          f"({100 * len(mirrored) / len(modules):.1f} %)")
