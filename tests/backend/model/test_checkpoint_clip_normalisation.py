"""CLIP's input normalisation is written once (backend/model/checkpoint.py: CLIP_MEAN, CLIP_STD)."""

from backend.model import checkpoint, configs


def test_the_stock_feature_extractor_uses_the_constants():
    fe = configs.build_components("tiny")["feature_extractor"]
    assert tuple(fe.image_mean) == checkpoint.CLIP_MEAN and tuple(fe.image_std) == checkpoint.CLIP_STD


def test_the_clip_mean_and_std_are_written_only_in_their_home():
    from tests_support import tracked_sources

    hits = []
    for f, text in tracked_sources(exclude=("backend/model/checkpoint.py",)).items():
        hits += [f"{f}: {v!r}" for v in checkpoint.CLIP_MEAN + checkpoint.CLIP_STD if repr(v) in text]
    assert hits == []
