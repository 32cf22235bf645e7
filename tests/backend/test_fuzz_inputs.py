"""Hostile input files (issue 14): every fuzz case of ``tests/fuzz_inputs.py`` is accepted or refused cleanly.

1,150 seeded cases (job.json, predictions.npz, car.ply and the checkpoint's files) run through
``python -m backend render`` and ``generate --check`` in-process, in two worker processes. Each must end
``accepted`` (exit 0) or ``clean`` (exit 2, an error event naming the file); never ``unclear`` (exit 2 naming no
file), ``traceback``, ``hang`` (5 s), ``escape`` (a file outside the job folder created, changed or deleted) or
``misread`` (a PLY rewritten without changing its Gaussians, accepted with other values). A failure prints the
table and one line per failing case; reproduce one with
``.venv/bin/python -m tests.fuzz_inputs --kind KIND --index N --keep``.
"""

import fuzz_inputs as F
import pytest


def test_every_hostile_input_is_accepted_or_refused_cleanly():
    # without --check the checkpoint cases would generate for real (minutes): fail at once instead
    assert F.has_check_option(), "python -m backend generate has no --check option"
    run = F.run(F.KINDS, seed=F.SEED, timeout=F.TIMEOUT_S)
    results = run["results"]
    summary = F.summarize(results)
    report = (f"{F.format_table(summary)}\n(generate --check: {run['check']}, {run['workers']} worker process(es), "
              f"{run['seconds']} s)\n{F.format_failures(results)}")
    assert all(b["outcome"] == "accepted" for b in run["base"].values()), f"the valid inputs fail: {run['base']}"
    assert summary["total"]["cases"] == len(results) >= 1000
    assert {r["kind"] for r in results} == set(F.KINDS)
    # a clean refusal names the field too (an InputError's error event carries file and field)
    failing = [r for r in results if r["outcome"] not in ("accepted", "clean") or
               (r["outcome"] == "clean" and not r.get("field"))]
    unnamed = "\n".join(f"  {r['kind']} {r['index']} clean but no field: {r['description'][:60]} {r['message'][:100]}"
                        for r in failing if r["outcome"] == "clean")
    if failing:
        pytest.fail(f"{len(failing)} of {len(results)} hostile inputs end badly:\n{report}\n{unnamed}", pytrace=False)
