"""``python -m backend contact-sheet``: the first frame of every variant of a vary folder in one picture
(``backend/vary/sheet.py``; docs/design.md §16)."""

from __future__ import annotations

import argparse

from .. import events

NAME = "contact-sheet"
ORDER = 130


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``contact-sheet``'s parser."""
    from scpainter_blender.core.output_layout import VariationLayout

    s = sub.add_parser(NAME, help="the first frame of every variant of a vary folder in one picture")
    s.add_argument("folder", help="the folder vary wrote")
    s.add_argument("--out", help=f"PNG to write (default: {VariationLayout.SHEET} in the folder)")
    s.set_defaults(func=run)
    return s


def run(args: argparse.Namespace) -> int:
    """Write the sheet; an ``artifact`` event (the PNG) and a ``done`` event."""
    from ..vary import sheet

    result = sheet.contact_sheet(args.folder, args.out)
    if result["shown"] < result["variants"]:
        events.warning(f"the sheet shows the first {result['shown']:,} of {result['variants']:,} variants "
                       f"(at most {sheet.MAX_TILES} tiles)", sheet.TRUNCATED)
    events.artifact(result["path"], kind="contact_sheet")
    events.done(command=NAME, **result)
    return events.EXIT_OK
