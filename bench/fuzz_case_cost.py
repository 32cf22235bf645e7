"""What the fuzz's many-asset job cases cost against its budget: CPU and wall seconds of "assets: 100 assets on the
same PLY", "50 assets on the same PLY" and "two assets on one PLY", run the way ``tests/fuzz_inputs.py`` runs them.

    .venv/bin/python bench/fuzz_case_cost.py [--label before|after] [--cases 100 50 2] [--job-index N ...]
                                             [--rounds 3] [--seed 14] [--out bench/results] [--smoke]

Each case is built by ``tests/fuzz_inputs.py``'s own machinery (``Base``, ``make_case`` at the first ``job`` index
whose description is the case's, ``prepare``, ``command``) and run in this process through ``invoke`` (its
``alarm`` raised to 600 CPU s, so a case over the fuzz budget is measured, not cut), in a process set up as a fuzz
worker is: one torch, numba and OpenMP thread, the valid job run once first, untimed (kernels loaded, imports
done). CPU seconds = ``time.process_time`` around ``invoke`` (user + system of every thread: what the fuzz's SIGPROF
timer counts); wall seconds = ``time.perf_counter``. The table gives the median and the worst of ``--rounds`` runs
per case, the fuzz budget (``TIMEOUT_S`` CPU s) and the worst's share of it, and each case's outcome (it must stay
``accepted``). ``--job-index`` adds any other ``job`` case by its index (the costliest of a fuzz run, say). Saves the table under bench/results/ (``--out DIR``; a path ending in .json names the file). Not a test
(``tests/bench/test_fuzz_case_cost.py`` runs ``--smoke``: the 2-asset case, one round, so it keeps working). It sets
its process's thread counts as a fuzz worker's: run it in a process of its own.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time

# as the fuzz's worker processes run (tests/fuzz_inputs._Worker): one thread each, set before torch/numba load
for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))

import fuzz_inputs as F  # noqa: E402
from scpainter_blender.core import outputs  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)
import provenance  # noqa: E402  (bench/, the script's folder)

#: --cases value -> the fuzz case's description (tests/fuzz_inputs.JOB_FAMILIES, family "assets")
DESCRIPTIONS = {100: "assets: 100 assets on the same PLY", 50: "assets: 50 assets on the same PLY",
                2: "assets: two assets on one PLY"}
UNTIMED_S = 600.0     # the alarm while measuring: far above the budget, so the whole case is timed


def find_index(description: str, base: F.Base, seed: int) -> int:
    """The first ``job`` case index whose description is ``description``."""
    for i in range(F.CASES["job"]):
        if F.make_case("job", i, seed, base).description == description:
            return i
    raise LookupError(f"no job case {description!r} in tests/fuzz_inputs.py")


def run_once(case: F.Case, base: F.Base, workdir: str, check: bool) -> dict:
    """One run of ``case`` as ``fuzz_inputs.run_case`` runs it (case folder built, ``invoke`` in this process,
    classified), timed: {cpu_s, wall_s, outcome, message}."""
    root = os.path.join(workdir, f"{case.kind}-{case.index:04d}")
    c = F.prepare(case, base, root)
    argv = F.command(case, c, check)
    names = F._case_names(c, case)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    ran = F.invoke(argv, UNTIMED_S)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    result = {"message": "", "file": None, "field": None}
    outcome = F.classify(result, ran, [], names, UNTIMED_S)
    shutil.rmtree(root, ignore_errors=True)
    return {"cpu_s": cpu, "wall_s": wall, "outcome": outcome, "message": result["message"]}


def measure(counts, rounds: int, seed: int = F.SEED, indices=()) -> list:
    """[{assets, description, index, cpu_s: [...], wall_s: [...], outcomes, messages}] for each asset count of
    ``counts`` (``DESCRIPTIONS``), then each ``job`` case index of ``indices`` (``assets``: None)."""
    import numba
    import torch

    torch.set_num_threads(1)
    numba.set_num_threads(1)
    workdir = tempfile.mkdtemp(prefix="scpainter-fuzz-cost-", dir=F._scratch_parent())
    try:
        base = F.Base(os.path.join(workdir, "base"))
        check = F.has_check_option()
        warm = run_once(F.base_case("job", seed), base, workdir, check)   # the worker's warm-up, untimed
        if warm["outcome"] != "accepted":
            raise RuntimeError(f"the valid job is not accepted: {warm}")
        rows = []
        todo = [(n, find_index(DESCRIPTIONS[n], base, seed)) for n in counts] + [(None, i) for i in indices]
        for n, index in todo:
            case = F.make_case("job", index, seed, base)
            runs = [run_once(case, base, workdir, check) for _ in range(rounds)]
            rows.append({"assets": n, "description": case.description, "index": index,
                         "cpu_s": [round(r["cpu_s"], 3) for r in runs],
                         "wall_s": [round(r["wall_s"], 3) for r in runs],
                         "outcomes": sorted({r["outcome"] for r in runs}),
                         "messages": sorted({r["message"] for r in runs if r["message"]})})
        return rows
    finally:
        shutil.rmtree(workdir, ignore_errors=True)


def format_table(rows: list) -> str:
    heads = ("case", "job index", "CPU s median", "CPU s worst", "wall s median", "wall s worst",
             f"worst / budget ({F.TIMEOUT_S:g} CPU s)", "outcome")
    cells = [[r["description"], str(r["index"]), f"{statistics.median(r['cpu_s']):.3f}", f"{max(r['cpu_s']):.3f}",
              f"{statistics.median(r['wall_s']):.3f}", f"{max(r['wall_s']):.3f}",
              f"{max(r['cpu_s']) / F.TIMEOUT_S:.0%}", ", ".join(r["outcomes"])] for r in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, h in enumerate(heads)]
    line = lambda cs: "| " + " | ".join(c.ljust(w) if i == 0 else c.rjust(w)  # noqa: E731
                                        for i, (c, w) in enumerate(zip(cs, widths))) + " |"
    return "\n".join([line(heads), "|" + "|".join("-" * (w + 2) for w in widths) + "|"] + [line(c) for c in cells])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--label", default="after", help="before | after (recorded in the JSON)")
    p.add_argument("--cases", nargs="*", type=int, choices=sorted(DESCRIPTIONS), default=[100, 50, 2],
                   help="the cases, by asset count")
    p.add_argument("--job-index", nargs="*", type=int, default=[], help="more job cases, by index")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--seed", type=int, default=F.SEED)
    bench_cli.add_smoke_and_out(p, "the 2-asset case, one round")
    args = p.parse_args(argv)
    if args.smoke:
        args.cases, args.rounds, args.job_index = [2], 1, []
    args.out = bench_cli.json_path(args.out, "fuzz_case_cost")

    rows = measure(args.cases, args.rounds, args.seed, args.job_index)
    commit, dirty = provenance.commit_and_dirty(ROOT)
    print(f"fuzz case cost ({args.label}): commit {commit}{' + local changes' if dirty else ''}, seed {args.seed}, "
          f"{args.rounds} round(s), one thread, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(format_table(rows))
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    outputs.write_json(args.out, {
        "label": args.label, "commit": commit, "local_changes": dirty, "seed": args.seed, "rounds": args.rounds,
        "budget_cpu_s": F.TIMEOUT_S, "budget_wall_s": F.TIMEOUT_S * F.WALL_FACTOR,
        "machine": {"cpus": os.cpu_count(), "load_average": round(os.getloadavg()[0], 2),
                    "platform": platform.platform(), "python": platform.python_version()},
        "cases": rows})
    print(f"\nwrote {os.path.relpath(args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
