"""How the UNet runs on a GPU, results unchanged up to rounding: the generate settings ``compile`` and ``gpu_tuning``
(docs/design.md §11; bench/generate.py measures both on CUDA).

``compile`` (``job.GENERATE_COMPILE``): ``off``; ``default`` / ``max-autotune``: ``torch.compile`` of the UNet in that
mode; ``reduce-overhead``: the same with CUDA graphs (the whole evaluation replayed as one graph: no per-kernel
launch cost). The first evaluation of each input shape compiles (minutes for SVD's UNet; bench/generate.py reports
it apart from the run time); the compiled kernels go to inductor's on-disk caches (FX graph and autotuning) in
``$TORCHINDUCTOR_CACHE_DIR``, which ``compile_unet`` points at the user's cache
(``~/.cache/scpainter/inductor``, ``core.user_cache``) unless it is set, so a second process with the same shapes
loads them instead of compiling again.

``gpu_tuning`` ``on`` (CUDA only; on the CPU it changes nothing): cuDNN picks the fastest convolution algorithm per
shape (``cudnn.benchmark``), the UNet's weights are channels-last (Hopper's tensor-core convolutions are NHWC), and
scaled-dot-product attention tries cuDNN's fused kernel, then FlashAttention, then the memory-efficient one, before
the plain one (``torch.nn.attention.sdpa_kernel`` with ``set_priority``). ``tuned`` is the context it runs in.
"""

from __future__ import annotations

import contextlib
import os

import torch

from scpainter_blender.core.user_cache import user_cache_dir

INDUCTOR_CACHE = "TORCHINDUCTOR_CACHE_DIR"


def inductor_cache_dir() -> str:
    """Where compiled kernels are kept across runs: ``$TORCHINDUCTOR_CACHE_DIR``, set to the user's cache folder
    (``~/.cache/scpainter/inductor``) when the user did not set it; inductor's FX graph cache is switched on there.
    Not set by the user includes set to torch's own default (``/tmp/torchinductor_<user>``, which a reboot empties):
    inductor writes that default into the environment the first time it asks for its cache folder, which importing
    diffusers already does, so by the time a UNet is compiled the variable is always present."""
    from torch._inductor.runtime.cache_dir_utils import default_cache_dir

    chosen = os.environ.get(INDUCTOR_CACHE)
    if not chosen or os.path.abspath(chosen) == os.path.abspath(default_cache_dir()):
        os.environ[INDUCTOR_CACHE] = user_cache_dir("inductor")
    os.environ.setdefault("TORCHINDUCTOR_FX_GRAPH_CACHE", "1")
    return os.environ[INDUCTOR_CACHE]


def compile_fn(fn, mode: str):
    """``fn`` (a module or function) compiled with ``torch.compile`` in ``mode`` (``GENERATE_COMPILE``; ``off``:
    ``fn`` itself). Shapes are static (one video size per run): no dynamic-shape guards."""
    if mode == "off":
        return fn
    inductor_cache_dir()
    return torch.compile(fn, mode=None if mode == "default" else mode, dynamic=False)


def channels_last(net: torch.nn.Module) -> torch.nn.Module:
    """The weights of ``net``'s 2D convolutions made channels-last, in place (``Module.to(memory_format=...)``
    would refuse SVD's UNet: its temporal layers are 3D convolutions, whose 5D weights have no channels-last)."""
    for m in net.modules():
        if isinstance(m, torch.nn.Conv2d):
            m.weight.data = m.weight.data.contiguous(memory_format=torch.channels_last)
    return net


def tune_unet(unet: torch.nn.Module, device: str | torch.device, setting: str) -> torch.nn.Module:
    """``unet`` made channels-last (``channels_last``) on CUDA when ``setting`` is ``on``; nothing elsewhere."""
    if setting == "on" and torch.device(device).type == "cuda":
        channels_last(getattr(unet, "_orig_mod", unet))
    return unet


@contextlib.contextmanager
def tuned(device: str | torch.device, setting: str):
    """The attention kernel order and cuDNN autotuning of ``gpu_tuning`` ``on`` on CUDA, for the ``with`` block
    (restored after); elsewhere nothing."""
    if setting != "on" or torch.device(device).type != "cuda":
        yield
        return
    from torch.nn.attention import SDPBackend, sdpa_kernel

    order = [SDPBackend.CUDNN_ATTENTION, SDPBackend.FLASH_ATTENTION, SDPBackend.EFFICIENT_ATTENTION, SDPBackend.MATH]
    before = torch.backends.cudnn.benchmark
    torch.backends.cudnn.benchmark = True
    try:
        with sdpa_kernel(order, set_priority=True):
            yield
    finally:
        torch.backends.cudnn.benchmark = before

