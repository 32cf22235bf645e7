"""``python -m backend serve``: a warm backend that runs render/generate/export requests read from standard input
one after another in this process (``backend/serve.py``; docs/design.md §12). Its name, request lines and the
commands it runs: ``core.backend_protocol`` (``SERVE``, ``SERVED_COMMANDS``)."""

from __future__ import annotations

import argparse

from scpainter_blender.core.backend_protocol import SERVE

from . import options

NAME = SERVE
ORDER = 110


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``serve``'s parser."""
    w = sub.add_parser(NAME, help="a warm backend: run render/generate/export requests read from standard input "
                                  "(one JSON object per line) one after another in this process, keeping the "
                                  "renderer's kernels, points and assets loaded (what the add-on starts once per "
                                  "Blender session; docs/design.md §12)")
    w.add_argument("--idle-timeout", type=options.non_negative, default=600.0, metavar="S",
                   help="end after S seconds without a request (0: never; default 600); it also ends when standard "
                        "input ends, on a quit request and on SIGTERM")
    options.device_option(w, "whose kernels to load (or compile) at the start; each request names its own")
    w.set_defaults(func=run)
    return w


def run(args: argparse.Namespace) -> int:
    """Serve until standard input ends, a quit request, the idle timeout or a signal; exit 0."""
    from .. import serve

    return serve.serve(args.idle_timeout, options.resolve_device(args.device))
