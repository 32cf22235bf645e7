"""CLIP's input normalisation is written once (backend/model/checkpoint.py: CLIP_MEAN, CLIP_STD)."""

import os
import subprocess

from backend.model import checkpoint, configs

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def test_the_stock_feature_extractor_uses_the_constants():
    fe = configs.build_components("tiny")["feature_extractor"]
    assert tuple(fe.image_mean) == checkpoint.CLIP_MEAN and tuple(fe.image_std) == checkpoint.CLIP_STD


def test_the_clip_mean_and_std_are_written_only_in_their_home():
    files = subprocess.run(["git", "ls-files", "*.py"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    hits = []
    for f in files:
        if f.startswith("tests/") or f == "backend/model/checkpoint.py":
            continue
        with open(os.path.join(ROOT, f), encoding="utf-8") as fh:
            text = fh.read()
        hits += [f"{f}: {v!r}" for v in checkpoint.CLIP_MEAN + checkpoint.CLIP_STD if repr(v) in text]
    assert hits == []
