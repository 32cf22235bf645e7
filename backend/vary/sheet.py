"""The contact sheet of a variation: the first frame of every variant in a grid, each captioned with what it
holds, so a person sees in one picture what a run made (docs/design.md §16). Drawn with OpenCV, written by the
backend's PNG writer.

A placed and rendered variant shows its labelled preview (boxes drawn; else the plain preview); a placed variant
not rendered yet, or one that could not be placed, shows a grey tile saying so.
"""

from __future__ import annotations

import math
import os

import numpy as np

from scpainter_blender.core import files
from scpainter_blender.core.output_layout import VariationLayout
from scpainter_blender.core.variation.spec import VariationError

from ..png import write_png

CAPTION_PX = 16
#: The grid is at most this many tiles wide.
MAX_COLUMNS = 8
#: Tiles are scaled to this width (pixels).
TILE_WIDTH = 320


def _caption(entry: dict) -> str:
    cam = entry["camera"]
    text = f"{entry['id']}  shift {cam['shift_m']:+.1f} m"
    if cam.get("lane_change"):
        text += f" lane {cam['lane_change']['shift_m']:+.1f}"
    modes = [c["mode"][0] for c in entry["cars"]]
    return text + f"  {len(modes)} car{'s' if len(modes) != 1 else ''} ({''.join(modes)})" if modes else text


def _first_frame(folder: str):
    """The variant's first labelled preview (or plain preview) as RGB uint8, or None when not rendered from the
    job now there: its render record (written when a render starts) must be no older than the job (``vary``
    rewrites a job only when it changes), so a picture of an earlier run's job is never shown under this one."""
    import cv2

    from scpainter_blender.core.output_layout import CONDITION_PREVIEW, LABELLED_PREVIEW, OutputLayout

    layout = OutputLayout(folder)
    try:
        if os.stat(layout.record).st_mtime_ns < os.stat(layout.job).st_mtime_ns:
            return None
    except OSError:  # no record: never rendered
        return None
    cond = layout.conditions
    for kind in (LABELLED_PREVIEW, CONDITION_PREVIEW):
        found = kind.in_folder(cond)
        if found:
            img = cv2.imread(found[0], cv2.IMREAD_COLOR)
            if img is not None:
                return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return None


def contact_sheet(root: str, out: str | None = None) -> dict:
    """Write the contact sheet of the variation folder ``root`` (``VariationLayout``) to ``out`` (default its
    ``contact_sheet.png``). Returns {"path", "variants", "rendered", "unplaced", "not_rendered"}. ``VariationError``
    when ``root`` holds no manifest."""
    import cv2

    layout = VariationLayout(root)
    manifest = files.read_json(layout.manifest, error=VariationError)
    entries = manifest.get("variants")
    if not isinstance(entries, list) or not entries:
        raise VariationError(layout.manifest, "variants", "lists no variants", hint="run vary again")
    tiles, counts = [], {"rendered": 0, "unplaced": 0, "not_rendered": 0}
    th = None
    for e in entries:
        img = _first_frame(layout.variant(int(e["id"][1:])).root) if e.get("outcome") == "placed" else None
        if img is not None:
            h = round(img.shape[0] * TILE_WIDTH / img.shape[1])
            img = cv2.resize(img, (TILE_WIDTH, h), interpolation=cv2.INTER_AREA)
            th = th or h
            counts["rendered"] += 1
            note = None
        else:
            key = "unplaced" if e.get("outcome") != "placed" else "not_rendered"
            counts[key] += 1
            rej = (e.get("unplaced") or {}).get("rejections", {})
            worst = ", ".join(f"{k} {v}" for k, v in sorted(rej.items(), key=lambda kv: -kv[1]) if v)[:40]
            note = "not placed: " + worst if key == "unplaced" else "not rendered (since its job was written)"
        tiles.append((img, _caption(e), note))
    th = th or round(TILE_WIDTH * 9 / 16)
    cols = min(MAX_COLUMNS, len(tiles))
    rows = math.ceil(len(tiles) / cols)
    sheet = np.full((rows * (th + CAPTION_PX + 2), cols * (TILE_WIDTH + 2), 3), 255, np.uint8)
    for k, (img, caption, note) in enumerate(tiles):
        y, x = (k // cols) * (th + CAPTION_PX + 2), (k % cols) * (TILE_WIDTH + 2)
        cv2.putText(sheet, caption, (x + 3, y + CAPTION_PX - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 1,
                    cv2.LINE_AA)
        tile = sheet[y + CAPTION_PX:y + CAPTION_PX + th, x:x + TILE_WIDTH]
        if img is not None:
            tile[:] = img[:th] if img.shape[0] >= th else np.pad(img, ((0, th - img.shape[0]), (0, 0), (0, 0)))
        else:
            tile[:] = 200
            cv2.putText(tile, note, (6, th // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (60, 60, 60), 1, cv2.LINE_AA)
    path = os.path.abspath(out or layout.sheet)
    write_png(path, sheet)  # the backend's one PNG writer (atomic)
    return dict(path=path, variants=len(entries), **counts)
