"""Where a training step's memory goes, measured without the memory: the step on fake tensors (docs/design.md §13).

``estimate`` builds the models of one size (``configs.SIZES``: "full" is SVD's architecture) on the meta device,
materialises them as ``FakeTensorMode`` tensors (shapes, dtypes and storages, no data: the full 1.56 B-parameter
model costs nothing), and runs ``step`` — the trainer's step: ``objective.loss``, backward, gradient clipping,
AdamW, EMA — under ``AllocationTracker`` (AdamW's state made beforehand), which follows every storage the
step creates and frees and labels it by what made it. The result is the peak of live bytes and what was live at
that moment, by label (``LABELS``), plus what the forward pass kept for backward and the peak of each phase.

Why not ``torch.distributed._tools.mem_tracker.MemTracker``: it updates every module's statistics on every
operator (one tiny-model step took 141 s); this tracker does a constant amount of work per operator (the full
model's step takes tens of seconds on fake tensors).

What the estimate is and is not. Fake tensors on the CPU run the CPU's kernels' shape rules, and CPU autocast keeps
group norm, layer norm and softmax in bf16 where CUDA's autocast computes them (and returns them) in float32; with
``cuda_autocast`` (the default) those three are run in float32 as CUDA's autocast would, so the activations have
CUDA's sizes. Attention is ``scaled_dot_product_attention`` on both (flash kernels: no L×L matrix is kept). Not
counted: cuDNN/cuBLAS workspaces, the CUDA caching allocator's rounding and fragmentation, the CUDA context —
``torch.cuda.max_memory_allocated`` on a GPU includes the workspaces, so it reads somewhat above the estimate.
"""

from __future__ import annotations

import contextlib
import time
import weakref
from collections import Counter
from dataclasses import dataclass, field

import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_leaves

from .view_settings import ViewSettings

#: (width, height) pixels of ``estimate``'s default: the paper's 1024 x 576, what bench/train_throughput.py and
#: the H200 run measured on CUDA (the training view's own default is ``ViewSettings``')
FULL_RESOLUTION = (1024, 576)

GIB = 2 ** 30

#: Labels of live memory, in the order tables print them. Persistent: the trained weights (float32 masters), the
#: frozen VAE and CLIP, gradients, AdamW's two moments, the EMA. Made by the forward pass and kept until backward
#: frees them: per model that made them. "backward": what the backward pass made that is live (recomputed
#: activations of checkpointed units, gradients of activations, gradients not yet accumulated into ``.grad``).
LABELS = ("weights (trained)", "weights (frozen)", "gradients", "AdamW state", "EMA", "target encoding (VAE)",
          "CLIP", "condition encoder", "UNet", "backward", "optimizer step", "EMA update", "batch", "other")


class AllocationTracker(TorchDispatchMode):
    """Live bytes of tensor storages by label, their peak, and what was live at the peak.

    Storages made inside the mode are labelled by ``phase`` (set with ``in_phase`` or by ``label_module``'s
    hooks), or "backward" while autograd's engine runs; ``label`` registers or relabels storages made elsewhere
    (parameters) or that change role (a gradient once accumulated, an optimizer state). A storage counts from its
    creation until Python frees it (a weak reference's callback), by ``nbytes``. Views share their base's storage
    and count once. Works on real and fake tensors."""

    def __init__(self) -> None:
        super().__init__()
        self._live: dict = {}          # id(storage) -> [nbytes, label, weakref]
        self.now = Counter()           # label -> live bytes
        self.total = self.peak = 0
        self.at_peak: dict = {}        # label -> bytes at the peak
        self.phase_peak: dict = {}     # phase -> highest total while it was the phase
        self.phase = "other"

    def _drop(self, key: int) -> None:
        entry = self._live.pop(key, None)
        if entry is not None:
            self.now[entry[1]] -= entry[0]
            self.total -= entry[0]

    def label(self, tensors, label: str) -> None:
        """Count (or relabel) the storages of ``tensors`` (a tensor, or an iterable or dict of them) as ``label``."""
        if isinstance(tensors, dict):
            tensors = tensors.values()
        for t in ([tensors] if isinstance(tensors, torch.Tensor) else tensors):
            if isinstance(t, torch.Tensor):
                self._track(t, label, relabel=True)
        self._update_peak()

    def _track(self, t: torch.Tensor, label: str, relabel: bool = False) -> None:
        try:
            st = t.untyped_storage()
        except (RuntimeError, NotImplementedError):   # a tensor without storage (sparse, nested)
            return
        key = id(st)
        entry = self._live.get(key)
        if entry is not None:
            if relabel and entry[1] != label:
                self.now[entry[1]] -= entry[0]
                self.now[label] += entry[0]
                entry[1] = label
            return
        n = st.nbytes()
        ref = weakref.ref(st, lambda _r, k=key: self._drop(k))
        self._live[key] = [n, label, ref]
        self.now[label] += n
        self.total += n

    def _update_peak(self) -> None:
        phase = "backward" if torch._C._current_graph_task_id() != -1 else self.phase
        if self.total > self.phase_peak.get(phase, -1):
            self.phase_peak[phase] = self.total
        if self.total > self.peak:
            self.peak = self.total
            self.at_peak = {k: v for k, v in self.now.items() if v}

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        label = "backward" if torch._C._current_graph_task_id() != -1 else self.phase
        for t in tree_leaves(out):
            if isinstance(t, torch.Tensor):
                self._track(t, label)
        self._update_peak()
        return out

    @contextlib.contextmanager
    def in_phase(self, phase: str):
        """Label what is made inside the block ``phase`` (the previous phase comes back after)."""
        old, self.phase = self.phase, phase
        try:
            yield
        finally:
            self.phase = old

    def label_module(self, module: torch.nn.Module, phase: str) -> list:
        """Hooks that set ``phase`` while ``module`` runs forward; returns their handles (``.remove()`` each)."""
        saved = []

        def pre(_m, _a):
            saved.append(self.phase)
            self.phase = phase

        def post(_m, _a, _o):
            self.phase = saved.pop()

        return [module.register_forward_pre_hook(pre), module.register_forward_hook(post)]


@contextlib.contextmanager
def cuda_autocast_norms(*roots: torch.nn.Module):
    """Under CPU autocast, run the group norms and layer norms of ``roots`` in float32, as CUDA's autocast does
    (both are on its fp32 list; CPU autocast leaves them in bf16): their outputs, which the next layers keep for
    backward, then have CUDA's size. Forward pre-hooks, so a checkpointed unit's recomputation does the same."""
    def to_fp32(_m, args):
        if torch.is_autocast_enabled("cpu"):
            return tuple(a.float() if isinstance(a, torch.Tensor) and a.is_floating_point() else a for a in args)
        return None

    handles = [m.register_forward_pre_hook(to_fp32) for r in roots for m in r.modules()
               if isinstance(m, (torch.nn.GroupNorm, torch.nn.LayerNorm))]
    try:
        yield
    finally:
        for h in handles:
            h.remove()


def step(models: dict, named: dict, optimizer: torch.optim.Optimizer, ema, batch: dict, cfg, gens: list,
         device, autocast, tracker: AllocationTracker | None = None, after_forward=None) -> torch.Tensor:
    """One optimiser step as ``Trainer.train`` takes it without accelerate (one process, no accumulation): loss,
    backward, clip to ``cfg.max_grad_norm``, AdamW, gradients set to None, EMA. Returns the loss (detached).
    ``tracker``: label the phases that are not a model's forward; ``after_forward()``: called between the loss and
    backward."""
    from . import objective

    phase = tracker.in_phase if tracker is not None else (lambda _p: contextlib.nullcontext())
    loss, _ = objective.loss(models, batch, cfg, gens, device, autocast)
    if after_forward is not None:
        after_forward()
    loss.backward()
    with phase("optimizer step"):
        torch.nn.utils.clip_grad_norm_(list(named.values()), cfg.max_grad_norm)
        optimizer.step()
    optimizer.zero_grad(set_to_none=True)
    if tracker is not None:
        tracker.label([t for s in optimizer.state.values() for t in s.values() if isinstance(t, torch.Tensor)],
                      "AdamW state")
    if ema is not None:
        with phase("EMA update"):
            ema.update(named)
    return loss.detach()


@dataclass
class Setting:
    """One configuration of the step to estimate or time. ``checkpointing``: None off, else the UNet's units
    (``checkpointing.UNITS``); ``condition_chunk``/``encode_chunk``: frames per chunk, 0 all at once. The setting
    before issue 44: ``Setting.before(...)``."""

    batch: int = 1
    checkpointing: str | None = "blocks"
    condition_chunk: int = 1
    encode_chunk: int = 1
    fused_adamw: bool = True
    ema: bool = True
    name: str = "after"

    @classmethod
    def before(cls, batch: int = 1, checkpointing: bool = True) -> Setting:
        """The step as it was before issue 44 (the bench's: diffusers' checkpointing flags on the UNet and the
        condition encoder, no chunks, fused AdamW)."""
        return cls(batch, "diffusers" if checkpointing else None, 0, 0, True, True, "before")

    def train_config(self, **kw):
        """A ``TrainConfig`` with this setting (paths empty: only the step reads it)."""
        from .config import TrainConfig

        return TrainConfig(checkpoint="", clips=["x"], output_dir="", batch_size=self.batch,
                           gradient_checkpointing=self.checkpointing is not None,
                           checkpointing_units=self.checkpointing or "blocks",
                           condition_chunk_frames=self.condition_chunk, encode_chunk_frames=self.encode_chunk, **kw)


def build(size: str, device: str = "cpu", frozen_dtype=torch.float32, fake: bool = False, seed: int = 0) -> dict:
    """SVD's components of ``size`` (``configs.SIZES``) and a condition encoder, as the training step uses them:
    unet, condition_encoder (trained, float32), vae, image_encoder (frozen, ``frozen_dtype``), denoiser,
    clip_mean/std, config. ``fake``: built on the meta device and materialised as fake tensors on ``device``
    (enter the returned ``"fake_mode"`` to run them); else random weights (``configs.build_components``)."""
    from ..model import configs, edm
    from ..model.checkpoint import CLIP_MEAN, CLIP_STD
    from ..model.checkpoint_config import ScpainterConfig
    from ..model.condition import ConditionEncoder

    out = {}
    if fake:
        from diffusers import AutoencoderKLTemporalDecoder, UNetSpatioTemporalConditionModel
        from torch._subclasses import FakeTensorMode
        from transformers import CLIPVisionConfig, CLIPVisionModelWithProjection

        k = configs.SIZES[size]
        with torch.device("meta"):
            c = {"unet": UNetSpatioTemporalConditionModel(**k["unet"]),
                 "vae": AutoencoderKLTemporalDecoder(**k["vae"]),
                 "image_encoder": CLIPVisionModelWithProjection(CLIPVisionConfig(**k["clip"]))}
            cond = ConditionEncoder.from_vae(c["vae"])
        for m in ("vae", "image_encoder"):
            c[m].to(frozen_dtype)
        mode = FakeTensorMode(allow_non_fake_inputs=True)
        with mode:
            for m in (c["unet"], cond, c["vae"], c["image_encoder"]):
                m.to_empty(device=device)
        out["fake_mode"] = mode
    else:
        c = configs.build_components(size, seed=seed)
        cond = ConditionEncoder.from_vae(c["vae"])
        for m in ("vae", "image_encoder"):
            c[m].to(device, frozen_dtype)
        c["unet"].to(device)
        cond.to(device)
    c["vae"].eval().requires_grad_(False)
    c["image_encoder"].eval().requires_grad_(False)
    c["unet"].train().requires_grad_(True)
    cond.train().requires_grad_(True)
    schedule = edm.Schedule.from_config(configs.SCHEDULER)   # SVD's scheduler config
    out.update({"unet": c["unet"], "denoiser": edm.Denoiser(c["unet"], schedule), "condition_encoder": cond,
                "vae": c["vae"], "image_encoder": c["image_encoder"],
                "clip_mean": torch.tensor(CLIP_MEAN).view(1, 3, 1, 1),
                "clip_std": torch.tensor(CLIP_STD).view(1, 3, 1, 1), "config": ScpainterConfig()})
    return out


def prepare(models: dict, setting: Setting, device, lr: float = 1e-5):
    """(step models, named trained parameters, optimizer, EMA or None, train config) for ``setting``: the UNet's
    checkpointing and the condition encoder's chunks set as the trainer sets them (``checkpointing.configure``)."""
    from . import checkpointing
    from .ema import EMA

    cfg = setting.train_config(learning_rate=lr, warmup_steps=0)
    unet, cond = models["unet"], models["condition_encoder"]
    chunks = checkpointing.configure(unet, cond, cfg)
    if setting.checkpointing == "diffusers" and setting.condition_chunk == 0:
        cond.enable_gradient_checkpointing()
    named = {f"unet.{k}": p for k, p in unet.named_parameters()}
    named.update({f"condition_encoder.{k}": p for k, p in cond.named_parameters()})
    kw = {"fused": True} if setting.fused_adamw else {"foreach": True}
    opt = torch.optim.AdamW(list(named.values()), lr=lr, betas=tuple(cfg.adam_betas), eps=cfg.adam_eps,
                            weight_decay=cfg.weight_decay, **kw)
    ema = EMA(named, cfg.ema_decay) if setting.ema else None
    return {**models, "condition_encoder": chunks}, named, opt, ema, cfg


def random_batch(batch: int, frames: int, height: int, width: int, device, seed: int = 0) -> dict:
    """Random frames and conditions (B, F, C, H, W) on ``device`` (fake under a fake mode)."""
    g = torch.Generator().manual_seed(seed)
    data = {"target": torch.rand(batch, frames, 3, height, width, generator=g),
            "image": torch.rand(batch, frames, 3, height, width, generator=g),
            "asset_mask": torch.zeros(batch, frames, 1, height, width),
            "valid": torch.ones(batch, frames, 1, height, width)}
    return {k: v.to(device) for k, v in data.items()}


@dataclass
class Estimate:
    """What ``estimate`` measured, in bytes: ``peak`` and ``at_peak`` (label → bytes live at the peak, ``LABELS``),
    ``kept`` (label → bytes live when the forward pass ended: what it keeps for backward, beside the persistent
    state), ``phase_peak`` (phase → highest total during it), ``seconds`` (wall time of the estimate), ``extra``:
    ``left_after_step`` (label → bytes live after the last step: what a step carries into the next)."""

    setting: Setting
    peak: int
    at_peak: dict
    kept: dict
    phase_peak: dict
    seconds: float
    extra: dict = field(default_factory=dict)

    def gib(self) -> dict:
        """The JSON row: setting, peak_gib, at_peak_gib, kept_gib, phase_peak_gib (GiB), seconds."""
        g = lambda d: {k: round(v / GIB, 3) for k, v in d.items() if v}  # noqa: E731
        return {"setting": self.setting.__dict__, "peak_gib": round(self.peak / GIB, 3), "at_peak_gib": g(self.at_peak),
                "kept_gib": g(self.kept), "phase_peak_gib": g(self.phase_peak), "seconds": round(self.seconds, 1),
                "left_after_step_gib": g(self.extra.get("left_after_step", {}))}


def tracked(models: dict, prepared: tuple, setting: Setting, frames: int, width: int, height: int, device,
            autocast, cuda_autocast: bool = False, steps: int = 1, seed: int = 0) -> Estimate:
    """Run ``steps`` steps of ``setting`` under an ``AllocationTracker`` (real or fake tensors) and return what it saw.
    ``models``: ``build``'s; ``prepared``: ``prepare``'s result for this setting (its AdamW state, if any, is
    counted as such); ``cuda_autocast``: ``cuda_autocast_norms`` (for the CPU standing in for CUDA)."""
    t0 = time.perf_counter()
    step_models, named, opt, ema, cfg = prepared
    tracker, kept = AllocationTracker(), {}
    trained = list(named.values())
    tracker.label(trained, "weights (trained)")
    tracker.label(list(models["vae"].parameters()) + list(models["image_encoder"].parameters()), "weights (frozen)")
    tracker.label([t for s in opt.state.values() for t in s.values() if isinstance(t, torch.Tensor)], "AdamW state")
    if ema is not None:
        tracker.label(ema.shadow, "EMA")
    hooks = [p.register_post_accumulate_grad_hook(lambda q: tracker.label(q.grad, "gradients")) for p in trained]
    for name, phase in (("unet", "UNet"), ("image_encoder", "CLIP"), ("condition_encoder", "condition encoder")):
        hooks += tracker.label_module(models[name], phase)
    hooks += tracker.label_module(models["vae"].encoder, "target encoding (VAE)")
    hooks += tracker.label_module(models["vae"].quant_conv, "target encoding (VAE)")
    norms = (cuda_autocast_norms(*(models[m] for m in ("unet", "condition_encoder", "vae", "image_encoder")))
             if cuda_autocast else contextlib.nullcontext())

    def after_forward():
        kept.clear()
        kept.update({k: v for k, v in tracker.now.items() if v})

    try:
        with norms:
            for i in range(steps):
                with tracker:
                    with tracker.in_phase("batch"):
                        batch = random_batch(setting.batch, frames, height, width, device, seed=seed + i)
                    gens = [torch.Generator().manual_seed(1000 * (seed + i) + b) for b in range(setting.batch)]
                    step(step_models, named, opt, ema, batch, cfg, gens, device, autocast, tracker, after_forward)
                    del batch
    finally:
        for h in hooks:
            h.remove()
    # what a step leaves live for the next one: the persistent state only (plus the returned loss, a scalar)
    left = {k: v for k, v in tracker.now.items() if v}
    return Estimate(setting, tracker.peak, dict(tracker.at_peak), kept, dict(tracker.phase_peak),
                    time.perf_counter() - t0, {"left_after_step": left})


def estimate(setting: Setting, size: str = "full", frames: int | None = None,
             resolution: tuple[int, int] = FULL_RESOLUTION, frozen_dtype=torch.bfloat16, autocast=torch.bfloat16, cuda_autocast: bool = True,
             models: dict | None = None, steps: int = 1) -> Estimate:
    """The memory of ``steps`` training steps of ``setting`` at ``size`` on fake tensors (module docstring), AdamW's
    state made beforehand (so the first step is the steady state). Defaults: what bench/train_throughput.py runs
    on CUDA (full size, 14 frames at 1024×576, frozen VAE and CLIP in bf16, bf16 autocast). ``models``: a fake
    ``build`` to reuse (its UNet's checkpointing is reset by this setting)."""
    t0 = time.perf_counter()
    frames = frames or ViewSettings.frames
    width, height = resolution
    models = models or build(size, "cpu", frozen_dtype, fake=True)
    with models["fake_mode"]:
        prepared = prepare(models, setting, "cpu")
        # AdamW's state exists from the first step on: make it with one step on zero gradients (no forward pass;
        # on fake tensors the values do not matter), so one tracked step shows the steady state
        params = list(prepared[1].values())
        for p in params:
            p.grad = torch.zeros_like(p)
        prepared[2].step()
        prepared[2].zero_grad(set_to_none=True)
        e = tracked(models, prepared, setting, frames, width, height, "cpu", autocast, cuda_autocast, steps)
    e.seconds = time.perf_counter() - t0
    return e
