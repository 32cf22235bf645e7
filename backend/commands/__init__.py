"""The sub-commands of ``python -m backend``, one module each (docs/design.md §4.4).

A command module holds its options beside its handler: ``NAME`` (the sub-command on the command line), ``ORDER``
(its place in ``--help``'s list; steps of 10), ``add_parser(sub)`` (its parser, ``set_defaults(func=run)``) and
``run(args)`` (the handler: checks the arguments, calls the work's module, emits the events; the exit code). A
module without ``NAME`` is not a command (``options.py``: what several commands share). Adding a command is adding
its module: ``command_modules`` finds it.

Importing this package imports only the standard library, and a command module imports at most ``core`` (numpy)
at its top: the work's modules (torch, numba, ...) are imported by ``run``, so building the parser touches no GPU,
and ``doctor``'s module imports the standard library alone (``backend.__main__`` builds its parser from it when
numpy may be missing).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
from types import ModuleType


def command_modules() -> list[ModuleType]:
    """Every module of this package that has a ``NAME``, in ``ORDER``."""
    found = (importlib.import_module(f"{__name__}.{info.name}") for info in pkgutil.iter_modules(__path__))
    return sorted((m for m in found if hasattr(m, "NAME")), key=lambda m: m.ORDER)


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Every command's parser, in ``ORDER``, to ``sub`` (the top parser's sub-parsers)."""
    for module in command_modules():
        module.add_parser(sub)
