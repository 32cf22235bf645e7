"""Box proposals on the ground-truth street (issue 41: ≤ 2 s): the reconstruction's points loaded as the renderer
loads them (``variants.scene_points``) and ``core.variation.proposals.propose`` on them, timed apart, for the
street's recorded drive without labels (its parked cars are what is proposed) and with the street's own cars as
recorded objects (everything covered: nothing proposed).

    .venv/bin/python bench/proposals.py [--rounds 5] [--out bench/results] [--json FILE] [--label TEXT] [--smoke]

Each round starts cold (no cache: ``propose`` is called directly, not through the per-process cache of
``with_proposals``). Prints a table (median and worst of the rounds, seconds) and saves it as JSON. Not a test
(tests/bench/test_proposals.py runs ``--smoke``: one round).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))

import numpy as np  # noqa: E402

import bench_cli  # noqa: E402  (bench/, the script's folder)
import provenance  # noqa: E402  (bench/, the script's folder)
from scpainter_blender.core import job as job_mod, outputs  # noqa: E402
from scpainter_blender.core.variation import proposals, variants  # noqa: E402
from scpainter_blender.street.dataset import ensure_street  # noqa: E402
from tests_support import street_base_job  # noqa: E402

#: The issue's budget for the street (seconds, points loading included).
BUDGET_S = 2.0


def measure(job_path: str, rounds: int) -> dict:
    """Seconds of each round's two steps (load, propose) and what the last round proposed."""
    job = job_mod.load(job_path)
    load, propose, found = [], [], []
    for _ in range(rounds):
        t0 = time.perf_counter()
        points = variants.scene_points(job, job_path)
        t1 = time.perf_counter()
        found = proposals.propose(points, job)
        t2 = time.perf_counter()
        load.append(t1 - t0)
        propose.append(t2 - t1)
    total = [a + b for a, b in zip(load, propose)]
    return {"points": int(len(points)), "load_s": load, "propose_s": propose, "total_s": total,
            "median_total_s": float(np.median(total)), "worst_total_s": float(max(total)),
            "proposals": [{"id": p.id, "class": p.category, "size": [round(float(v), 3) for v in p.size]}
                          for p in found]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--json", help="the JSON file (default: proposals.json in --out)")
    p.add_argument("--label", default="")
    bench_cli.add_smoke_and_out(p, "one round")
    args = p.parse_args(argv)
    if args.smoke:
        args.rounds, args.label = 1, args.label or "smoke"
    args.json = args.json or bench_cli.json_path(args.out, "proposals")
    street = ensure_street()
    commit, dirty = provenance.commit_and_dirty(ROOT)
    cases = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, recorded in (("street, no labels", False), ("street, its cars recorded", True)):
            path = os.path.join(tmp, name.replace(",", "").replace(" ", "_"), "job.json")
            street_base_job(street, path, recorded_cars=recorded)
            cases[name] = measure(path, args.rounds)
    print(f"\nbox proposals on the street ({platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; "
          f"commit {commit}{' +changes' if dirty else ''}; {args.rounds} rounds, budget {BUDGET_S:.0f} s)")
    print(f"{'case':<28} {'points':>9} {'load s':>7} {'propose s':>9} {'total s':>8} {'worst s':>8} {'proposed':>8}")
    for name, c in cases.items():
        print(f"{name:<28} {c['points']:>9} {np.median(c['load_s']):>7.2f} {np.median(c['propose_s']):>9.2f} "
              f"{c['median_total_s']:>8.2f} {c['worst_total_s']:>8.2f} {len(c['proposals']):>8}")
    os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
    outputs.write_json(args.json, {"label": args.label, "commit": commit, "dirty": dirty, "rounds": args.rounds,
                                   "budget_s": BUDGET_S, "cpus": os.cpu_count(), "cases": cases})
    return 0


if __name__ == "__main__":
    sys.exit(main())
