"""The documented short training run: the tiny model fine-tuned on the ground-truth street, then evaluated.

    make train-street            (= .venv/bin/python tools/train_street.py)

Steps, all under build/train_street/ (each skipped when its output exists, so a second run resumes):
1. the street (cached) exported as a training clip (backend.train.street_clip);
2. a tiny SVD (backend.model.configs "tiny"): random weights, except that its VAE is first fitted as an
   autoencoder to the recorded frames (a few hundred steps) — a stand-in for SVD's pretrained VAE, without which
   no UNet could produce an image — and an SCPainter checkpoint made from it (python -m backend init-checkpoint);
3. python -m backend train train.json (CPU; resumes from its newest checkpoint);
4. python -m backend evaluate on the same street: PSNR/SSIM of the shifted drives against the Cycles renders,
   for the trained model and for the condition-only baseline; FID/KID too with --inception PATH.

The street is both training and evaluation data here (one clip exists): this checks that the machinery runs end
to end and measures against true ground truth, not generalisation. The tiny model cannot make good images.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def backend(*args) -> None:
    cmd = [sys.executable, "-m", "backend", *map(str, args)]
    print("+", " ".join(cmd), flush=True)
    p = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, text=True)
    done = [json.loads(line) for line in p.stdout.splitlines() if line.startswith('{"event": "done"')]
    if p.returncode != 0 or not done:
        errors = [line for line in p.stdout.splitlines() if '"error"' in line]
        sys.exit(f"train_street: {' '.join(cmd)} failed ({p.returncode}): {errors[-1:] or 'see stderr'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "build", "train_street"))
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--inception", help="FID Inception weights file (optional)")
    args = ap.parse_args()
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)

    from backend.model import configs
    from backend.train import street_clip, vae_fit
    from scpainter_blender.core import outputs
    from scpainter_blender.street.dataset import ensure_street

    clip = street_clip.export_clip(ensure_street(log=print), os.path.join(out, "street_clip"))
    svd, ckpt = os.path.join(out, "svd-tiny"), os.path.join(out, "scpainter-tiny")
    if not os.path.isdir(svd):
        from backend.train import clip as clip_mod

        with outputs.atomic_folder(svd) as tmp:
            configs.save_stock_svd(tmp, "tiny", seed=0)
            print("fit tiny VAE:", vae_fit.fit_vae(tmp, clip_mod.load(clip), 128, 64, log=print))
    if not os.path.isdir(ckpt):
        backend("init-checkpoint", "--svd", svd, "--out", ckpt)
    cfg = {"schema": "scpainter.train/1", "checkpoint": "scpainter-tiny", "clips": ["street_clip"],
           "output_dir": "run", "pairs": {"width": 128, "height": 64, "frames": 8},
           "steps": args.steps, "batch_size": 1, "learning_rate": 2e-4, "warmup_steps": 20, "ema_decay": 0.99,
           "save_every": 100, "log_every": 10, "sample_every": 100, "sample_steps": 10, "num_workers": 1, "seed": 0}
    outputs.write_json(os.path.join(out, "train.json"), cfg)
    backend("train", os.path.join(out, "train.json"), "--device", "cpu")
    trained = sorted(os.listdir(os.path.join(out, "run", "checkpoints")))[-1]
    extra = ["--inception", args.inception] if args.inception else []
    for name, ck in (("trained", os.path.join(out, "run", "checkpoints", trained)), ("untrained", ckpt)):
        backend("evaluate", os.path.dirname(clip), "--output-dir", os.path.join(out, f"evaluate_{name}"),
                "--checkpoint", ck, "--resolution", 128, 64, "--frames", 8, "--steps", 10, "--device", "cpu", *extra)
    from backend.evaluate.protocol import format_table

    for name in ("untrained", "trained"):
        with open(os.path.join(out, f"evaluate_{name}", "evaluation.json")) as f:
            print(f"\n== {name} checkpoint ==\n" + format_table(json.load(f)))


if __name__ == "__main__":
    main()
