"""``python -m backend train CONFIG``: fine-tune an SCPainter checkpoint on clip folders (docs/design.md §5).

Read top to bottom: load the checkpoint's components (UNet and condition encoder trained; VAE and CLIP frozen),
wrap what trains with ``accelerate`` (DDP over however many processes ``accelerate launch``/``torchrun`` started;
one process otherwise), resume from the newest checkpoint in ``output_dir`` if there is one, then step:

    batch (rendered pairs, backend.train.pairs) → objective.loss → backward → clip → AdamW → EMA,

logging to TensorBoard (rank 0) and saving checkpoints that ``generate`` loads directly. The loss's x̂_0 comes from
``self.denoiser``, an ``edm.Denoiser`` over the trained UNet holding the base checkpoint's schedule: the function
and the noise levels ``generate`` samples with (the σ that training draws is the training config's log-normal).

Determinism and exact resume: sample i of the run is drawn from (seed, i) (pairs.PairDataset) and its noise from
a CPU generator seeded by (seed, i) (objective.generators); the learning rate is a function of the step. So the
run does not depend on how the global batch is split over processes either. A checkpoint holds the weights, the
optimiser state and the EMA, so resuming at step k and training to n gives the weights of an uninterrupted run to n.

Checkpoint folder ``checkpoints/step_NNNNNNN`` (written under a temporary name, renamed when complete): an
SCPainter checkpoint (scpainter.json with trained_steps, the base's frozen components hard-linked, unet/ and
condition_encoder/ holding the EMA weights, or the raw ones without EMA) plus ``training_state/`` (raw weights,
optimiser state — read back with ``torch.load(weights_only=True)`` — EMA, step).

A non-finite loss or gradient norm stops the run with ``NonFiniteError`` before the optimiser step, so neither the
weights nor the EMA take anything from that step and no checkpoint is written after it; the newest checkpoint is
the last good state, and ``save`` refuses non-finite weights as a last guard.

Over ~400 lines because ``Trainer`` is one piece of state (models, optimiser, EMA, step, ranks) that loading,
resuming, the step, the non-finite guard and saving all read and write; its helpers (the pairs, the objective, the
EMA, the log) are modules of their own already.
"""

from __future__ import annotations

import math
import os
import shutil
import time
from dataclasses import asdict
from typing import TYPE_CHECKING

import numpy as np
import torch

from scpainter_blender.core import files, outputs

from .. import events
from ..errors import FolderBusyError, NonFiniteError
from ..model import checkpoint as ckpt_mod
from ..model import checkpoint_init, edm
from . import clip as clip_mod
from . import checkpointing, objective
from .config import TrainConfig, TrainConfigError
from .ema import EMA
from .pairs import PairDataset

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

CKPT_PREFIX = "step_"


def checkpoints(output_dir: str) -> list:
    """Finished checkpoint folders in ``output_dir``, oldest first."""
    d = os.path.join(output_dir, "checkpoints")
    if not os.path.isdir(d):
        return []
    names = sorted(n for n in os.listdir(d) if n.startswith(CKPT_PREFIX) and n[len(CKPT_PREFIX):].isdigit())
    return [os.path.join(d, n) for n in names if os.path.isfile(os.path.join(d, n, "training_state", "state.json"))]


def lr_at(cfg: TrainConfig, step: int) -> float:
    """Linear warm-up over ``warmup_steps``, then constant."""
    return cfg.learning_rate * min(1.0, (step + 1) / cfg.warmup_steps) if cfg.warmup_steps else cfg.learning_rate


class StepSampler(torch.utils.data.Sampler):
    """Global sample indices of this rank from ``start_step`` on: micro-step m of step s takes samples
    ((s·A + m)·W + rank)·B + j, j < B (A: accumulation, W: processes, B: batch)."""

    def __init__(self, start_step: int, steps: int, batch: int, accumulation: int, world: int, rank: int) -> None:
        self.a = (start_step, steps, batch, accumulation, world, rank)

    def __iter__(self):
        start, steps, B, A, W, r = self.a
        for s in range(start, steps):
            for m in range(A):
                base = ((s * A + m) * W + r) * B
                yield from range(base, base + B)

    def __len__(self):
        start, steps, B, A, _, _ = self.a
        return max(0, steps - start) * A * B


def _collate(items: list) -> dict:
    """Stack PairDataset items; ``index``, ``clip`` (index into the run's clip list) and ``t0`` (first target
    frame) are (B,) int64, kept so a failing step can name its samples."""
    out = {k: torch.stack([it[k] for it in items]) for k in ("target", "image", "asset_mask", "valid")}
    for k in ("index", "clip", "t0"):
        out[k] = torch.tensor([it[k] for it in items])
    return out


def make_optimizer(cfg: TrainConfig, params: list) -> torch.optim.Optimizer:
    if cfg.optimizer == "adamw8bit":
        try:
            import bitsandbytes as bnb
        except ImportError:
            raise TrainConfigError(cfg.path, "optimizer", "'adamw8bit' needs bitsandbytes (a CUDA package): "
                                   "pip install bitsandbytes, or use 'adamw'") from None
        opt = bnb.optim.AdamW8bit
        kw = {}
    else:
        opt = torch.optim.AdamW
        # on CUDA the fused kernel: the default foreach kernel allocates a temporary the size of every parameter
        # (its sqrt of exp_avg_sq), 5.8 GiB for the full UNet; the CPU keeps foreach (its results unchanged)
        kw = {"fused": True} if params and params[0].device.type == "cuda" else {}
    return opt(params, lr=lr_at(cfg, 0), betas=tuple(cfg.adam_betas), eps=cfg.adam_eps,
               weight_decay=cfg.weight_decay, **kw)


def _save_component(model, folder: str, state: dict) -> None:
    """A diffusers component folder (config.json + safetensors) holding ``state``."""
    from safetensors.torch import save_file

    os.makedirs(folder, exist_ok=True)
    model.save_config(folder)
    save_file({k: v.detach().float().cpu().contiguous() for k, v in state.items()},
              os.path.join(folder, "diffusion_pytorch_model.safetensors"))


class Trainer:
    def __init__(self, cfg: TrainConfig, device: str | None = None, log: Callable[[str], None] | None = None) -> None:
        from accelerate import Accelerator

        self.cfg = cfg
        cpu = device == "cpu" or (device is None and not torch.cuda.is_available())
        mp = cfg.mixed_precision
        if mp == "auto":
            mp = "no" if cpu else "bf16"
        self.accelerator = Accelerator(cpu=cpu, mixed_precision=mp, gradient_accumulation_steps=1)
        self.autocast = torch.bfloat16 if mp == "bf16" else None
        self.device = self.accelerator.device
        self.rank, self.world = self.accelerator.process_index, self.accelerator.num_processes
        self.out = cfg.resolve(cfg.output_dir)
        os.makedirs(self.out, exist_ok=True)
        self.log = log or (events.FileLog(os.path.join(self.out, "train.log")) if self.rank == 0 else (lambda m: None))
        self.base = ckpt_mod.resolve(cfg.resolve(cfg.checkpoint))
        self.clip_paths = clip_paths = cfg.clip_paths()
        # fail before loading models, not in a DataLoader worker an hour in: every clip.json exists, the first
        # clip loads whole (the others are read when first sampled, and a bad one stops training with its name)
        missing = [p for p in clip_paths if not os.path.isfile(clip_mod.json_path(p))]
        if missing:
            raise TrainConfigError(cfg.path, "clips", f"{len(missing)} clip folders have no clip.json: {missing[:3]}")
        clip_mod.load(clip_paths[0])
        comps = ckpt_mod.load(self.base, device=self.device, dtype=torch.float32)
        self.scp_config = comps["config"]
        self.schedule = comps["schedule"]   # the checkpoint's scheduler/scheduler_config.json (edm.Schedule)
        self.unet, self.cond = comps["unet"], comps["condition_encoder"]
        self.unet.train().requires_grad_(True)
        self.cond.train().requires_grad_(cfg.train_condition_encoder)
        # what the step keeps for backward (checkpointed units, frame chunks): train/checkpointing.py
        self.cond_chunks = checkpointing.configure(self.unet, self.cond, cfg)
        self.frozen = {"vae": comps["vae"], "image_encoder": comps["image_encoder"],
                       "clip_mean": torch.tensor(comps["clip_mean"]).view(1, 3, 1, 1),
                       "clip_std": torch.tensor(comps["clip_std"]).view(1, 3, 1, 1), "config": comps["config"]}
        self.named = {f"unet.{k}": p for k, p in self.unet.named_parameters()}
        if cfg.train_condition_encoder:
            self.named.update({f"condition_encoder.{k}": p for k, p in self.cond.named_parameters()})
        self.optimizer = make_optimizer(cfg, list(self.named.values()))
        self.ema = EMA(self.named, cfg.ema_decay) if cfg.ema_decay > 0 else None
        self.step = 0
        latest = checkpoints(self.out)
        if latest:
            self._load_state(latest[-1])
        if cfg.train_condition_encoder:
            self.unet_ddp, self.cond_ddp, self.optimizer = self.accelerator.prepare(self.unet, self.cond_chunks,
                                                                                    self.optimizer)
        else:  # DDP refuses a module without trainable parameters
            self.unet_ddp, self.optimizer = self.accelerator.prepare(self.unet, self.optimizer)
            self.cond_ddp = self.cond_chunks
        # the loss's x̂_0: the sampler's denoiser (edm.Denoiser) around the UNet as DDP runs it
        self.denoiser = edm.Denoiser(self.unet_ddp, self.schedule)
        self.dataset = PairDataset(clip_paths, cfg.pairs, seed=cfg.seed)
        from .tensorboard_log import TrainLog

        self.tb = TrainLog(os.path.join(self.out, "logs") if self.rank == 0 else None)

    # ---------------------------------------------------------------------------------------------------------
    def _load_state(self, folder: str) -> None:
        from safetensors.torch import load_file

        st = os.path.join(folder, "training_state")
        meta = files.read_json(os.path.join(st, "state.json"), error=TrainConfigError)
        for key in ("step", "ema_updates"):
            if not isinstance(meta, dict) or isinstance(meta.get(key), bool) or not isinstance(meta.get(key), int):
                raise TrainConfigError(os.path.join(st, "state.json"), key, "expected an integer (a damaged "
                                       "training state: remove this checkpoint folder to resume from the one before)")
        raw = load_file(os.path.join(st, "weights.safetensors"))
        missing = set(self.named) - set(raw)
        if missing:
            raise TrainConfigError(self.cfg.path, "output_dir", f"{st}: the saved weights lack {sorted(missing)[:3]} "
                                   "(trained with another configuration?)")
        with torch.no_grad():
            for k, p in self.named.items():
                p.copy_(raw[k])
        opt_state = torch.load(os.path.join(st, "optimizer.pt"), map_location="cpu", weights_only=True)
        self.optimizer.load_state_dict(opt_state)
        if self.ema is not None:
            ema = load_file(os.path.join(st, "ema.safetensors"))
            self.ema.shadow = {k: ema[k].to(self.device) for k in self.named}
            self.ema.updates = int(meta["ema_updates"])
        self.step = int(meta["step"])
        self.log(f"train: resumed from {folder} at step {self.step}")

    def _describe(self, samples: list) -> list:
        """[{"sample": global index, "clip": clip path, "frames": [t0, t0 + F)}] for (index, clip, t0) triples."""
        F = self.cfg.pairs.frames
        return [{"sample": int(i), "clip": self.clip_paths[int(k)], "frames": [int(t0), int(t0) + F]}
                for i, k, t0 in samples]

    def _nonfinite(self, what: str, step: int, samples: list | None) -> NonFiniteError:
        """The error for a non-finite ``what`` ("the loss is nan") at ``step`` (1-based: step N is the one that
        makes checkpoint step_N), naming this rank's samples of that step when known. Fields: stage "train",
        step, batch (``_describe``, [] when unknown), checkpoint (the newest checkpoint folder, or None)."""
        batch = self._describe(samples or [])
        last = (checkpoints(self.out) or [None])[-1]

        def name(b):
            c = os.path.normpath(b["clip"])
            c = os.path.basename(os.path.dirname(c) if c.endswith(".json") else c)
            return f"{b['sample']} ({c}, frames {b['frames'][0]}-{b['frames'][1] - 1})"

        names = ", ".join(name(b) for b in batch[:4]) + (f" and {len(batch) - 4} more" if len(batch) > 4 else "")
        where = f" (samples{f' on rank {self.rank}' if self.world > 1 else ''}: {names})" if batch else ""
        kept = (f"the last good checkpoint {last} is kept" if last else "no checkpoint had been written yet")
        # data and noise are functions of the step, so rerunning unchanged would meet the same NaN: change a setting
        fp32 = " or set mixed_precision to \"no\" (fp32)" if self.autocast is not None else ""
        hint = (f"lower learning_rate{fp32} in the training config, then run the same command again: it "
                + (f"resumes from {last}" if last else "starts from the base checkpoint"))
        return NonFiniteError(f"train: {what} at step {step}{where}; nothing from it is saved and {kept}",
                              hint=hint, stage="train", step=step, batch=batch, checkpoint=last)

    def _check_weights(self) -> None:
        """Raise NonFiniteError if a weight about to be saved (raw or EMA) holds NaN/inf: a checkpoint is a state
        to resume and generate from, and a poisoned one would replace a good one when old ones are pruned."""
        named = dict(self.named)
        if self.ema is not None:
            named.update({f"ema:{k}": v for k, v in self.ema.shadow.items()})
        ok = torch.stack([torch.isfinite(p.detach()).all() for p in named.values()])  # one host sync
        if not bool(ok.all()):
            bad = [k for k, good in zip(named, ok.tolist()) if not good]
            more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
            raise self._nonfinite(f"the weight {bad[0]}{more} holds NaN/inf", self.step, None)

    def save(self) -> str:
        """Write checkpoints/step_N (every rank waits; rank 0 writes) and prune old ones. Returns the folder.
        Raises NonFiniteError, writing nothing, if a weight is NaN/inf (see ``_check_weights``)."""
        self._check_weights()  # on every rank (the weights are the same on all), so all of them stop
        self.accelerator.wait_for_everyone()
        final = os.path.join(self.out, "checkpoints", f"{CKPT_PREFIX}{self.step:07d}")
        if self.rank == 0 and not os.path.isdir(final):
            from safetensors.torch import save_file

            os.makedirs(os.path.dirname(final), exist_ok=True)
            with outputs.atomic_folder(final) as tmp:
                frozen = [c for c in ckpt_mod.COMPONENTS if c != "unet"]  # unet/ is written below, trained
                checkpoint_init.link_components(self.base, tmp, frozen)
                weights = self.ema.shadow if self.ema is not None else {k: p for k, p in self.named.items()}
                unet_state = dict(self.unet.state_dict())
                unet_state.update({k[5:]: v for k, v in weights.items() if k.startswith("unet.")})
                _save_component(self.unet, os.path.join(tmp, "unet"), unet_state)
                cond_state = dict(self.cond.state_dict())
                cond_state.update({k[18:]: v for k, v in weights.items() if k.startswith("condition_encoder.")})
                _save_component(self.cond, os.path.join(tmp, "condition_encoder"), cond_state)
                sc = asdict(self.scp_config)
                sc["trained_steps"] = self.scp_config.trained_steps + self.step
                sc["extra"] = dict(sc.get("extra") or {}, trained_from=self.base, ema=self.ema is not None,
                                   train_config=self.cfg.to_json())
                outputs.write_json(os.path.join(tmp, "scpainter.json"), sc)
                st = os.path.join(tmp, "training_state")
                os.makedirs(st)
                save_file({k: p.detach().float().cpu().contiguous() for k, p in self.named.items()},
                          os.path.join(st, "weights.safetensors"))
                torch.save(self.optimizer.state_dict(), os.path.join(st, "optimizer.pt"))
                if self.ema is not None:
                    save_file({k: v.cpu().contiguous() for k, v in self.ema.shadow.items()},
                              os.path.join(st, "ema.safetensors"))
                outputs.write_json(os.path.join(st, "state.json"), {
                    "step": self.step, "ema_updates": 0 if self.ema is None else self.ema.updates,
                    "world_size": self.world})
            for old in checkpoints(self.out)[:-self.cfg.keep_checkpoints]:
                shutil.rmtree(old, ignore_errors=True)
            events.artifact(final, kind="checkpoint", step=self.step)
        self.accelerator.wait_for_everyone()
        return final

    # ---------------------------------------------------------------------------------------------------------
    def _models(self) -> dict:
        return {"denoiser": self.denoiser, "unet": self.unet_ddp, "condition_encoder": self.cond_ddp, **self.frozen}

    def sample_video(self, sample: dict, steps: int) -> torch.Tensor | None:
        """(F, 3, H, 3W) in [0, 1]: condition | generated (EMA weights) | target, for the log; None (logged) when
        the sampler produced NaN/inf."""
        from ..model.pipeline import SCPainterPipeline

        comps = {"unet": self.unet, "vae": self.frozen["vae"], "image_encoder": self.frozen["image_encoder"],
                 "condition_encoder": self.cond, "config": self.scp_config, "schedule": self.schedule,
                 "clip_mean": self.frozen["clip_mean"].flatten().tolist(),
                 "clip_std": self.frozen["clip_std"].flatten().tolist()}
        self.unet.eval(), self.cond.eval()
        try:
            ctx = self.ema.applied(self.named) if self.ema is not None else torch.no_grad()
            with ctx:
                pipe = SCPainterPipeline(comps, self.device)
                cond = pipe.condition_latents(sample["image"], sample["asset_mask"], sample["valid"])
                x = pipe.sample(cond, pipe.clip_embedding(sample["target"][0]), steps=steps)
                video = pipe.decode(x)
        except NonFiniteError as e:
            # the log's sample is not the run: a bad state is caught by the loss or by save, not here
            self.log(f"train: no sample video at step {self.step}: {e}")
            return None
        finally:
            self.unet.train(), self.cond.train()
        return torch.cat([sample["image"], video, sample["target"]], dim=-1)

    def train(self, stop: Sequence[object] = (), max_steps: int | None = None) -> dict:
        cfg, acc = self.cfg, self.accelerator
        end = cfg.steps if max_steps is None else min(cfg.steps, max_steps)
        if self.step >= end:
            self.log(f"train: already at step {self.step} of {end}")
            return {"step": self.step, "stopped": False, "checkpoint": (checkpoints(self.out) or [None])[-1]}
        loader = torch.utils.data.DataLoader(
            self.dataset, batch_size=cfg.batch_size, num_workers=cfg.num_workers, collate_fn=_collate,
            sampler=StepSampler(self.step, end, cfg.batch_size, cfg.gradient_accumulation, self.world, self.rank),
            prefetch_factor=2 if cfg.num_workers else None,
            # spawn, not fork: the parent has run numba's and torch's thread pools (samples, model loading), and a
            # forked child inherits their locks and hangs
            multiprocessing_context="spawn" if cfg.num_workers else None)
        val = (self.dataset.maker(0).sample(np.random.default_rng([cfg.seed, 2**31]))
               if cfg.sample_every and self.rank == 0 else None)
        n_params = sum(p.numel() for p in self.named.values())
        self.log(f"train: {n_params / 1e6:.1f} M trained parameters, steps {self.step} -> {end}, batch "
                 f"{cfg.batch_size} x {cfg.gradient_accumulation} x {self.world} processes, "
                 f"{cfg.pairs.frames} frames {cfg.pairs.width}x{cfg.pairs.height}, {self.device}, "
                 f"mixed precision {acc.mixed_precision}")
        it = iter(loader)
        t_last, losses, stopped = time.perf_counter(), [], False
        while self.step < end:
            if stop:
                stopped = True
                break
            lr = lr_at(cfg, self.step)
            for g in self.optimizer.param_groups:
                g["lr"] = lr
            step_loss, samples = 0.0, []
            for m in range(cfg.gradient_accumulation):
                batch = next(it)
                samples += zip(batch["index"].tolist(), batch["clip"].tolist(), batch["t0"].tolist())
                gens = objective.generators(cfg.seed, batch["index"].tolist())
                loss, _ = objective.loss(self._models(), batch, cfg, gens, self.device, self.autocast)
                acc.backward(loss / cfg.gradient_accumulation)
                step_loss += float(loss.detach()) / cfg.gradient_accumulation
            if self.world > 1:  # the logged loss is the global batch's, not rank 0's share
                step_loss = float(acc.reduce(torch.tensor(step_loss, device=self.device), "mean"))
            # both checks come before optimizer.step: a bad step changes neither the weights nor the EMA, and
            # raising here skips every save after it (the reduced loss and the DDP-averaged gradient norm are the
            # same on every rank, so all ranks stop together)
            if not math.isfinite(step_loss):
                raise self._nonfinite(f"the loss is {step_loss}", self.step + 1, samples)
            grad_norm = float(acc.clip_grad_norm_(list(self.named.values()), cfg.max_grad_norm))
            if not math.isfinite(grad_norm):
                raise self._nonfinite(f"the gradient norm is {grad_norm}", self.step + 1, samples)
            self.optimizer.step()
            self.optimizer.zero_grad(set_to_none=True)
            if self.ema is not None:
                self.ema.update(self.named)
            self.step += 1
            losses.append(step_loss)
            if self.rank == 0:
                events.progress("train", self.step, end, loss=step_loss)
            if self.step % cfg.log_every == 0 or self.step == end:
                dt = time.perf_counter() - t_last
                t_last = time.perf_counter()
                mean = float(np.mean(losses[-cfg.log_every:]))
                samples_s = cfg.log_every * cfg.batch_size * cfg.gradient_accumulation * self.world / dt
                self.tb.scalars(self.step, {"loss": mean, "lr": lr, "grad_norm": grad_norm,
                                            "samples_per_s": samples_s})
                self.log(f"step {self.step}: loss {mean:.4f}, grad norm {grad_norm:.3f}, lr {lr:.2e}, "
                         f"{samples_s:.2f} samples/s")
            if val is not None and self.rank == 0 and self.step % cfg.sample_every == 0:
                video = self.sample_video(val, cfg.sample_steps)
                if video is not None:
                    self.tb.video("sample/condition|generated|target", self.step, video, fps=int(self.scp_config.fps))
            if self.step % cfg.save_every == 0:
                self.save()
        final = self.save()
        self.tb.flush()
        return {"step": self.step, "stopped": stopped, "checkpoint": final, "losses": losses}


def train(cfg: TrainConfig, device: str | None = None, stop: Sequence[object] = (),
          max_steps: int | None = None) -> dict:
    """Train (or resume) the run of ``cfg`` up to ``cfg.steps`` (or ``max_steps``): ``Trainer.train``'s result.

    One run writes a run folder at a time: rank 0 holds the output folder's lock (``core.locking.OutputLock``, as
    ``render`` and ``generate`` do) for every rank, from before the last checkpoint is read until the last one is
    written, so a second ``train`` on the same ``output_dir`` raises ``errors.FolderBusyError`` naming the first
    (pid, host, since) instead of interleaving its checkpoints with it. A lock left by a run that died is taken over."""
    import contextlib

    from scpainter_blender.core import locking
    from scpainter_blender.core.batch_items import ranks_from_env

    out = cfg.resolve(cfg.output_dir)
    os.makedirs(out, exist_ok=True)
    held = locking.OutputLock(out, "train", busy=FolderBusyError) if ranks_from_env()[0] == 0 else None
    with held or contextlib.nullcontext():
        trainer = Trainer(cfg, device)
        if held is not None and held.stale:
            trainer.log(f"train: {held.took_over()}")
        try:
            return trainer.train(stop, max_steps)
        finally:
            trainer.tb.close()
