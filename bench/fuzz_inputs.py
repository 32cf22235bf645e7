"""The fuzz cases of issues 14, 30 and 42 on this checkout: per input kind, how many are accepted, refused cleanly, or end badly.

    .venv/bin/python bench/fuzz_inputs.py [--label before|after] [--kinds job npz ply checkpoint mesh splat exr clip kill
                                          links races lists serve numerics names diskfull varykill] [--seed 14]
                                          [--timeout 5] [--out bench/results] [--smoke]

Issue 42's kinds alone, as the closing note's before/after table (``tests/fuzz_round3.py``; diskfull needs root)::

    .venv/bin/python bench/fuzz_inputs.py --label before --kinds links races lists serve numerics names diskfull varykill \
                                          --out bench/results/fuzz_round3_before.json

Runs the cases of ``tests/fuzz_inputs.py`` (the same ones ``tests/backend/test_fuzz_inputs.py`` asserts on) and
prints the table of the closing note (input kind, cases, accepted, clean errors, unclear, tracebacks, hangs,
escapes, misreads), then the failing cases grouped by family with one example each, then by failure class (kind,
outcome, the message with paths and numbers blanked: one line per defect). Outcome classes are defined in
``tests/fuzz_inputs.py``: ``clean`` = exit 2 with an error naming the file; ``unclear`` = exit 2 naming none;
``traceback`` = exit 1 or a traceback; ``hang`` = no answer within the timeout; ``escape`` = a file outside the
job folder created, changed or deleted; ``misread`` = a PLY rewritten without changing its Gaussians, accepted with
other values (issue 30's kinds: as tests/fuzz_surfaces.py defines it). Run from any checkout's root (an older one
gives the "before" column: copy this file, tests/fuzz_inputs.py and tests/fuzz_surfaces.py into it). Saves the table and the failing cases to the JSON (``--out DIR``, or a path ending in .json). Not a test;
``--smoke``: the first two ply cases on one worker (``tests/bench/test_fuzz_inputs.py``). It sets its
process's thread counts as the fuzz's workers': run it in a process of its own.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))

import fuzz_inputs as F  # noqa: E402
import fuzz_round3  # noqa: E402
import fuzz_surfaces  # noqa: E402
from scpainter_blender.core import outputs  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)
import provenance  # noqa: E402  (bench/, the script's folder)


def compact(r: dict) -> dict:
    """One case for the JSON: no traceback, no empty fields, the message's first 160 characters."""
    out = {k: v for k, v in r.items() if k not in ("traceback", "seed") and v not in (None, "")}
    if "message" in out:
        out["message"] = out["message"][:160]
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--label", default="after", help="before | after (recorded in the JSON)")
    p.add_argument("--kinds", nargs="+", choices=F.KINDS,
                   default=list(F.INPUT_KINDS + fuzz_surfaces.CI_KINDS + fuzz_round3.ci_kinds()),
                   help="default: the kinds the test runs (all; diskfull where a tmpfs can be mounted)")
    p.add_argument("--seed", type=int, default=F.SEED)
    p.add_argument("--timeout", type=float, default=F.TIMEOUT_S, help="seconds per case before it is a hang")
    p.add_argument("--quiet", action="store_true", help="no line per failing case while running")
    bench_cli.add_smoke_and_out(p, "the first two ply cases, one worker")
    args = p.parse_args(argv)
    args.out = bench_cli.json_path(args.out, "fuzz_inputs")
    indices, workers = None, 2
    if args.smoke:
        args.kinds = ["ply"]
        indices, workers = [("ply", i) for i in range(2)], 1

    def on_result(r):
        if not args.quiet and r["outcome"] in F.FAILURES:
            print(f"  {r['kind']:<10} {r['index']:>4} {r['outcome']:<9} {r['description'][:60]:<60} "
                  f"{r['message'][:110]}", flush=True)

    if "diskfull" in args.kinds and not fuzz_round3.can_mount():
        print("diskfull left out: it needs root and `mount -t tmpfs` (fuzz_round3.can_mount)")
        args.kinds = [k for k in args.kinds if k != "diskfull"]
    t0 = time.perf_counter()
    run = F.run(args.kinds, seed=args.seed, timeout=args.timeout, indices=indices, on_result=on_result,
                workers=workers)
    seconds = time.perf_counter() - t0
    results = run["results"]
    summary = F.summarize(results)
    commit, dirty = provenance.commit_and_dirty(ROOT)

    print(f"\nfuzz_inputs ({args.label}): commit {commit}{' + local changes' if dirty else ''}, seed {args.seed}, "
          f"timeout {args.timeout:g} s, generate --check: {'yes' if run['check'] else 'no (generate runs for real)'}, "
          f"{run['workers']} worker process(es), {seconds:.0f} s; backend {run['backend']}")
    bad_base = {k: v for k, v in run["base"].items() if v["outcome"] != "accepted"}
    if bad_base:
        print(f"WARNING: the valid inputs themselves are not accepted, the table means little: {bad_base}")
    print(F.format_table(summary))
    groups = F.families(results)
    if groups:
        print("\nfailing cases by family (kind, family, outcome, count, an example):")
        for kind, family, outcome, count, example in groups:
            print(f"  {kind:<10} {family:<28} {outcome:<9} {count:>3}  {example[:200]}")
    classes = F.failure_classes(results)
    if classes:
        print("\nfailure classes (kind, outcome, count, message with paths and numbers blanked; an example):")
        for kind, outcome, msg, count, example in classes:
            print(f"  {kind:<10} {outcome:<9} {count:>3}  {msg}  [{example}]")

    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    outputs.write_json(args.out, {
        "label": args.label, "commit": commit, "local_changes": dirty, "seed": args.seed,
        "timeout_s": args.timeout, "generate_check": run["check"], "base": run["base"], "backend": run["backend"],
        "seconds": round(seconds, 1), "workers": run["workers"],
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "summary": summary,
        "families": [dict(zip(("kind", "family", "outcome", "count", "example"), g)) for g in groups],
        "failure_classes": [dict(zip(("kind", "outcome", "message", "count", "example"), g)) for g in classes],
        # every case is reproducible from (kind, index, seed): only the ones that end badly are kept
        "failing_cases": [compact(r) for r in results if r["outcome"] in F.FAILURES]})
    print(f"\nwrote {os.path.relpath(args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
