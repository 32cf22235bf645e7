"""The FID Inception: pytorch-fid's key names and shapes, input conventions, and loading local weight files."""

import pickle

import pytest
import torch
import torch.nn.functional as F
from safetensors.torch import save_file

from backend.evaluate.inception import (
    EvaluationError,
    InceptionFeatures,
    load_inception,
)


@pytest.fixture(scope="module")
def random_model():
    """Random weights with non-trivial batch-norm statistics, so that every tensor in the file matters."""
    torch.manual_seed(0)
    model = InceptionFeatures()
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.copy_(0.1 * torch.randn(m.num_features, generator=g))
                m.running_var.copy_(0.5 + torch.rand(m.num_features, generator=g))
                m.weight.copy_(0.5 + torch.rand(m.num_features, generator=g))
                m.bias.copy_(0.1 * torch.randn(m.num_features, generator=g))
            elif isinstance(m, torch.nn.Conv2d):
                torch.nn.init.kaiming_normal_(m.weight, nonlinearity="relu", generator=g)
    return model


@pytest.fixture(scope="module")
def images():
    return torch.rand(2, 3, 64, 80, generator=torch.Generator().manual_seed(2))


@pytest.fixture(scope="module")
def features(random_model, images):
    with torch.no_grad():
        return random_model(images)


def test_random_init_gives_pool3_features(random_model, features):
    assert not random_model.training
    feats = features
    assert feats.shape == (2, 2048) and feats.dtype == torch.float32
    assert torch.isfinite(feats).all() and (feats >= 0).all()  # pool3 averages ReLU outputs
    assert not torch.equal(feats[0], feats[1])
    with pytest.raises(ValueError, match=r"\(N, 3, H, W\)"):
        random_model(torch.zeros(2, 1, 8, 8))


def test_state_dict_uses_pytorch_fid_names():
    sd = InceptionFeatures().state_dict()
    shapes = {k: tuple(v.shape) for k, v in sd.items()}
    assert shapes["Conv2d_1a_3x3.conv.weight"] == (32, 3, 3, 3)
    assert shapes["Conv2d_1a_3x3.bn.running_mean"] == (32,)
    assert shapes["Conv2d_4a_3x3.conv.weight"] == (192, 80, 3, 3)
    assert shapes["Mixed_5b.branch1x1.conv.weight"] == (64, 192, 1, 1)
    assert shapes["Mixed_5b.branch_pool.conv.weight"] == (32, 192, 1, 1)
    assert shapes["Mixed_6b.branch7x7_2.conv.weight"] == (128, 128, 1, 7)
    assert shapes["Mixed_6e.branch7x7dbl_5.conv.weight"] == (192, 192, 1, 7)
    assert shapes["Mixed_7a.branch7x7x3_4.conv.weight"] == (192, 192, 3, 3)
    assert shapes["Mixed_7b.branch3x3dbl_3b.conv.weight"] == (384, 384, 3, 1)
    assert shapes["Mixed_7c.branch_pool.conv.weight"] == (192, 2048, 1, 1)
    assert shapes["fc.weight"] == (1008, 2048) and shapes["fc.bias"] == (1008,)
    # torchvision's Inception3(aux_logits=False) with pytorch-fid's blocks has 566 entries, 94 of them batch counters
    assert len(sd) == 566 and sum(k.endswith("num_batches_tracked") for k in sd) == 94
    assert not any("Aux" in k for k in sd)
    bns = [m for m in InceptionFeatures().modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert len(bns) == 94 and all(m.eps == 0.001 for m in bns)


class _Stop(Exception):
    pass


def test_input_is_resized_bilinearly_and_mapped_to_minus_one_one(random_model):
    x = torch.rand(1, 3, 40, 52, generator=torch.Generator().manual_seed(3))
    seen = []

    def grab(module, args):
        seen.append(args[0])
        raise _Stop  # the first layer's input is all this test needs; skip the rest of the network

    hook = random_model.Conv2d_1a_3x3.register_forward_pre_hook(grab)
    try:
        with torch.no_grad(), pytest.raises(_Stop):
            random_model(x.double())  # any float dtype: the network runs in float32
    finally:
        hook.remove()
    expected = 2 * F.interpolate(x, size=(299, 299), mode="bilinear", align_corners=False) - 1
    assert seen[0].dtype == torch.float32
    torch.testing.assert_close(seen[0], expected, rtol=0, atol=1e-6)


def test_safetensors_and_pth_load_to_identical_features(random_model, images, features, tmp_path):
    sd = random_model.state_dict()
    pth, st = tmp_path / "pt_inception.pth", tmp_path / "inception.safetensors"
    torch.save(sd, pth)
    save_file({k: v.contiguous() for k, v in sd.items()}, str(st))
    a, b = load_inception(pth), load_inception(str(st))
    assert not a.training and not b.training
    with torch.no_grad():
        fa, fb = a(images), b(images)
    assert torch.equal(fa, fb) and torch.equal(fa, features)
    # pytorch-fid's file predates torch 1.6, so it is in the legacy (non-zip) format; weights_only reads that too
    legacy = tmp_path / "legacy.pth"
    torch.save(sd, legacy, _use_new_zipfile_serialization=False)
    loaded = load_inception(legacy).state_dict()
    assert all(torch.equal(loaded[k], v) for k, v in sd.items())


def test_file_without_batch_counters_loads(random_model, tmp_path):
    # Weight files from before torch 0.4.1 carry no num_batches_tracked; eval mode never reads them.
    sd = {k: v for k, v in random_model.state_dict().items() if not k.endswith("num_batches_tracked")}
    path = tmp_path / "old.safetensors"
    save_file({k: v.contiguous() for k, v in sd.items()}, str(path))
    loaded = load_inception(path).state_dict()
    for k, v in sd.items():
        assert torch.equal(loaded[k], v)


def test_missing_file_says_what_is_needed(tmp_path):
    path = tmp_path / "nowhere" / "pt_inception.pth"
    with pytest.raises(EvaluationError) as e:
        load_inception(path)
    msg = str(e.value)
    assert str(path) in msg and "pt_inception-2015-12-05-6726825d.pth" in msg
    assert "--inception PATH" in msg and "nothing is downloaded" in msg
    assert isinstance(e.value, ValueError)


def test_wrong_keys_and_shapes_are_named(random_model, tmp_path):
    sd = dict(random_model.state_dict())
    sd["fc.weight"] = torch.zeros(1000, 2048)
    sd["AuxLogits.fc.weight"] = torch.zeros(1000, 768)
    del sd["Mixed_7c.branch_pool.conv.weight"]
    path = tmp_path / "wrong.pth"
    torch.save(sd, path)
    with pytest.raises(EvaluationError) as e:
        load_inception(path)
    msg = str(e.value)
    assert str(path) in msg
    assert "missing keys: Mixed_7c.branch_pool.conv.weight (192, 2048, 1, 1)" in msg
    assert "unexpected keys: AuxLogits.fc.weight (1000, 768)" in msg
    assert "fc.weight (1000, 2048) (expected (1008, 2048))" in msg


class NotATensor:
    pass


def test_unreadable_files_are_refused(tmp_path):
    pickled = tmp_path / "object.pth"
    with open(pickled, "wb") as f:
        pickle.dump({"x": NotATensor()}, f, protocol=2)  # weights_only refuses arbitrary classes
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"not a safetensors file")
    other = tmp_path / "weights.npz"
    other.write_bytes(b"")
    listed = tmp_path / "list.pt"
    torch.save([torch.zeros(1)], listed)
    for path, reason in ((pickled, "cannot read"), (junk, "cannot read"), (other, "unsupported"),
                         (listed, "not a state dict")):
        with pytest.raises(EvaluationError, match=reason) as e:
            load_inception(path)
        assert str(path) in str(e.value)
