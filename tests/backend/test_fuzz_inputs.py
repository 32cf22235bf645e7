"""Hostile input files (issues 14 and 30): every fuzz case of ``tests/fuzz_inputs.py`` and of
``tests/fuzz_surfaces.py`` (its ``CI_KINDS``: mesh, splat, splat2 (issue 31's formats: SPZ, .ksplat, SOG,
glTF splats; ``tests/fuzz_splat_formats.py``), exr, clip; 810 cases) is accepted or refused cleanly;
kills and concurrent runs on one output folder (``kill``, 36 cases) leave no mixed frames, lock or temporary behind.

1,150 seeded cases (job.json, predictions.npz, car.ply and the checkpoint's files) run through
``python -m backend render`` and ``generate --check`` in-process, in two worker processes. Each must end
``accepted`` (exit 0) or ``clean`` (exit 2, an error event naming the file); never ``unclear`` (exit 2 naming no
file), ``traceback``, ``hang`` (5 s), ``escape`` (a file outside the job folder created, changed or deleted) or
``misread`` (a PLY rewritten without changing its Gaussians, accepted with other values). A failure prints the
table and one line per failing case; reproduce one with
``.venv/bin/python -m tests.fuzz_inputs --kind KIND --index N --keep``.
"""

import fuzz_inputs as F
import fuzz_surfaces
import pytest

#: The kinds run here: issue 14's inputs and issue 30's surfaces, kills included (``fuzz_surfaces.CI_KINDS``).
CI_KINDS = F.INPUT_KINDS + fuzz_surfaces.CI_KINDS
SURFACE_FILES = tuple(k for k in fuzz_surfaces.CI_KINDS if k != "kill")


@pytest.fixture(scope="module")
def fuzz_run():
    # without --check the checkpoint cases would generate for real (minutes): fail at once instead
    assert F.has_check_option(), "python -m backend generate has no --check option"
    return F.run(CI_KINDS, seed=F.SEED, timeout=F.TIMEOUT_S)


def test_every_hostile_input_is_accepted_or_refused_cleanly(fuzz_run):
    """Issue 14's kinds (job, npz, ply, checkpoint)."""
    _assert_clean(fuzz_run, F.INPUT_KINDS, 1000)


def test_every_hostile_surface_file_is_accepted_or_refused_cleanly(fuzz_run):
    """Issue 30's kinds (mesh files with the files they name, splat formats, condition EXRs as generate reads them,
    training clips); misreads as ``tests/fuzz_surfaces.py`` defines them."""
    _assert_clean(fuzz_run, SURFACE_FILES, 400)


def test_kills_and_concurrent_runs_leave_only_the_finished_runs_outputs(fuzz_run):
    """Issue 30's ``kill`` kind: generate (the baseline), render and mesh-asset killed (SIGKILL or SIGTERM) before
    one of their atomic renames, or two runs at once on one output folder; then the next run: every frame in
    ``generated/`` and ``conditions/`` (the asset PLY) is that finished run's, no temporary is left, and a run
    refused by the other's lock says so (exit 1) without a traceback."""
    _assert_clean(fuzz_run, ("kill",), 30)
    # every kill landed (fuzz_surfaces.KILL_SCENARIOS counts the renames a run makes: a product change to them must
    # change it too, or the kills would silently come after the run's end)
    missed = [f"{r['index']} {r['description']}: {r['killed_before']}" for r in fuzz_run["results"]
              if r["kind"] == "kill" and r.get("killed_before", "").startswith("(the run ended")]
    assert not missed, "kills that came after the run ended:\n" + "\n".join(missed)


def _assert_clean(run, kinds, least):
    results = [r for r in run["results"] if r["kind"] in kinds]
    summary = F.summarize(results)
    report = (f"{F.format_table(summary)}\n(generate --check: {run['check']}, {run['workers']} worker process(es), "
              f"{run['seconds']} s)\n{F.format_failures(results)}")
    assert all(b["outcome"] == "accepted" for b in run["base"].values()), f"the valid inputs fail: {run['base']}"
    assert summary["total"]["cases"] == len(results) >= least
    assert {r["kind"] for r in results} == set(kinds)
    # a clean refusal names the field too (an InputError's error event carries file and field)
    failing = [r for r in results if r["outcome"] not in ("accepted", "clean") or
               (r["outcome"] == "clean" and not r.get("field"))]
    unnamed = "\n".join(f"  {r['kind']} {r['index']} clean but no field: {r['description'][:60]} {r['message'][:100]}"
                        for r in failing if r["outcome"] == "clean")
    if failing:
        pytest.fail(f"{len(failing)} of {len(results)} hostile inputs end badly:\n{report}\n{unnamed}", pytrace=False)
