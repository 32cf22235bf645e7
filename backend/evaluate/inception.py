"""The Inception-v3 network used for FID: TensorFlow's 2015-12-05 graph in the layout of pytorch-fid's port.

Module and parameter names follow torchvision's ``Inception3`` (without the auxiliary classifier), so
``load_state_dict`` accepts pytorch-fid's ``pt_inception-2015-12-05-6726825d.pth`` key for key. The FID graph differs
from torchvision's ImageNet Inception in three places, all reproduced here:

- the pool branch of the A, C and first E blocks averages without counting the zero padding
  (``count_include_pad=False``, TensorFlow's ``AVG`` pooling with ``SAME`` padding);
- the pool branch of the last E block (``Mixed_7c``) is a 3x3 *max* pool;
- the classifier has 1008 outputs (unused by FID, kept so the weight file loads strictly).

Nothing is ever downloaded: the weights come from a local file the user names (``--inception PATH``).
"""

from __future__ import annotations

import os

import torch
import torch.nn.functional as F
from torch import nn

from scpainter_blender.core import errors

WEIGHTS_FILE = "pt_inception-2015-12-05-6726825d.pth"
FEATURE_DIM = 2048
INPUT_SIZE = 299


class EvaluationError(errors.InputError):
    """Evaluation input that cannot be used (the ``--inception`` weights file): ``str()`` is ``"<full path>:
    <what is wrong>"``; ``field`` the part at fault (``"(file)"`` for the file as a whole)."""

    def __init__(self, path: str | os.PathLike, message: str, field: str | None = None,
                 hint: str | None = None) -> None:
        errors.InputError.__init__(self, path, field, message, hint)
        self.args = (f"{self.path}: {message}",)


class BasicConv2d(nn.Module):
    """Convolution without bias, batch norm (eps 1e-3, as in the TF graph), ReLU."""

    def __init__(self, cin: int, cout: int, kernel_size: int | tuple[int, int], stride: int = 1,
                 padding: int | tuple[int, int] = 0) -> None:
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, kernel_size, stride=stride, padding=padding, bias=False)
        self.bn = nn.BatchNorm2d(cout, eps=0.001)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.bn(self.conv(x)))


def _avg_pool_same(x: torch.Tensor) -> torch.Tensor:
    # TF averages only over the pixels inside the image at the border; torch's default would count the zero padding.
    return F.avg_pool2d(x, kernel_size=3, stride=1, padding=1, count_include_pad=False)


class InceptionA(nn.Module):
    """35x35 block (Mixed_5b..5d): 64 + 64 + 96 + ``pool_features`` channels out."""

    def __init__(self, cin: int, pool_features: int) -> None:
        super().__init__()
        self.branch1x1 = BasicConv2d(cin, 64, 1)
        self.branch5x5_1 = BasicConv2d(cin, 48, 1)
        self.branch5x5_2 = BasicConv2d(48, 64, 5, padding=2)
        self.branch3x3dbl_1 = BasicConv2d(cin, 64, 1)
        self.branch3x3dbl_2 = BasicConv2d(64, 96, 3, padding=1)
        self.branch3x3dbl_3 = BasicConv2d(96, 96, 3, padding=1)
        self.branch_pool = BasicConv2d(cin, pool_features, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b1 = self.branch1x1(x)
        b5 = self.branch5x5_2(self.branch5x5_1(x))
        b3 = self.branch3x3dbl_3(self.branch3x3dbl_2(self.branch3x3dbl_1(x)))
        bp = self.branch_pool(_avg_pool_same(x))
        return torch.cat([b1, b5, b3, bp], 1)


class InceptionB(nn.Module):
    """Grid reduction 35 -> 17 (Mixed_6a): 384 + 96 + ``cin`` channels out."""

    def __init__(self, cin: int) -> None:
        super().__init__()
        self.branch3x3 = BasicConv2d(cin, 384, 3, stride=2)
        self.branch3x3dbl_1 = BasicConv2d(cin, 64, 1)
        self.branch3x3dbl_2 = BasicConv2d(64, 96, 3, padding=1)
        self.branch3x3dbl_3 = BasicConv2d(96, 96, 3, stride=2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b3 = self.branch3x3(x)
        bd = self.branch3x3dbl_3(self.branch3x3dbl_2(self.branch3x3dbl_1(x)))
        bp = F.max_pool2d(x, kernel_size=3, stride=2)
        return torch.cat([b3, bd, bp], 1)


class InceptionC(nn.Module):
    """17x17 block with factorised 7x7 convolutions (Mixed_6b..6e): 4 x 192 channels out."""

    def __init__(self, cin: int, channels_7x7: int) -> None:
        super().__init__()
        c7 = channels_7x7
        self.branch1x1 = BasicConv2d(cin, 192, 1)
        self.branch7x7_1 = BasicConv2d(cin, c7, 1)
        self.branch7x7_2 = BasicConv2d(c7, c7, (1, 7), padding=(0, 3))
        self.branch7x7_3 = BasicConv2d(c7, 192, (7, 1), padding=(3, 0))
        self.branch7x7dbl_1 = BasicConv2d(cin, c7, 1)
        self.branch7x7dbl_2 = BasicConv2d(c7, c7, (7, 1), padding=(3, 0))
        self.branch7x7dbl_3 = BasicConv2d(c7, c7, (1, 7), padding=(0, 3))
        self.branch7x7dbl_4 = BasicConv2d(c7, c7, (7, 1), padding=(3, 0))
        self.branch7x7dbl_5 = BasicConv2d(c7, 192, (1, 7), padding=(0, 3))
        self.branch_pool = BasicConv2d(cin, 192, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b1 = self.branch1x1(x)
        b7 = self.branch7x7_3(self.branch7x7_2(self.branch7x7_1(x)))
        bd = x
        for layer in (self.branch7x7dbl_1, self.branch7x7dbl_2, self.branch7x7dbl_3, self.branch7x7dbl_4,
                      self.branch7x7dbl_5):
            bd = layer(bd)
        bp = self.branch_pool(_avg_pool_same(x))
        return torch.cat([b1, b7, bd, bp], 1)


class InceptionD(nn.Module):
    """Grid reduction 17 -> 8 (Mixed_7a): 320 + 192 + ``cin`` channels out."""

    def __init__(self, cin: int) -> None:
        super().__init__()
        self.branch3x3_1 = BasicConv2d(cin, 192, 1)
        self.branch3x3_2 = BasicConv2d(192, 320, 3, stride=2)
        self.branch7x7x3_1 = BasicConv2d(cin, 192, 1)
        self.branch7x7x3_2 = BasicConv2d(192, 192, (1, 7), padding=(0, 3))
        self.branch7x7x3_3 = BasicConv2d(192, 192, (7, 1), padding=(3, 0))
        self.branch7x7x3_4 = BasicConv2d(192, 192, 3, stride=2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b3 = self.branch3x3_2(self.branch3x3_1(x))
        b7 = self.branch7x7x3_4(self.branch7x7x3_3(self.branch7x7x3_2(self.branch7x7x3_1(x))))
        bp = F.max_pool2d(x, kernel_size=3, stride=2)
        return torch.cat([b3, b7, bp], 1)


class InceptionE(nn.Module):
    """8x8 block with split 1x3/3x1 convolutions (Mixed_7b, 7c): 320 + 768 + 768 + 192 = 2048 channels out.

    ``max_pool`` selects the pool branch: average (count_include_pad=False) in Mixed_7b, max in Mixed_7c, as in the
    2015-12-05 TF graph.
    """

    def __init__(self, cin: int, max_pool: bool) -> None:
        super().__init__()
        self.max_pool = max_pool
        self.branch1x1 = BasicConv2d(cin, 320, 1)
        self.branch3x3_1 = BasicConv2d(cin, 384, 1)
        self.branch3x3_2a = BasicConv2d(384, 384, (1, 3), padding=(0, 1))
        self.branch3x3_2b = BasicConv2d(384, 384, (3, 1), padding=(1, 0))
        self.branch3x3dbl_1 = BasicConv2d(cin, 448, 1)
        self.branch3x3dbl_2 = BasicConv2d(448, 384, 3, padding=1)
        self.branch3x3dbl_3a = BasicConv2d(384, 384, (1, 3), padding=(0, 1))
        self.branch3x3dbl_3b = BasicConv2d(384, 384, (3, 1), padding=(1, 0))
        self.branch_pool = BasicConv2d(cin, 192, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b1 = self.branch1x1(x)
        t = self.branch3x3_1(x)
        b3 = torch.cat([self.branch3x3_2a(t), self.branch3x3_2b(t)], 1)
        t = self.branch3x3dbl_2(self.branch3x3dbl_1(x))
        bd = torch.cat([self.branch3x3dbl_3a(t), self.branch3x3dbl_3b(t)], 1)
        pooled = F.max_pool2d(x, kernel_size=3, stride=1, padding=1) if self.max_pool else _avg_pool_same(x)
        bp = self.branch_pool(pooled)
        return torch.cat([b1, b3, bd, bp], 1)


class InceptionFeatures(nn.Module):
    """FID Inception-v3 returning pool3 features.

    ``forward(images)``: ``images`` is (N, 3, H, W), RGB, float in [0, 1] holding sRGB *display* values (what a PNG
    stores, not linear light). It is resized to 299x299 (bilinear, ``align_corners=False``, no antialiasing, as
    pytorch-fid does), mapped to [-1, 1] by ``2x - 1`` and run through the network in float32 on the module's
    device. Returns (N, 2048) float32: the output of the final global average pool ("pool3"), before dropout and
    ``fc``. Values outside [0, 1] are not clamped.

    A fresh instance has random weights; use :func:`load_inception` for the real ones. The module starts in eval
    mode with frozen parameters (batch norm must use its running statistics); wrap calls in ``torch.no_grad()``
    when no gradient is wanted. ``fc`` (1008 classes) is never used in ``forward``; it exists so that the weight
    file loads with a strict key check.
    """

    def __init__(self) -> None:
        super().__init__()
        self.Conv2d_1a_3x3 = BasicConv2d(3, 32, 3, stride=2)
        self.Conv2d_2a_3x3 = BasicConv2d(32, 32, 3)
        self.Conv2d_2b_3x3 = BasicConv2d(32, 64, 3, padding=1)
        self.Conv2d_3b_1x1 = BasicConv2d(64, 80, 1)
        self.Conv2d_4a_3x3 = BasicConv2d(80, 192, 3)
        self.Mixed_5b = InceptionA(192, pool_features=32)
        self.Mixed_5c = InceptionA(256, pool_features=64)
        self.Mixed_5d = InceptionA(288, pool_features=64)
        self.Mixed_6a = InceptionB(288)
        self.Mixed_6b = InceptionC(768, channels_7x7=128)
        self.Mixed_6c = InceptionC(768, channels_7x7=160)
        self.Mixed_6d = InceptionC(768, channels_7x7=160)
        self.Mixed_6e = InceptionC(768, channels_7x7=192)
        self.Mixed_7a = InceptionD(768)
        self.Mixed_7b = InceptionE(1280, max_pool=False)
        self.Mixed_7c = InceptionE(2048, max_pool=True)
        self.fc = nn.Linear(FEATURE_DIM, 1008)
        self.requires_grad_(False)
        self.eval()

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        if not torch.is_tensor(images) or images.ndim != 4 or images.shape[1] != 3:
            shape = tuple(images.shape) if hasattr(images, "shape") else type(images).__name__
            raise ValueError(f"InceptionFeatures expects images of shape (N, 3, H, W), got {shape}")
        w = self.fc.weight
        x = images.to(device=w.device, dtype=torch.float32)
        if x.shape[-2:] != (INPUT_SIZE, INPUT_SIZE):
            x = F.interpolate(x, size=(INPUT_SIZE, INPUT_SIZE), mode="bilinear", align_corners=False)
        x = 2.0 * x - 1.0
        x = self.Conv2d_1a_3x3(x)
        x = self.Conv2d_2a_3x3(x)
        x = self.Conv2d_2b_3x3(x)
        x = F.max_pool2d(x, kernel_size=3, stride=2)
        x = self.Conv2d_3b_1x1(x)
        x = self.Conv2d_4a_3x3(x)
        x = F.max_pool2d(x, kernel_size=3, stride=2)
        for block in (self.Mixed_5b, self.Mixed_5c, self.Mixed_5d, self.Mixed_6a, self.Mixed_6b, self.Mixed_6c,
                      self.Mixed_6d, self.Mixed_6e, self.Mixed_7a, self.Mixed_7b, self.Mixed_7c):
            x = block(x)
        return torch.flatten(F.adaptive_avg_pool2d(x, 1), 1).float()


def _describe(keys, tensors, limit=5) -> str:
    keys = sorted(keys)
    shown = ", ".join(f"{k} {tuple(tensors[k].shape)}" for k in keys[:limit])
    more = f" (and {len(keys) - limit} more)" if len(keys) > limit else ""
    return shown + more


def _read_state_dict(path: str) -> dict:
    ext = os.path.splitext(path)[1].lower()
    try:
        if ext == ".safetensors":
            from safetensors.torch import load_file

            state = load_file(path, device="cpu")
        elif ext in (".pth", ".pt"):
            # weights_only: a user-supplied file is never unpickled beyond tensors and plain containers.
            state = torch.load(path, map_location="cpu", weights_only=True)
        else:
            raise EvaluationError(path, f"unsupported Inception weights format {ext or '(no extension)'!r}; "
                                        "expected .safetensors, .pth or .pt")
    except EvaluationError:
        raise
    except Exception as e:  # noqa: BLE001  (any reader failure: corrupt file, a pickle of arbitrary objects)
        raise EvaluationError(path, f"cannot read the Inception weights ({type(e).__name__}: {e})") from None
    if not isinstance(state, dict) or not all(isinstance(k, str) and torch.is_tensor(v) for k, v in state.items()):
        raise EvaluationError(path, f"not a state dict of tensors (the file holds a {type(state).__name__})")
    return dict(state)


def load_inception(path: str | os.PathLike, device: str | torch.device = "cpu") -> InceptionFeatures:
    """The FID Inception with weights from a local file; nothing is downloaded.

    ``path``: pytorch-fid's ``pt_inception-2015-12-05-6726825d.pth`` (read with ``weights_only=True``) or the same
    state dict saved as ``.safetensors``. Every key and shape must match (``num_batches_tracked`` buffers may be
    absent); otherwise :class:`EvaluationError` names the file and the first mismatching keys. Returns the model on
    ``device`` in eval mode.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise EvaluationError(
            path, f"Inception weights file not found. FID needs pytorch-fid's Inception weights file {WEIGHTS_FILE} "
            "(or the same state dict as .safetensors), given with --inception PATH; nothing is downloaded.")
    state = _read_state_dict(path)
    # Built on the meta device: no time spent on a random init that the file replaces; assign=True below adopts the
    # file's tensors as the parameters.
    with torch.device("meta"):
        model = InceptionFeatures()
    expected = model.state_dict()
    for key in expected:
        # Files written before torch 0.4.1 have no batch counters; they play no part in eval mode.
        if key.endswith(".num_batches_tracked") and key not in state:
            state[key] = torch.zeros((), dtype=torch.long)
    missing = expected.keys() - state.keys()
    unexpected = state.keys() - expected.keys()
    mismatched = sorted(k for k in expected.keys() & state.keys() if state[k].shape != expected[k].shape)
    problems = []
    if missing:
        problems.append(f"missing keys: {_describe(missing, expected)}")
    if unexpected:
        problems.append(f"unexpected keys: {_describe(unexpected, state)}")
    if mismatched:
        shown = ", ".join(f"{k} {tuple(state[k].shape)} (expected {tuple(expected[k].shape)})" for k in mismatched[:5])
        more = f" (and {len(mismatched) - 5} more)" if len(mismatched) > 5 else ""
        problems.append(f"wrong shapes: {shown}{more}")
    if problems:
        raise EvaluationError(path, f"not the FID Inception-v3 weights ({WEIGHTS_FILE}); " + "; ".join(problems))
    bad = [k for k, v in state.items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if bad:
        raise EvaluationError(path, f"non-finite values in {', '.join(sorted(bad)[:5])}", sorted(bad)[0])
    # float32 whatever the file stores (the network runs in float32); counters stay integers.
    state = {k: v.float() if v.is_floating_point() else v.long() for k, v in state.items()}
    model.load_state_dict(state, strict=True, assign=True)
    model.requires_grad_(False)
    return model.to(device).eval()
