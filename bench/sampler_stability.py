"""The EDM sampler's arithmetic in fp16 and bf16 against float64: where low precision breaks, and our path.

    .venv/bin/python bench/sampler_stability.py [--smoke] [--out bench/results]

For σ from σ_max = 700 down to σ_min = 0.002 and guidance scales 1–15, on latents of SVD's scale (x_0 ~ N(0, 1)):

* ``all-<dtype>``: the preconditioned input c_in·x, the v → x_0 conversion and the guidance mix computed entirely
  in that dtype (what a pipeline that casts its latents to the model dtype does);
* ``ours-<dtype>``: what ``backend.model.pipeline`` does — latents, schedule and every formula in float32, only
  the UNet's input and output pass through the dtype (modelled by rounding them to it).

Prints the max abs error of x_0 against float64 and whether anything was inf/NaN; writes
bench/results/sampler_stability.json. CPU only: this is arithmetic, not speed. ``--smoke``: σ_max and σ_min, guidance 1 and 15, a 4 x 8 x 16 latent.
"""

from __future__ import annotations

import argparse
import os
import sys

import torch

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

from backend import events  # noqa: E402
from backend.model import configs, edm  # noqa: E402
from scpainter_blender.core import outputs  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)

DTYPES = {"fp16": torch.float16, "bf16": torch.bfloat16, "fp32": torch.float32}
SVD = edm.Schedule.from_config(configs.SCHEDULER)   # SVD's scheduler config: σ from 700 to 0.002


def case(sigma: float, scale: float, seed: int = 0, n: int = 4 * 72 * 128):
    g = torch.Generator().manual_seed(seed)
    x0 = torch.randn(n, generator=g, dtype=torch.float64)
    x = x0 + sigma * torch.randn(n, generator=g, dtype=torch.float64)
    s = torch.tensor(sigma, dtype=torch.float64)
    v_c = (x / (s * s + 1) - x0) * torch.sqrt(s * s + 1) / s          # the v that denoises exactly
    v_u = v_c + 0.1 * torch.randn(n, generator=g, dtype=torch.float64)  # an unconditional branch that differs
    ref_in = edm.c_in(s) * x
    ref = edm.v_to_x0(x, edm.guide(v_u, v_c, torch.tensor(scale, dtype=torch.float64)), s)
    rows = []
    for name, dt in DTYPES.items():
        # everything in dt
        xs, ss = x.to(dt), s.to(dt)
        inp = edm.c_in(ss) * xs
        mix = edm.guide(v_u.to(dt), v_c.to(dt), torch.tensor(scale, dtype=dt))
        x0_all = edm.v_to_x0(xs, mix, ss)
        # ours: float32 math, the network's input and output rounded to dt
        xf, sf = x.float(), s.float()
        inp_ours = (edm.c_in(sf) * xf).to(dt).float()
        mix_ours = edm.guide(v_u.to(dt).float(), v_c.to(dt).float(), torch.tensor(scale))
        x0_ours = edm.v_to_x0(xf, mix_ours, sf)
        for path, i, out in (("all", inp, x0_all), ("ours", inp_ours, x0_ours)):
            finite = bool(torch.isfinite(i).all() and torch.isfinite(out).all())
            rows.append({"sigma": sigma, "guidance": scale, "path": f"{path}-{name}", "finite": finite,
                         "max_abs_err_input": float((i.double() - ref_in).abs().max()) if finite else None,
                         "max_abs_err_x0": float((out.double() - ref).abs().max()) if finite else None})
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    bench_cli.add_smoke_and_out(p, "σ_max and σ_min, guidance 1 and 15, a small latent")
    args = p.parse_args(argv)
    sigmas = (SVD.sigma_max, SVD.sigma_min) if args.smoke else (SVD.sigma_max, 100.0, 1.0, 0.01, SVD.sigma_min)
    rows = []
    for sigma in sigmas:
        for scale in ((1.0, 15.0) if args.smoke else (1.0, 3.0, 7.5, 15.0)):
            rows += case(sigma, scale, n=4 * 8 * 16) if args.smoke else case(sigma, scale)
    print("sigma | guidance | path | finite | max |Δ c_in·x| | max |Δ x0|")
    print("--- | --- | --- | --- | --- | ---")
    for r in rows:
        if r["guidance"] in (1.0, 15.0) or r["sigma"] in (SVD.sigma_max, SVD.sigma_min):
            e_in = "inf/NaN" if r["max_abs_err_input"] is None else f"{r['max_abs_err_input']:.2e}"
            e_x0 = "inf/NaN" if r["max_abs_err_x0"] is None else f"{r['max_abs_err_x0']:.2e}"
            print(f"{r['sigma']:g} | {r['guidance']:g} | {r['path']} | {r['finite']} | {e_in} | {e_x0}")
    path = bench_cli.json_path(args.out, "sampler_stability")
    outputs.write_json(path, events.json_safe(rows))
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
