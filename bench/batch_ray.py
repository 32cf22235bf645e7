"""Ray against static sharding on a job list of uneven lengths, on this machine's CPUs.

    .venv/bin/python bench/batch_ray.py [--workers 2] [--long 160] [--short 2] [--jobs 8] [--size 320 240]
                                        [--repeats 2] [--out bench/results] [--ray-address HEAD:PORT] [--smoke]

The jobs (``tests_support.small_job``: synthetic predictions and a 300-Gaussian car) alternate long and short
(``--long`` and ``--short`` frames at ``--size``), so static sharding (``torchrun --standalone --nproc_per_node N
-m backend batch``: rank r takes jobs r, r + N, …) gives rank 0 every long job, while Ray (``batch --ray`` on a local
cluster of N CPUs started beforehand with ``ray start``, as a pipeline's is, one CPU per job) hands each job to
whichever worker is free. Both arms run the same command line in a fresh process (the arms alternated ``--repeats``
times), each on fresh copies of the jobs, one thread per worker (``NUMBA_NUM_THREADS`` and ``OMP_NUM_THREADS`` 1, so
N workers use N cores). Reported: wall time of the command, and per worker its busy time
(the sum of its jobs' own ``seconds``) and idle time (wall − busy: start-up, waiting for the slowest rank, and
scheduling). Prints a table; writes bench/results/batch_ray.json (``--out DIR``, or a path ending in .json). It runs
``ray stop --force`` after each Ray arm, which ends every Ray process on the machine: run it alone, never beside the
tests. ``--ray-address``: the Ray arm joins that running cluster instead (nothing started or stopped; its start is
not the batch's time either). ``--smoke``: one worker, two jobs of 2 and 1 frames at 32 x 24, one repeat, the Ray
arm on ``--ray-address`` or, without one, on a local cluster of its own that ends with the command
(``--ray local``), never ``ray stop`` (what tests/bench/test_batch_ray.py runs beside the other tests).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))

import bench_cli  # noqa: E402  (bench/, the script's folder)


def make_jobs(folder: str, n: int, long: int, short: int, size) -> list:
    from tests_support import small_job

    return [small_job(os.path.join(folder, f"job{i:02d}"), frames=tuple(range(1, 1 + (long if i % 2 == 0 else short))),
                      resolution=tuple(size)) for i in range(n)]


def run(arm: str, jobs: list, workers: int, ray_address: str | None = None) -> dict:
    """One arm's command on ``jobs``; ``ray_address``: the Ray arm joins it (``local``: a cluster of the command's
    own) instead of a ``ray start`` cluster of ``workers`` CPUs stopped afterwards."""
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "PYTHONPATH": ROOT}
    env.pop("RAY_ADDRESS", None)
    ray_bin = None
    if arm == "static":
        cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={workers}",
               "-m", "backend", "batch", *jobs, "--command", "render", "--device", "cpu"]
    elif ray_address:
        cmd = [sys.executable, "-m", "backend", "batch", *jobs, "--command", "render", "--device", "cpu",
               "--ray", ray_address]
    else:  # a cluster already running, as a pipeline has one: its start is not the batch's time
        ray_bin = os.path.join(os.path.dirname(sys.executable), "ray")
        subprocess.run([ray_bin, "start", "--head", f"--num-cpus={workers}", "--num-gpus=0",
                        "--include-dashboard=false", "--disable-usage-stats"], env=env, check=True,
                       capture_output=True)
        cmd = [sys.executable, "-m", "backend", "batch", *jobs, "--command", "render", "--device", "cpu",
               "--ray", "auto"]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=1800)
    finally:
        if ray_bin:
            subprocess.run([ray_bin, "stop", "--force"], env=env, capture_output=True)
    wall = time.perf_counter() - t0
    done = [json.loads(line) for line in p.stdout.splitlines() if line.startswith('{"event": "done"')]
    if p.returncode != 0 or not done:
        sys.exit(f"{arm} failed ({p.returncode}): {p.stderr[-2000:]}")
    busy = {}
    for item in done[-1]["items"]:
        who = f"rank {item['rank']}" if arm == "static" else f"worker {item['worker'].split(':')[-1]}"
        busy[who] = busy.get(who, 0.0) + item["seconds"]
    return {"arm": arm, "wall_s": wall, "busy_s": busy, "idle_s": {k: wall - v for k, v in busy.items()},
            "jobs": len(done[-1]["items"])}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=8)
    ap.add_argument("--long", type=int, default=160)
    ap.add_argument("--short", type=int, default=2)
    ap.add_argument("--size", type=int, nargs=2, default=[320, 240])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--ray-address", help="the Ray arm joins this running cluster (nothing started or stopped)")
    bench_cli.add_smoke_and_out(ap, "one worker, two short jobs at 32 x 24, one repeat, no ray start/stop")
    args = ap.parse_args(argv)
    if args.smoke:
        args.workers, args.jobs, args.long, args.short, args.size, args.repeats = 1, 2, 2, 1, [32, 24], 1
        args.ray_address = args.ray_address or "local"
    work = tempfile.mkdtemp(prefix="batch_ray_")
    rows = []
    for r in range(args.repeats):  # alternated, so a change in the machine's load hits both arms
        for arm in ("static", "ray"):
            folder = os.path.join(work, f"{arm}{r}")
            rows.append(run(arm, make_jobs(folder, args.jobs, args.long, args.short, args.size), args.workers,
                            args.ray_address))
    shutil.rmtree(work, ignore_errors=True)
    print(f"\n{args.jobs} render jobs alternating {args.long} and {args.short} frames at "
          f"{args.size[0]}x{args.size[1]}, {args.workers} workers, one thread each")
    print("| arm | wall s | busy s per worker | idle s per worker | idle share |\n|---|---|---|---|---|")
    for r in rows:
        idle = sum(r["idle_s"].values()) / (r["wall_s"] * max(len(r["idle_s"]), 1))
        print(f"| {r['arm']} | {r['wall_s']:.1f} | {', '.join(f'{v:.1f}' for v in r['busy_s'].values())} | "
              f"{', '.join(f'{v:.1f}' for v in r['idle_s'].values())} | {idle:.0%} |")
    from scpainter_blender.core import outputs

    outputs.write_json(bench_cli.json_path(args.out, "batch_ray"), {"settings": vars(args), "rows": rows})


if __name__ == "__main__":
    main()
