"""The allocation tracker counts what lives, and the fake-tensor estimate of a tiny training step counts the
persistent state exactly (weights, AdamW's two moments, the EMA: 4, 8 and 4 bytes per trained parameter)."""

import torch

from backend.train import memory


def test_tracker_counts_storages_once_and_frees_them():
    tr = memory.AllocationTracker()
    with tr:
        with tr.in_phase("a"):
            x = torch.zeros(1024, 256)          # 1 MiB
            v = x[:10].view(-1)                 # a view: no new storage
        y = torch.ones(512, dtype=torch.float64)  # 4 KiB, phase "other"
        assert tr.now["a"] == 2 ** 20 and tr.now["other"] == 4096
        tr.label(y, "b")
        assert tr.now["other"] == 0 and tr.now["b"] == 4096
        del x, v
        z = torch.empty(16)
    assert tr.now["a"] == 0 and tr.total == 4096 + 64 and tr.peak == 2 ** 20 + 4096
    assert tr.at_peak == {"a": 2 ** 20, "other": 4096}
    del y, z


def test_estimate_of_a_tiny_step_counts_the_state_exactly():
    """One fake-tensor step of the tiny model (the full model's estimate is the same code: bench/train_throughput.py
    --estimate): the persistent state to the byte, the condition encoder's one-frame chunks keep nothing of their
    own for backward (they are checkpointed), the peak is what was live at it."""
    models = memory.build("tiny", "cpu", torch.bfloat16, fake=True)
    n = sum(p.numel() for m in ("unet", "condition_encoder") for p in models[m].parameters())
    e = memory.estimate(memory.Setting(2), "tiny", 2, (128, 64), models=models)
    assert e.kept["weights (trained)"] == 4 * n and e.kept["EMA"] == 4 * n
    assert e.kept["AdamW state"] == 8 * n + 4 * len(list(models["unet"].parameters()) +
                                                   list(models["condition_encoder"].parameters()))
    assert e.at_peak["gradients"] <= 4 * n and e.kept.get("condition encoder", 0) == 0 and e.kept["UNet"] > 0
    assert e.peak == sum(e.at_peak.values()) and e.phase_peak["backward"] == e.peak
    assert e.kept["weights (frozen)"] == 2 * sum(p.numel() for m in ("vae", "image_encoder")
                                                 for p in models[m].parameters())
    # a step carries nothing into the next but the persistent state and its loss (a scalar)
    left = e.extra["left_after_step"]
    assert set(left) - {"other"} == {"weights (trained)", "weights (frozen)", "AdamW state", "EMA"}
    assert left.get("other", 0) <= 16
