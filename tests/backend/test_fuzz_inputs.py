"""Hostile input files (issues 14, 30 and 42): every fuzz case of ``tests/fuzz_inputs.py`` and of
``tests/fuzz_surfaces.py`` (its ``CI_KINDS``: mesh, splat, splat2 (issue 31's formats: SPZ, .ksplat, SOG,
glTF splats; ``tests/fuzz_splat_formats.py``), exr, clip; 810 cases) is accepted or refused cleanly;
kills and concurrent runs on one output folder (``kill``, 36 cases) leave no mixed frames, lock or temporary behind.
Issue 42's surfaces (``tests/fuzz_round3.py``: links, races, lists, serve, numerics, names, diskfull where a tmpfs
can be mounted, varykill; 560 cases) write, read and delete nothing outside the case's job folder, keep list files'
meaning, answer every malformed serve request, and never leave a mixed vary folder; 2,556 cases in all (2,526
without diskfull).

1,150 seeded cases (job.json, predictions.npz, car.ply and the checkpoint's files) run through
``python -m backend render`` and ``generate --check`` in-process, in two worker processes. Each must end
``accepted`` (exit 0) or ``clean`` (exit 2, an error event naming the file); never ``unclear`` (exit 2 naming no
file), ``traceback``, ``hang`` (5 s), ``escape`` (a file outside the job folder created, changed or deleted) or
``misread`` (a PLY rewritten without changing its Gaussians, accepted with other values). A failure prints the
table and one line per failing case; reproduce one with
``.venv/bin/python -m tests.fuzz_inputs --kind KIND --index N --keep``.
"""

import fuzz_inputs as F
import fuzz_round3
import fuzz_surfaces
import pytest

#: The kinds run here: issue 14's inputs, issue 30's surfaces, kills included (``fuzz_surfaces.CI_KINDS``), and
#: issue 42's (``fuzz_round3.ci_kinds()``: diskfull only where this process can mount a tmpfs).
ROUND3 = fuzz_round3.ci_kinds()
CI_KINDS = F.INPUT_KINDS + fuzz_surfaces.CI_KINDS + ROUND3
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


def test_the_fuzzer_runs_2500_cases():
    """Issue 42: at least 2,500 cases in CI (with or without the diskfull kind)."""
    assert sum(F.CASES[k] for k in CI_KINDS) >= 2500


def test_links_and_races_write_and_read_nothing_outside(fuzz_run):
    """Issue 42's ``links`` (planted symbolic and hard links where render, generate, export and vary write) and
    ``races`` (an input swapped for a link right after its first open, an output folder right after it was made):
    nothing outside the case's job folder is created, changed, deleted, or read by a run that succeeds."""
    _assert_clean(fuzz_run, ("links", "races"), 100)
    idle = [f"{r['index']} {r['description']}" for r in fuzz_run["results"]
            if r["kind"] == "races" and r.get("swapped") is False]
    assert not idle, "races whose swap never happened (the hooked call was not made):\n" + "\n".join(idle)


def test_list_files_and_manifests_keep_their_meaning(fuzz_run):
    """Issue 42's ``lists``: batch lists with hidden line breaks, NUL, control characters and non-UTF-8 bytes are
    refused or read as written (the injected data root never trusted); vary's list never declares roots or jobs
    its run did not mean, whatever its folders are called; contact-sheet on a hostile manifest is clean."""
    _assert_clean(fuzz_run, ("lists",), 60)


def test_serve_answers_every_malformed_request_and_goes_on(fuzz_run):
    """Issue 42's ``serve``: each malformed request line gets an error event and the server answers the next valid
    request (no hang, no death)."""
    _assert_clean(fuzz_run, ("serve",), 120)


def test_hostile_numbers_and_names_are_accepted_or_refused_by_name(fuzz_run):
    """Issue 42's ``numerics`` (every numeric field of a job and a variation spec, vary's options) and ``names``
    (long, non-UTF-8, NUL, newline names for inputs and outputs)."""
    _assert_clean(fuzz_run, ("numerics", "names"), 240)


def test_a_full_disk_is_an_error_naming_the_folder_with_nothing_half_written(fuzz_run):
    """Issue 42's ``diskfull``: render, generate, export and vary on an 8-256 KiB tmpfs (root only)."""
    if "diskfull" not in ROUND3:
        pytest.skip("diskfull needs root and `mount -t tmpfs` (fuzz_round3.can_mount)")
    _assert_clean(fuzz_run, ("diskfull",), 30, need_field=False)


def test_killed_and_concurrent_vary_runs_never_leave_a_mixed_list(fuzz_run):
    """Issue 42's ``varykill``: vary killed before a seeded rename, then a re-run or none, or two at once: the list
    and the jobs it names are wholly one run's (or refused), no temporary after a re-run."""
    _assert_clean(fuzz_run, ("varykill",), 10, need_field=False)
    missed = [f"{r['index']} {r['description']}: {r['killed_before']}" for r in fuzz_run["results"]
              if r["kind"] == "varykill" and r.get("killed_before", "").startswith("(the run ended")]
    assert not missed, "kills that came after the run ended:\n" + "\n".join(missed)


def _assert_clean(run, kinds, least, need_field=True):
    results = [r for r in run["results"] if r["kind"] in kinds]
    summary = F.summarize(results)
    report = (f"{F.format_table(summary)}\n(generate --check: {run['check']}, {run['workers']} worker process(es), "
              f"{run['seconds']} s)\n{F.format_failures(results)}")
    assert all(b["outcome"] == "accepted" for b in run["base"].values()), f"the valid inputs fail: {run['base']}"
    assert summary["total"]["cases"] == len(results) >= least
    assert {r["kind"] for r in results} == set(kinds)
    # a clean refusal names the field too (an InputError's error event carries file and field)
    failing = [r for r in results if r["outcome"] not in ("accepted", "clean") or
               (need_field and r["outcome"] == "clean" and not r.get("field"))]
    unnamed = "\n".join(f"  {r['kind']} {r['index']} clean but no field: {r['description'][:60]} {r['message'][:100]}"
                        for r in failing if r["outcome"] == "clean")
    if failing:
        pytest.fail(f"{len(failing)} of {len(results)} hostile inputs end badly:\n{report}\n{unnamed}", pytrace=False)
