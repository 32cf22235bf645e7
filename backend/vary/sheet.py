"""The contact sheet of a variation: the first frame of every variant in a grid, each captioned with what it
holds, so a person sees in one picture what a run made (docs/design.md §16). Drawn with OpenCV, written by the
backend's PNG writer.

A placed and rendered variant shows its labelled preview (boxes drawn; else the plain preview); a placed variant
not rendered yet, or one that could not be placed, shows a grey tile saying so.
"""

from __future__ import annotations

import math
import os
import re

import numpy as np

from scpainter_blender.core import fields, files, outputs
from scpainter_blender.core.errors import InputError
from scpainter_blender.core.job import MAX_PIXELS
from scpainter_blender.core.output_layout import VariationLayout
from scpainter_blender.core.variation.spec import MAX_CARS, MAX_VARIANTS, VariationError

from ..png import has_text, write_png

CAPTION_PX = 16
#: The grid is at most this many tiles wide.
MAX_COLUMNS = 8
#: Tiles are scaled to this width (pixels).
TILE_WIDTH = 320
#: What a manifest (read from a folder someone may have handed over) can make the sheet allocate: at most this
#: many tiles (the first variants; a ``warning`` says how many more there are: ``TRUNCATED``), each at most
#: ``MAX_TILE_HEIGHT`` pixels high (a taller preview is cut), so the sheet is at most 8 x 32 tiles of 322 x 658
#: pixels (0.16 GB; previews of 16:9, 180 rows: 50 MB); a preview is decoded only when its PNG header says it holds at
#: most a job's ``MAX_PIXELS`` and its file at most ``MAX_PREVIEW_BYTES``.
MAX_TILES = 256
MAX_TILE_HEIGHT = 2 * TILE_WIDTH
MAX_PREVIEW_BYTES = 256 * 2 ** 20
#: The ``tEXt`` chunk every sheet carries (``png.write_png``): a file at the destination without it is a user's,
#: never replaced (``png.has_text``).
SHEET_MARK = ("Software", "SCPainter contact-sheet")
#: The warning code of a sheet showing fewer variants than the manifest lists.
TRUNCATED = "contact_sheet_truncated"
#: A variant's name in the manifest (``VariationLayout.variant_name``: "v" and at least that many digits).
_VARIANT_ID = re.compile(rf"v\d{{{VariationLayout.VARIANT_DIGITS},7}}")
_OUTCOMES = ("placed", "unplaced")


def _entry(e: object, path: str, where: str) -> dict:
    """A manifest entry, checked for what the sheet reads of it (``VariationError`` naming the field): ``id`` a
    variant's name, ``outcome``, ``camera.shift_m`` (and ``camera.lane_change.shift_m``) finite numbers, ``cars`` a
    list of at most ``MAX_CARS`` objects whose ``mode`` is a name, ``unplaced.rejections`` {rule: count}."""
    def obj(v, field):
        if not isinstance(v, dict):
            raise VariationError(path, field, f"expected an object, got {fields.short(v)}", hint="run vary again")
        return v

    obj(e, where)
    vid = e.get("id")
    if not isinstance(vid, str) or not _VARIANT_ID.fullmatch(vid):
        raise VariationError(path, f"{where}.id", f"expected a variant's name such as "
                                                  f"{VariationLayout.variant_name(0)!r}, got {fields.short(vid)}")
    if e.get("outcome") not in _OUTCOMES:
        raise VariationError(path, f"{where}.outcome", f"expected one of {list(_OUTCOMES)}, got "
                                                       f"{fields.short(e.get('outcome'))}")
    cam = obj(e.get("camera"), f"{where}.camera")
    fields.number(cam.get("shift_m"), path, f"{where}.camera.shift_m", error=VariationError)
    if cam.get("lane_change") is not None:
        lane = obj(cam["lane_change"], f"{where}.camera.lane_change")
        fields.number(lane.get("shift_m"), path, f"{where}.camera.lane_change.shift_m", error=VariationError)
    cars = e.get("cars")
    if not isinstance(cars, list) or len(cars) > MAX_CARS:
        raise VariationError(path, f"{where}.cars", f"expected a list of at most {MAX_CARS} cars, got "
                                                    f"{fields.short(cars)}")
    for i, car in enumerate(cars):
        fields.string(obj(car, f"{where}.cars[{i}]").get("mode"), path, f"{where}.cars[{i}].mode",
                      error=VariationError)
    if e["outcome"] == "unplaced" and e.get("unplaced") is not None:
        rej = obj(obj(e["unplaced"], f"{where}.unplaced").get("rejections", {}), f"{where}.unplaced.rejections")
        for k, v in rej.items():
            fields.integer(v, path, f"{where}.unplaced.rejections.{k}", lo=0, error=VariationError)
    return e


def _caption(entry: dict) -> str:
    cam = entry["camera"]
    text = f"{entry['id']}  shift {cam['shift_m']:+.1f} m"
    if cam.get("lane_change"):
        text += f" lane {cam['lane_change']['shift_m']:+.1f}"
    modes = [c["mode"][0] for c in entry["cars"]]
    return text + f"  {len(modes)} car{'s' if len(modes) != 1 else ''} ({''.join(modes)})" if modes else text


def _png_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG's header, None when ``data`` is not a PNG."""
    if len(data) < 24 or data[:8] != b"\x89PNG\r\n\x1a\n" or data[12:16] != b"IHDR":
        return None
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def _read_preview(path: str, root: str):
    """A preview PNG as RGB uint8, or None: a file that resolves outside ``root`` (a planted link), is not a
    regular file (a FIFO is never waited on), is larger than the bounds, or is not a PNG OpenCV decodes."""
    import cv2

    if not outputs.inside(path, root):
        return None
    try:
        with files.open_regular(path) as f:
            data = f.read(MAX_PREVIEW_BYTES + 1)
    except (InputError, OSError):
        return None
    size = _png_size(data)
    if len(data) > MAX_PREVIEW_BYTES or size is None or not 0 < size[0] * size[1] <= MAX_PIXELS:
        return None
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    return None if img is None else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _first_frame(folder: str, root: str):
    """The variant's first labelled preview (or plain preview) as RGB uint8, or None when not rendered from the
    job now there: its render record (written when a render starts) must be no older than the job (``vary``
    rewrites a job only when it changes), so a picture of an earlier run's job is never shown under this one.
    Only files inside the variation folder ``root`` are read (``_read_preview``)."""
    from scpainter_blender.core.output_layout import CONDITION_PREVIEW, LABELLED_PREVIEW, OutputLayout

    layout = OutputLayout(folder)
    shown = layout.camera(_first_camera(layout.job)) if not os.path.lexists(layout.record) else layout
    try:
        if os.stat(shown.record).st_mtime_ns < os.stat(layout.job).st_mtime_ns:
            return None
    except (OSError, ValueError):  # no record: never rendered
        return None
    cond = shown.conditions
    if not outputs.inside(cond, root):
        return None
    for kind in (LABELLED_PREVIEW, CONDITION_PREVIEW):
        for found in kind.in_folder(cond)[:1]:
            img = _read_preview(found, root)
            if img is not None:
                return img
    return None


def _first_camera(job_path: str) -> str:
    """The first camera's name of a rig job's variant (its frames are in that camera's folder, docs/design.md §17),
    or "" when the job is none (a single camera's, unreadable: its own folder is looked at)."""
    from scpainter_blender.core import rig as rig_mod

    try:
        name = files.read_json(job_path)["rig"]["cameras"][0]["name"]
    except (InputError, KeyError, IndexError, TypeError):
        return ""
    return name if isinstance(name, str) and rig_mod.NAME_PATTERN.fullmatch(name) else ""


def contact_sheet(root: str, out: str | None = None) -> dict:
    """Write the contact sheet of the variation folder ``root`` (``VariationLayout``) to ``out`` (default its
    ``contact_sheet.png``), atomically. Returns {"path", "variants", "shown", "rendered", "unplaced",
    "not_rendered"} (the counts over the tiles shown: the first ``MAX_TILES`` variants). ``VariationError``
    naming the field when ``root`` holds no manifest or its fields are not what ``vary`` writes."""
    import cv2

    layout = VariationLayout(root)
    manifest = files.read_json(layout.manifest, error=VariationError)
    if not isinstance(manifest, dict):
        raise VariationError(layout.manifest, "(top level)", "expected a JSON object", hint="run vary again")
    if manifest.get("state") == "running":   # vary's manifest while it writes (variants.make_variants)
        raise VariationError(layout.manifest, "state", "says the vary run writing this folder has not finished (or "
                                                       "was stopped)", hint="wait for it, or run vary again")
    path = os.path.abspath(out or layout.sheet)
    if os.path.lexists(path) and not has_text(path, *SHEET_MARK):
        raise VariationError(path, "--out", "exists and is not a contact sheet this command wrote: it is never "
                                            "replaced", hint="move it away, or give another --out")
    entries = manifest.get("variants")
    if not isinstance(entries, list) or not entries:
        raise VariationError(layout.manifest, "variants", "lists no variants", hint="run vary again")
    if len(entries) > MAX_VARIANTS:
        raise VariationError(layout.manifest, "variants", f"lists {len(entries):,} variants, more than vary makes "
                                                          f"({MAX_VARIANTS:,})", hint="run vary again")
    shown = [_entry(e, layout.manifest, f"variants[{i}]") for i, e in enumerate(entries[:MAX_TILES])]
    tiles, counts = [], {"rendered": 0, "unplaced": 0, "not_rendered": 0}
    th = None
    for e in shown:
        img = _first_frame(os.path.join(layout.root, e["id"]), layout.root) if e["outcome"] == "placed" else None
        if img is not None:
            h = max(1, min(MAX_TILE_HEIGHT, round(img.shape[0] * TILE_WIDTH / img.shape[1])))
            img = cv2.resize(img, (TILE_WIDTH, h), interpolation=cv2.INTER_AREA)
            th = th or h
            counts["rendered"] += 1
            note = None
        else:
            key = "unplaced" if e["outcome"] != "placed" else "not_rendered"
            counts[key] += 1
            note = "not rendered (since its job was written)"
            if key == "unplaced":
                rej = (e.get("unplaced") or {}).get("rejections", {})
                note = "not placed: " + ", ".join(f"{k} {v}" for k, v in sorted(rej.items(), key=lambda kv: -kv[1])
                                                  if v)[:40]
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
    write_png(path, sheet, text=dict([SHEET_MARK]))  # the backend's one PNG writer (atomic)
    return dict(path=path, variants=len(entries), shown=len(shown), **counts)
