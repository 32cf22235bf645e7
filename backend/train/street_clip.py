"""The ground-truth street as a training clip (``scpainter.clip/1``), for the documented street training run.

The clip holds the recorded drive only: predictions, metric poses, frames and the parked cars' boxes. Each parked
car gets a Gaussian asset standing in for an Amodal3R reconstruction: the procedural car shape the street was
built with (core.shapes), painted with the median colour of the car's pixels in the recorded frames, centred in
its box (so ``asset_to_box`` is the identity). The shifted ground-truth renders come along as the clip's ``views``: the
evaluation's ground truth, which the trainer never reads.
"""

from __future__ import annotations

import os

import numpy as np

from scpainter_blender.core import outputs, shapes
from scpainter_blender.core.splats import gaussians as splats, inria as splats_inria

from . import clip as clip_mod


def car_paint(street, instance: int) -> tuple:
    """Median sRGB colour of the pixels of one parked car (instance id) over the recorded frames."""
    from PIL import Image

    inst = street.metric()["instance"]
    picks = []
    for i in range(inst.shape[0]):
        m = inst[i] == instance
        if m.any():
            with Image.open(street.frame_path("recorded", i)) as im:
                picks.append(np.asarray(im.convert("RGB"), np.float32)[m] / 255.0)
    if not picks:
        return (0.5, 0.5, 0.5)
    return tuple(float(v) for v in np.median(np.concatenate(picks), axis=0))


def export_clip(street, out: str, gaussians_per_car: int = 8000) -> str:
    """Write the street's recorded drive as a clip folder at ``out`` (built beside it, renamed when complete).
    Returns the path of its clip.json."""
    out = os.path.abspath(out)
    if os.path.exists(os.path.join(out, "clip.json")):
        return os.path.join(out, "clip.json")
    os.makedirs(os.path.dirname(out), exist_ok=True)
    with outputs.atomic_folder(out) as tmp:
        S = street.params.num_frames
        outputs.link_or_copy(street.predictions_path, os.path.join(tmp, "predictions.npz"))
        metric = street.metric()
        np.savez(os.path.join(tmp, "poses.npz"), world_to_camera=metric["world_to_camera"], K=metric["K"],
                 vggt_to_world=metric["vggt_to_world"])
        os.makedirs(os.path.join(tmp, "frames"))
        for i in range(S):
            outputs.link_or_copy(street.frame_path("recorded", i), os.path.join(tmp, "frames", f"frame_{i:06d}.png"))
        views = {}
        # ground truth for evaluation (the trainer never reads it); street.views = ["recorded", one per shift]
        for shift, name in zip(street.params.shifts_m, street.views[1:]):
            os.makedirs(os.path.join(tmp, "views", name))
            for i in range(S):
                outputs.link_or_copy(street.frame_path(name, i), os.path.join(tmp, "views", name, f"frame_{i:06d}.png"))
            views[f"{shift:g}"] = f"views/{name}/frame_{{:06d}}.png"
        os.makedirs(os.path.join(tmp, "assets"))
        cars = []
        for car in street.info["cars"]:
            k = int(car["instance"])
            g = shapes.procedural_car_gaussians(gaussians_per_car, seed=k, paint=car_paint(street, k))
            A = clip_mod.fit_asset_to_box(g.means, np.array(car["size"]))
            A[:3, :3] = np.eye(3)  # the street's cars are the procedural shape at scale 1: centre only
            name = f"assets/car_{k}.ply"
            splats_inria.write_ply(os.path.join(tmp, name), splats.encode(shapes.transform_gaussians(g, A)),
                             comment="SCPainter street clip: procedural stand-in for an Amodal3R asset")
            cars.append({"id": car["name"], "size": list(map(float, car["size"])),
                         "boxes": {str(i): car["box_to_world"] for i in range(S)}, "asset": name,
                         "asset_to_box": np.eye(4).tolist()})
        clip_mod.save(os.path.join(tmp, "clip.json"), {
            "schema": clip_mod.SCHEMA, "predictions": "predictions.npz", "frames": "frames/frame_{:06d}.png",
            "poses": "poses.npz", "cars": cars, "views": views, "fps": 10.0,
            "source": {"street": street.root, "params": street.info["params"]}})
    return os.path.join(out, "clip.json")
