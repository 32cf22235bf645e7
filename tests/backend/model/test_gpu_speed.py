"""The generate settings ``compile`` and ``gpu_tuning`` run: torch.compile of the tiny UNet on the CPU (inductor's
cache in the user's cache folder unless set), the same latents up to rounding; tuning changes nothing on the CPU."""

import os

import pytest
import torch

from backend.model import gpu_speed
from backend.model.pipeline import SCPainterPipeline


def test_gpu_tuning_is_a_no_op_on_the_cpu():
    net = torch.nn.Conv2d(3, 4, 3)
    assert gpu_speed.tune_unet(net, "cpu", "on") is net and net.weight.is_contiguous()
    before = torch.backends.cudnn.benchmark
    with gpu_speed.tuned("cpu", "on"):
        assert torch.backends.cudnn.benchmark == before


def test_a_channels_last_unet_computes_the_same():
    """gpu_tuning's channels-last conversion on SVD's UNet class (2D and 3D convolutions): same output."""
    from diffusers import UNetSpatioTemporalConditionModel

    from backend.model import configs

    torch.manual_seed(0)
    unet = UNetSpatioTemporalConditionModel(**configs.TINY["unet"]).eval()
    g = torch.Generator().manual_seed(1)
    args = (torch.randn(1, 3, 8, 8, 8, generator=g), torch.rand(1, generator=g), torch.randn(1, 1, 32, generator=g),
            torch.randn(1, 3, generator=g))
    with torch.no_grad():
        ref = unet(*args[:2], encoder_hidden_states=args[2], added_time_ids=args[3], return_dict=False)[0]
        gpu_speed.channels_last(unet)
        assert unet.conv_in.weight.is_contiguous(memory_format=torch.channels_last)
        out = unet(*args[:2], encoder_hidden_states=args[2], added_time_ids=args[3], return_dict=False)[0]
    assert torch.allclose(out, ref, atol=1e-5)


def test_the_inductor_cache_is_the_users_unless_set(monkeypatch, tmp_path):
    monkeypatch.delenv(gpu_speed.INDUCTOR_CACHE, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert gpu_speed.inductor_cache_dir() == os.path.join(str(tmp_path), "scpainter", "inductor")
    monkeypatch.setenv(gpu_speed.INDUCTOR_CACHE, str(tmp_path / "mine"))
    assert gpu_speed.inductor_cache_dir() == str(tmp_path / "mine")


def test_the_inductor_cache_is_the_users_after_diffusers_set_torchs_default(monkeypatch, tmp_path):
    """Importing diffusers makes inductor write its own default (/tmp/torchinductor_<user>) into
    $TORCHINDUCTOR_CACHE_DIR before any UNet is compiled: that is not the user's choice, so the kernels still go to
    the user's cache folder (they went to /tmp, emptied by a reboot, before)."""
    from torch._inductor.runtime.cache_dir_utils import cache_dir, default_cache_dir

    monkeypatch.delenv(gpu_speed.INDUCTOR_CACHE, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_dir() == os.path.abspath(default_cache_dir())      # what `import diffusers` does on the way
    assert gpu_speed.inductor_cache_dir() == os.path.join(str(tmp_path), "scpainter", "inductor")
    assert cache_dir() == os.path.join(str(tmp_path), "scpainter", "inductor")   # where inductor now writes


@pytest.mark.slow
@pytest.mark.parametrize("feature_reuse", [1, 2])
def test_a_compiled_unet_samples_the_same_latents(tiny_checkpoint, monkeypatch, tmp_path, feature_reuse):
    """torch.compile (default mode) of the whole UNet, or of the written-out forward with feature reuse; on the CPU
    (inductor's C++ kernels): the latents agree with eager to rounding. Slow: compiling takes ~1 min here."""
    monkeypatch.setenv(gpu_speed.INDUCTOR_CACHE, str(tmp_path / "inductor"))
    pipe = SCPainterPipeline.from_checkpoint(tiny_checkpoint)
    gen = torch.Generator().manual_seed(0)
    cond, clip = torch.randn(2, 4, 4, 4, generator=gen), torch.randn(1, 1, 32, generator=gen)
    kw = dict(steps=2, seed=1, feature_reuse=feature_reuse, guidance_sigma_max=1e10)
    eager = pipe.sample(cond, clip, **kw)
    pipe.set_speed("default", "on")
    compiled = pipe.sample(cond, clip, **kw)
    assert torch.allclose(compiled, eager, rtol=1e-4, atol=1e-4)
    assert os.listdir(tmp_path / "inductor")      # kernels cached for the next process
