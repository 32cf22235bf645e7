"""Tiny SVD snapshots and SCPainter checkpoints built from configs (random weights, nothing downloaded)."""

import pytest


@pytest.fixture(scope="session")
def tiny_svd(tmp_path_factory):
    from backend.model import configs

    return configs.save_stock_svd(str(tmp_path_factory.mktemp("svd") / "svd-tiny"), "tiny", seed=0)


@pytest.fixture(scope="session")
def tiny_checkpoint(tiny_svd, tmp_path_factory):
    from backend.model import checkpoint

    return checkpoint.init_checkpoint(tiny_svd, str(tmp_path_factory.mktemp("ckpt") / "scpainter-tiny"))
