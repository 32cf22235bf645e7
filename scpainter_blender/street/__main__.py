"""``python -m scpainter_blender.street --out DIR [--params JSON]``: generate one street into DIR (needs bpy)."""

import argparse
import json
import sys

from .dataset import StreetParams


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m scpainter_blender.street", description=__doc__)
    p.add_argument("--out", required=True)
    p.add_argument("--params", default="{}", help="StreetParams fields as JSON")
    args = p.parse_args(argv)
    fields = json.loads(args.params)
    if "shifts_m" in fields:
        fields["shifts_m"] = tuple(fields["shifts_m"])
    from .render import render_drive

    info = render_drive(StreetParams(**fields), args.out, log=lambda m: print(m, file=sys.stderr, flush=True))
    print(json.dumps({"event": "done", "timings_s": info["timings_s"]}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
