"""``blender -c scpainter <command> ...``: the add-on's headless commands for batch pipelines.

    blender -c scpainter import predictions.npz --camera-height 1.6 --save scene.blend
    blender -c scpainter import predictions.npz --extrinsic-convention camera_to_world --crop "0 77 0 77"
    blender -c scpainter import predictions.npz --depth-edge-ratio off
    blender -c scpainter render scene.blend [--camera NAME] [--output DIR] [--device cpu|cuda|auto]
    blender -c scpainter generate scene.blend --checkpoint /models/scpainter
    blender -c scpainter generate scene.blend [--inpaint telea|navier-stokes]    # no checkpoint: the baseline
    blender -c scpainter export scene.blend --format kitti|coco|openlabel [--out DIR]
    blender -c scpainter batch a.blend b.blend jobs/c.json [--list scenes.txt] --command generate [--shard 0/4]
    blender -c scpainter batch a.blend b.blend jobs/c.json --command generate --ray [HEAD:6379] [--retries 2]
    blender -c scpainter vary scene.blend --out variants/ [--variants 8]

One module per command in this package (its ``NAME``, ``ORDER`` in ``--help``'s list, ``add_parser`` and ``run``;
the command's own docstring says what it does), found here (``COMMANDS``): adding a command is adding its module.
What several commands share (options, opening a .blend, the backend's command line, the scene run of ``render``,
``generate`` and ``export``) is in ``common.py``.

``-c`` implies background mode; the import goes into the scene that is open (``blender -b scene.blend -c ...``
imports into scene.blend). With the ``bpy`` module (no ``-c``), call ``execute(argv)`` directly. Output: a JSON
summary on standard output; exit code 0 done, 2 bad input, 1 anything else (the backend's convention:
``core.backend_protocol``). Bad input is an ``InputError``, caught by name: a file, a scene setting, a command-line
argument (file "(command line)", field the option), or the backend's own exit 2 for the scene's job; its error
event has ``file`` and ``field``. Any other exception, a plain ValueError included, is a bug: exit 1, its traceback
on standard error.
"""

from __future__ import annotations

import importlib
import json
import pkgutil
import sys
import traceback
from collections.abc import Sequence
from types import ModuleType

import bpy

from ..runs import client
from ..core import backend_protocol as protocol
from ..core import errors
from ..scene import props
from . import common


def _commands() -> tuple[ModuleType, ...]:
    """The command modules of this package (each module with a ``NAME``), in ``ORDER``. Imported relative to this
    package: installed as an extension its name is ``bl_ext.<repo>.scpainter.scpainter_blender.cli``."""
    found = (importlib.import_module("." + m.name, __package__) for m in pkgutil.iter_modules(__path__))
    return tuple(sorted((m for m in found if hasattr(m, "NAME")), key=lambda m: m.ORDER))


# imported with this package (when the add-on is enabled): a broken command module fails there, not at its first use
COMMANDS = _commands()


def _parser() -> common.Parser:
    """The whole command line: one sub-command per command module, each with its handler as ``func``."""
    p = common.Parser(prog="blender -c scpainter", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return p


def execute(argv: Sequence[str]) -> int:
    """Run one command line (``argv`` without the ``scpainter``): its events on standard output, the last one the
    ``done`` summary or the ``error``; the exit code (0 done, 2 bad input, 1 anything else)."""
    if not props.registered():  # the bpy module with the add-on not enabled: the scene settings it reads
        props.register()
    try:
        args = _parser().parse_args(list(argv))
        summary, code = args.func(args)
    except SystemExit as e:  # --help: argparse printed it and exits, which would end Blender; return instead
        return e.code if isinstance(e.code, int) else protocol.EXIT_OK
    except errors.InputError as e:  # bad input, caught by name (never as a ValueError): exit 2
        print(json.dumps(protocol.error_event(str(e), e.hint, file=e.path, field=e.field)), flush=True)
        return protocol.EXIT_BAD_INPUT
    except client.BackendError as e:  # the backend refused the scene's job (its exit 2) or failed
        fields = {k: v for k, v in common.failure(e).items() if k != "error"}  # file, field (bad input); log
        print(json.dumps(protocol.error_event(str(e), **fields)), flush=True)
        return protocol.EXIT_BAD_INPUT if e.bad_input else protocol.EXIT_FAILED
    except Exception as e:  # a bug (a plain ValueError included) or a failure of Blender itself: exit 1
        traceback.print_exc(file=sys.stderr)
        print(json.dumps(protocol.error_event(f"{type(e).__name__}: {e}", "an internal error in SCPainter, not a "
                                              "problem with the input: the traceback is on standard error; please "
                                              "report it")), flush=True)
        return protocol.EXIT_FAILED
    print(json.dumps(protocol.event(protocol.DONE, command=args.command, **summary)), flush=True)
    return code


_handle: object | None = None


def register() -> None:
    """``blender -c scpainter`` registered (Blender ≥ 4.2 has ``register_cli_command``; the bpy module may not)."""
    global _handle
    if hasattr(bpy.utils, "register_cli_command"):
        _handle = bpy.utils.register_cli_command("scpainter", execute)


def unregister() -> None:
    """The command registered by ``register`` removed."""
    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None
