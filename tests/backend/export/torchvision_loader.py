"""Load a COCO export with torchvision, in a process of its own (test_coco.py runs it): ``python -m
tests.backend.export.torchvision_loader ANNOTATIONS IMAGES OUT.npz`` with ``PYTHONPATH`` naming the folder that holds
torchvision (``requirements-isolated.txt``: never in the environment's site-packages, where it breaks transformers'
import beside a CPU build of torch).

It reads the dataset as a training script would — ``torchvision.datasets.CocoDetection`` wrapped by
``wrap_dataset_for_transforms_v2(ds, target_keys=("boxes", "labels", "masks", "image_id"))`` — and saves, per
image i, ``masks_i`` (N, H, W) bool, ``boxes_i`` (N, 4) XYXY, ``labels_i`` (N,), ``image_id_i`` and ``size_i``
(W, H), plus ``version`` (torchvision's).

PyPI's torchvision wheel is built against PyPI's CUDA torch; beside a CPU build of the same release its compiled
operators do not load, and its import then fails declaring a fake kernel for ``torchvision::nms`` ("operator
torchvision::nms does not exist"). What this loads is pure Python (the masks come from pycocotools), so in that case
the two operators' schemas are declared, without kernels, and the import retried.
"""

import sys

import numpy as np
import torch

#: The operator schemas declared when torchvision's own do not load (see the module's docstring); kept alive.
_SCHEMAS = []


def import_torchvision():
    try:
        import torchvision
    except RuntimeError as e:
        if "torchvision::nms" not in str(e):
            raise
        for name in [n for n in sys.modules if n == "torchvision" or n.startswith("torchvision.")]:
            del sys.modules[name]
        lib = torch.library.Library("torchvision", "DEF")
        for op in ("nms", "qnms"):
            lib.define(f"{op}(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
        _SCHEMAS.append(lib)
        import torchvision
    return torchvision


def main(annotations: str, images: str, out: str) -> None:
    tv = import_torchvision()
    from torchvision import datasets

    ds = datasets.CocoDetection(images, annotations)
    wrapped = datasets.wrap_dataset_for_transforms_v2(ds, target_keys=("boxes", "labels", "masks", "image_id"))
    arrays = {"version": np.array(tv.__version__), "count": np.array(len(wrapped))}
    for i in range(len(wrapped)):
        image, target = wrapped[i]
        arrays[f"masks_{i}"] = target["masks"].numpy().astype(bool)
        arrays[f"boxes_{i}"] = target["boxes"].numpy()
        arrays[f"labels_{i}"] = target["labels"].numpy()
        arrays[f"image_id_{i}"] = np.array(target["image_id"])
        arrays[f"size_{i}"] = np.array(image.size)
    np.savez(out, **arrays)


if __name__ == "__main__":
    main(*sys.argv[1:4])
