"""The two options every bench script shares (issue 44: benches that cannot rot), and where its JSON goes.

``--smoke``: the script's smallest size on the CPU (seconds, no GPU, no network, nothing written outside ``--out``
and temporary folders), what its test in ``tests/bench/test_<name>.py`` runs so that a change that breaks the bench
fails CI. ``--out DIR``: the folder its JSON goes to (default ``bench/results``). A value ending in ``.json`` is
taken as the file itself, as some scripts' ``--out`` was before (``--out bench/results/x_before.json`` keeps working).
"""

from __future__ import annotations

import argparse
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS = os.path.join(ROOT, "bench", "results")


def add_smoke_and_out(parser: argparse.ArgumentParser, what: str = "") -> None:
    """Adds ``--smoke`` and ``--out DIR`` to ``parser``; ``what``: what the smoke size is, for its help."""
    parser.add_argument("--smoke", action="store_true",
                        help="the smallest size on the CPU, in seconds (what the smoke test runs)"
                             + (f": {what}" if what else ""))
    parser.add_argument("--out", default=RESULTS, metavar="DIR",
                        help="folder for the JSON (default bench/results); a path ending in .json names the file")


def json_path(out: str, name: str) -> str:
    """The JSON file of a bench named ``name`` (``name.json``) under ``out`` (a folder, made if missing), or ``out``
    itself when it ends in ``.json`` (its folder made)."""
    path = out if out.endswith(".json") else os.path.join(out, f"{name}.json")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    return path
