"""The README's pictures of the artist's loop, made headless from the demo's output.

    .venv/bin/python tools/demo.py && .venv/bin/python tools/screenshots.py [--demo build/demo]

Blender cannot draw its UI or viewport without a display (``render.opengl`` needs an OpenGL context, which the
bpy module in background mode does not have), so instead of screen captures this composes what the loop produces:
the Cycles render of the scene from the new camera path (points and the Gaussian car), the condition image the
backend rendered for that frame, its hole and asset masks, and the generated frame when a checkpoint was used (the
street's ground-truth render of the same view otherwise). Writes docs/images/loop.png.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np
from PIL import Image, ImageDraw

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def tile(img: np.ndarray, label: str, width: int) -> Image.Image:
    im = Image.fromarray((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)) if img.dtype != np.uint8 else \
        Image.fromarray(img)
    im = im.convert("RGB").resize((width, round(im.height * width / im.width)), Image.LANCZOS)
    draw = ImageDraw.Draw(im)
    draw.rectangle([0, 0, width, 16], fill=(0, 0, 0))
    draw.text((4, 2), label, fill=(255, 255, 255))
    return im


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--demo", default=os.path.join(ROOT, "build", "demo"))
    p.add_argument("--out", default=os.path.join(ROOT, "docs", "images", "loop.png"))
    p.add_argument("--frame", type=int, default=1)
    p.add_argument("--shift", type=float, default=2.0, help="the demo's camera-path shift (for the true view)")
    args = p.parse_args(argv)
    from backend.render import channels
    from scpainter_blender.core import job as job_mod
    from scpainter_blender.core.output_layout import OutputLayout
    from scpainter_blender.street.dataset import ensure_street, view_name

    layout = OutputLayout(args.demo)
    job = job_mod.load(layout.job)
    cond = channels.read(layout.condition_exr(args.frame))
    image = np.stack([cond[c] for c in channels.IMAGE], -1)
    masks = np.repeat(cond[channels.HOLE][..., None], 3, -1) * 0.85
    masks[cond[channels.ASSET_MASK] > 0.5] = (0.9, 0.2, 0.2)
    W = 518
    tiles = [tile(np.asarray(Image.open(os.path.join(args.demo, "preview.png")).convert("RGB")),
                  "1. the scene in Blender from the 2 m path (Cycles)", W),
             tile(image, "2. Render Conditions: image I (points + car)", W),
             tile(masks, "3. hole mask M (grey) and asset mask M_a (red)", W)]
    generated = layout.generated_frame(args.frame)
    if os.path.isfile(generated):
        tiles.append(tile(np.asarray(Image.open(generated).convert("RGB")), "4. Generate: the video frame", W))
    else:
        street = ensure_street(log=lambda m: None)
        gt = street.frame_path(view_name(args.shift), job.frames[0].frame - 1)
        tiles.append(tile(np.asarray(Image.open(gt).convert("RGB")),
                          "4. (no checkpoint) the true view, without the car", W))
    h = max(t.height for t in tiles)
    sheet = Image.new("RGB", (2 * W, 2 * h), (0, 0, 0))
    for i, t in enumerate(tiles):
        sheet.paste(t, ((i % 2) * W, (i // 2) * h))
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    sheet.save(args.out + ".tmp.png")
    os.replace(args.out + ".tmp.png", args.out)
    print(args.out)


if __name__ == "__main__":
    main()
