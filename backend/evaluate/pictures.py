"""Pictures of an evaluation, for people: a contact sheet per task and the metrics against the shift.

Videos are (T, 3, H, W) tensors (or lists of (3, H, W) frames), display values in [0, 1]. Files are written
atomically (``core.outputs``), PNG through OpenCV, the plot through matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from scpainter_blender.core import outputs

#: Frames shown per task: first, middle and last.
SHEET_ROWS = 3
LABEL_PX = 18


def contact_sheet(path: str, videos: dict) -> None:
    """A PNG at ``path``: one column per video of ``videos`` {title: video} (e.g. condition, generated, ground
    truth), one row per shown frame (first, middle, last), each column titled. Videos of one task share their
    size and length."""
    import cv2

    titles = list(videos)
    frames = [torch.stack(list(v)) if not torch.is_tensor(v) else v for v in videos.values()]
    T, _, H, W = frames[0].shape
    rows = sorted({0, T // 2, T - 1})[:SHEET_ROWS]
    sheet = np.full((LABEL_PX + len(rows) * (H + 2), len(titles) * (W + 2), 3), 255, np.uint8)
    for c, (title, video) in enumerate(zip(titles, frames)):
        x = c * (W + 2)
        cv2.putText(sheet, title, (x + 3, LABEL_PX - 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        for r, t in enumerate(rows):
            img = (video[t].permute(1, 2, 0).clamp(0, 1).cpu().numpy() * 255.0 + 0.5).astype(np.uint8)
            y = LABEL_PX + r * (H + 2)
            sheet[y:y + H, x:x + W] = img
    ok, png = cv2.imencode(".png", cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    if not ok:  # OpenCV's encoder failing on a plain uint8 image would be a bug, not input
        raise RuntimeError(f"OpenCV could not encode {path}")
    with outputs.atomic_write(path) as f:
        f.write(png.tobytes())


def metrics_plot(path: str, ground_truth: list, temporal: list) -> None:
    """A PNG at ``path``: PSNR of covered pixels (rows of evaluation.json's ``ground_truth``) and the flow-warping
    error (its ``temporal`` rows) against the lateral shift in metres, one line per output (naive, generated,
    ground truth), the tasks that insert a car apart."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, rows, key, label in ((axes[0], ground_truth, "psnr_covered", "PSNR of covered pixels (dB)"),
                                 (axes[1], temporal, "warping_error", "flow-warping error")):
        series = lambda r: r["output"] + (" (car inserted)" if r["task"].startswith("insert") else "")  # noqa: E731
        for name in sorted({series(r) for r in rows}):
            pts = sorted((r["shift_m"], r[key]) for r in rows if series(r) == name and r.get(key) is not None
                         and not math.isnan(r[key]))
            if pts:
                ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=name)
        ax.ticklabel_format(axis="y", useOffset=False)  # equal values must not look far apart on an offset axis
        ax.set_xlabel("lateral shift (m)")
        ax.set_ylabel(label)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    fig.tight_layout()
    with outputs.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
