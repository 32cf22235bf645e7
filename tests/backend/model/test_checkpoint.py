"""Checkpoint folders validated before any model is loaded (issue 14, points 3 and 6): ``scpainter.json`` field by
field, and safetensors only — a pickled component, or an index naming a pickled shard, is refused naming the file.

Bad folders are copies of the session's tiny checkpoint (``tiny_checkpoint`` in tests/conftest.py; real copies, never
hard links, so the shared fixture is never written through). Nothing here unpickles: the ``.bin`` files are written
with ``torch.save`` and ``torch.load`` is replaced by a tripwire wherever a model load is attempted."""

import json
import os
import shutil
from dataclasses import asdict

import pytest
import torch

from backend.model import checkpoint as C
from backend.model import checkpoint_init
from backend.model.checkpoint_config import (BOUNDS, SCHEMA, CheckpointError, ScpainterConfig, check_field,
                                             check_guidance)
from scpainter_blender.core import errors
from scpainter_blender.core.errors import InputError


@pytest.fixture
def ckpt(tiny_checkpoint, tmp_path):
    return shutil.copytree(tiny_checkpoint, tmp_path / "ckpt")


@pytest.fixture
def no_unpickling(monkeypatch):
    def tripwire(*a, **k):
        raise AssertionError("torch.load was called")

    monkeypatch.setattr(torch, "load", tripwire)


def refused(path, where, field=None, *words, fn=C.check):
    """Run ``fn(path)``; assert a CheckpointError naming ``where`` (a path suffix), ``field`` and ``words``."""
    with pytest.raises(CheckpointError) as info:
        fn(path)
    e = info.value
    assert isinstance(e, InputError) and isinstance(e, ValueError)
    assert e.path.endswith(where), (e.path, where)
    if field is not None:
        assert e.field.split("[")[0] == field, str(e)   # read_json names a refused number's element: image_std[1]
    assert str(e).startswith(f"{e.path}: {e.field}: " if e.path else f"{e.field}: "), str(e)
    for w in words:
        assert w in str(e), (w, str(e))
    return e


def test_the_tiny_checkpoint_passes_and_loads(tiny_checkpoint, no_unpickling):
    cfg = C.check(tiny_checkpoint)
    assert isinstance(cfg, ScpainterConfig) and cfg.fps == 7 and cfg.latent_validity == "area"
    comps = C.load(tiny_checkpoint)
    assert comps["config"] == cfg and len(comps["clip_mean"]) == 3 and all(s > 0 for s in comps["clip_std"])


# -- scpainter.json, field by field ----------------------------------------------------------------------------

GOOD = asdict(ScpainterConfig(base="/svd"))


def write_config(folder, text: str):
    with open(os.path.join(folder, "scpainter.json"), "w") as f:
        f.write(text)


def with_field(field, literal):
    """scpainter.json text with ``field`` set to the raw JSON ``literal`` (so NaN and 1e999 stay literals)."""
    return json.dumps({**GOOD, field: "@@"}).replace('"@@"', literal)


@pytest.mark.parametrize("field, literal, words", [
    ("schema", '"scpainter.checkpoint/2"', ["scpainter.checkpoint/1"]),
    ("base", "3", ["string"]),
    ("trained_steps", "-1", ["≥ 0"]),
    ("trained_steps", "null", ["integer"]),
    ("fps", '"7"', ["integer", "a string"]),
    ("fps", "0", ["[1, 240]"]),
    ("fps", "241", ["[1, 240]"]),
    ("fps", "true", ["boolean"]),
    ("fps", "7.5", ["integer"]),
    ("motion_bucket_id", "1024", ["[0, 1023]"]),
    ("motion_bucket_id", "-1", ["[0, 1023]"]),
    ("noise_aug_strength", "NaN", []),        # refused by read_json or the validator: either names the field
    ("noise_aug_strength", "10.5", ["[0, 10]"]),
    ("min_guidance", "-Infinity", []),
    ("min_guidance", "false", ["boolean"]),
    ("max_guidance", "1e999", []),
    ("max_guidance", "[3]", ["an array"]),
    ("window", "0", ["[1, 256]"]),
    ("window", "257", ["[1, 256]"]),
    ("window", "true", ["boolean"]),
    ("window", "1" + "0" * 30, ["[1, 256]", "31 digits"]),
    ("latent_validity", '"nearest"', ["'area'"]),
    ("latent_validity", "1", ["'area'"]),
    ("extra", "[]", ["object"]),
])
def test_each_bad_field_is_refused_naming_the_file_and_field(ckpt, field, literal, words):
    write_config(ckpt, with_field(field, literal))
    refused(ckpt, "scpainter.json", field, *words)


def test_min_guidance_above_max_is_refused(ckpt):
    write_config(ckpt, json.dumps({**GOOD, "min_guidance": 4, "max_guidance": 3.5}))
    refused(ckpt, "scpainter.json", "min_guidance", "max_guidance 3.5")


@pytest.mark.parametrize("text", ["[]", '"scpainter.checkpoint/1"', "null", "{", ""])
def test_a_non_object_or_broken_file_is_refused(ckpt, text):
    write_config(ckpt, text)
    refused(ckpt, "scpainter.json", "(file)")


def test_missing_schema_unknown_keys_and_integral_numbers(ckpt):
    write_config(ckpt, json.dumps({k: v for k, v in GOOD.items() if k != "schema"}))
    refused(ckpt, "scpainter.json", "schema", "missing")
    write_config(ckpt, json.dumps({"schema": SCHEMA, "fps": 12.0, "window": 8, "from_the_future": {"x": 1}}))
    cfg = C.check(ckpt)
    assert cfg.fps == 12 and type(cfg.fps) is int and cfg.window == 8 and cfg.motion_bucket_id == 127
    assert not hasattr(cfg, "from_the_future")


def test_bounds_are_public_for_the_generate_overrides():
    assert ScpainterConfig.BOUNDS is BOUNDS and BOUNDS["window"] == ("int", 1, 256)
    assert check_field("window", 14.0) == 14 and check_field("min_guidance", 2) == 2.0
    for name, bad in [("window", True), ("fps", 0), ("max_guidance", float("nan")), ("noise_aug_strength", "0")]:
        with pytest.raises(ValueError, match="expected"):
            check_field(name, bad)
    with pytest.raises(ValueError, match="greater than max_guidance"):
        check_guidance(3.0, 1.0)


# -- safetensors only -------------------------------------------------------------------------------------------

def write_index(path, shards):
    with open(path, "w") as f:
        json.dump({"metadata": {}, "weight_map": {f"p{i}": s for i, s in enumerate(shards)}}, f)


def test_an_index_naming_a_bin_shard_is_refused(ckpt, no_unpickling):
    unet = os.path.join(ckpt, "unet")
    index = os.path.join(unet, "diffusion_pytorch_model.safetensors.index.json")
    os.rename(os.path.join(unet, "diffusion_pytorch_model.safetensors"),
              os.path.join(unet, "diffusion_pytorch_model-00001-of-00002.safetensors"))
    torch.save({"w": torch.zeros(1)}, os.path.join(unet, "diffusion_pytorch_model-00002-of-00002.bin"))
    write_index(index, ["diffusion_pytorch_model-00001-of-00002.safetensors",
                        "diffusion_pytorch_model-00002-of-00002.bin"])
    e = refused(ckpt, "unet/diffusion_pytorch_model.safetensors.index.json", "weight_map.p1",
                "diffusion_pytorch_model-00002-of-00002.bin", "pickled weights are never loaded")
    assert "safetensors" in e.hint
    refused(ckpt, "unet/diffusion_pytorch_model.safetensors.index.json", fn=C.load)   # load checks first


def test_an_index_beside_the_single_file_is_checked_too(ckpt):
    """diffusers prefers the index to the single file: the index is what must be safe."""
    index = os.path.join(ckpt, "vae", "diffusion_pytorch_model.safetensors.index.json")
    write_index(index, ["weights.pt"])
    refused(ckpt, "vae/diffusion_pytorch_model.safetensors.index.json", "weight_map.p0", "weights.pt")
    write_index(index, ["../unet/diffusion_pytorch_model.safetensors"])
    refused(ckpt, "vae/diffusion_pytorch_model.safetensors.index.json", "weight_map.p0", "own folder")
    write_index(index, ["missing.safetensors"])
    refused(ckpt, "vae/missing.safetensors", "(file)", "not found")
    with open(index, "w") as f:
        json.dump({"weight_map": []}, f)
    refused(ckpt, "vae/diffusion_pytorch_model.safetensors.index.json", "weight_map")


def test_a_transformers_index_naming_a_pickle_is_refused(ckpt):
    enc = os.path.join(ckpt, "image_encoder")
    os.remove(os.path.join(enc, "model.safetensors"))
    write_index(os.path.join(enc, "model.safetensors.index.json"), ["pytorch_model-00001-of-00001.bin"])
    refused(ckpt, "image_encoder/model.safetensors.index.json", "weight_map.p0", "pytorch_model-00001-of-00001.bin")


@pytest.mark.parametrize("comp, pickle_name", [("vae", "diffusion_pytorch_model.bin"),
                                               ("condition_encoder", "diffusion_pytorch_model.bin"),
                                               ("image_encoder", "pytorch_model.bin")])
def test_a_component_with_only_pickled_weights_is_refused(ckpt, no_unpickling, comp, pickle_name):
    folder = os.path.join(ckpt, comp)
    single = [f for f in os.listdir(folder) if f.endswith(".safetensors")]
    assert len(single) == 1
    os.remove(os.path.join(folder, single[0]))
    torch.save({"w": torch.zeros(1)}, os.path.join(folder, pickle_name))
    refused(ckpt, f"{comp}/{pickle_name}", "(file)", "pickled weights are never loaded: convert to safetensors")
    refused(ckpt, f"{comp}/{pickle_name}", fn=C.load)   # nothing reaches from_pretrained, so no torch.load


def test_pickled_weights_renamed_to_safetensors_are_refused(ckpt, no_unpickling):
    path = os.path.join(ckpt, "unet", "diffusion_pytorch_model.safetensors")
    os.remove(path)
    torch.save({"w": torch.zeros(1)}, path)
    refused(ckpt, "unet/diffusion_pytorch_model.safetensors", "(file)", "not a safetensors file")


def test_only_a_variant_is_refused_saying_what_is_loaded(ckpt):
    unet = os.path.join(ckpt, "unet")
    os.rename(os.path.join(unet, "diffusion_pytorch_model.safetensors"),
              os.path.join(unet, "diffusion_pytorch_model.fp16.safetensors"))
    refused(ckpt, "unet", "(folder)", "diffusion_pytorch_model.fp16.safetensors", "rename it")


def test_transformers_weights_naming_a_pickle_is_refused(ckpt):
    path = os.path.join(ckpt, "image_encoder", "config.json")
    with open(path) as f:
        cfg = json.load(f)
    with open(path, "w") as f:
        json.dump({**cfg, "transformers_weights": "adapter_model.bin"}, f)
    refused(ckpt, "image_encoder/config.json", "transformers_weights", "adapter_model.bin")


# -- component configs ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("rel", ["condition_encoder/config.json", "unet/config.json", "model_index.json",
                                 "scheduler/scheduler_config.json", "feature_extractor/preprocessor_config.json"])
def test_a_missing_config_is_refused(ckpt, rel):
    os.remove(os.path.join(ckpt, rel))
    refused(ckpt, rel, "(file)", "not found")


def test_a_missing_component_folder_is_refused(ckpt):
    shutil.rmtree(os.path.join(ckpt, "condition_encoder"))
    refused(ckpt, "condition_encoder", "(folder)", "missing")


def test_a_fifo_config_is_refused_without_blocking(ckpt):
    path = os.path.join(ckpt, "vae", "config.json")
    os.remove(path)
    os.mkfifo(path)
    refused(ckpt, "vae/config.json", "(file)", "FIFO")


def edit_json(path, **changes):
    with open(path) as f:
        data = json.load(f)
    with open(path, "w") as f:
        f.write(json.dumps({**data, **changes}).replace('"@nan"', "NaN"))


@pytest.mark.parametrize("rel, field, value", [
    ("vae/config.json", "force_upcast", "yes"),
    ("vae/config.json", "force_upcast", 1),
    ("feature_extractor/preprocessor_config.json", "image_mean", [0.5, 0.5]),
    ("feature_extractor/preprocessor_config.json", "image_mean", "0.5"),
    ("feature_extractor/preprocessor_config.json", "image_std", [0.5, "@nan", 0.5]),
    ("feature_extractor/preprocessor_config.json", "image_std", [0.5, 0.0, 0.5]),
    ("feature_extractor/preprocessor_config.json", "image_std", [0.5, True, 0.5]),
])
def test_values_load_reads_from_component_configs_are_checked(ckpt, rel, field, value):
    edit_json(os.path.join(ckpt, rel), **{field: value})
    refused(ckpt, rel, field)


def test_check_svd_folder_uses_the_same_weights_check(tiny_svd, tmp_path, no_unpickling):
    svd = shutil.copytree(tiny_svd, tmp_path / "svd")
    C.check_svd_folder(str(svd))
    os.remove(svd / "vae" / "diffusion_pytorch_model.safetensors")
    torch.save({"w": torch.zeros(1)}, svd / "vae" / "diffusion_pytorch_model.bin")
    refused(str(svd), "vae/diffusion_pytorch_model.bin", "(file)", "pickled", fn=C.check_svd_folder)
    with pytest.raises(CheckpointError):
        checkpoint_init.init_checkpoint(str(svd), str(tmp_path / "never"))
    assert not (tmp_path / "never").exists()
    refused(str(tmp_path), str(tmp_path), "(folder)", "no model_index.json", fn=C.check_svd_folder)


def test_resolve_still_fails_fast(tiny_svd):
    e = refused(None, errors.COMMAND_LINE, "--checkpoint", "init-checkpoint", fn=C.resolve)
    assert str(e).startswith("(command line): --checkpoint: no SCPainter checkpoint") and "init-checkpoint" in e.hint
    cls, args = e.__reduce__()   # how pickle would rebuild it in another process (not exercised: nothing unpickles)
    again = cls(*args)
    assert str(again) == str(e) and (again.path, again.field, again.hint) == (e.path, e.field, e.hint)
    refused(tiny_svd, tiny_svd, "(folder)", "stock SVD snapshot", fn=C.check)


def test_no_checkpoint_names_where_one_was_expected(tmp_path):
    """Without a checkpoint, the error names where one was looked for: the command line's --checkpoint by default,
    the job file and its generate.checkpoint in ``generate.prepare`` (a job without one, no --checkpoint given);
    never an empty path or "None"."""
    from backend.generate import command as generate
    from scpainter_blender.core import job as J
    from tests_support import small_job

    job_path = small_job(tmp_path, asset=False)
    e = refused(None, job_path, "generate.checkpoint", fn=lambda p: C.resolve(p, job_path, "generate.checkpoint"))
    assert str(e).startswith(f"{job_path}: generate.checkpoint: no SCPainter checkpoint is configured")
    assert generate.prepare(job_path, J.load(job_path), None).model == "baseline"  # auto: no checkpoint, baseline
    with pytest.raises(CheckpointError) as info:                            # the model asked for: refused
        generate.prepare(job_path, J.load(job_path), None, {"model": "scpainter"})
    assert (info.value.path, info.value.field, info.value.hint) == (job_path, "generate.checkpoint", e.hint)
    missing = str(tmp_path / "nowhere")   # a --checkpoint that is no folder is named itself
    refused(missing, missing, "(folder)", "does not exist",
            fn=lambda p: generate.prepare(job_path, J.load(job_path), p))
