"""``python -m backend <command>``: the backend's command line (docs/design.md §4.4): the entry point (``main``), the
top parser (``build_parser``) and the dispatch. Each command's options and handler live in its own module of
``backend/commands/`` (found there by ``commands.command_modules``; shared options: ``commands/options.py``).

Exit codes: 0 done; 2 bad input: an ``InputError`` (the error event has ``file`` and ``field``; a command-line
argument is file "(command line)" with the option as field, argparse's own errors included); 1 anything else: a
failure the command explains (``errors.CleanFailure``: a busy output folder, a model producing NaN; no
traceback), or a bug (any other exception, a plain ValueError included): its traceback on standard error and in the
command's log (``<output_dir>/backend.log``), whose path the error event's ``log`` field gives; 130 interrupted by
Ctrl-C (an error event). Standard output carries JSON events only. The codes, device names and event kinds:
``scpainter_blender.core.backend_protocol``; the add-on writes this command line with
``scpainter_blender.runs.client.Invocation`` (a test parses its ``argv()`` with ``build_parser``).
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import NoReturn

from . import events


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        """argparse's usage and message on standard error, as always, and the error event a pipeline reads on
        standard output (file "(command line)", field the argument: ``ArgumentError.from_argparse``); exit 2."""
        from scpainter_blender.core.errors import ArgumentError

        e = ArgumentError.from_argparse(message, self.prog)
        self.print_usage(sys.stderr)
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        events.error(str(e), hint=e.hint, file=e.path, field=e.field)
        sys.exit(events.EXIT_BAD_INPUT)


#: The command pyproject.toml installs (``[project.scripts]``): the same ``main`` as ``python -m backend``.
CONSOLE_COMMAND = "scpainter-backend"


def _doctor_parser() -> argparse.ArgumentParser:
    """A parser of ``doctor`` alone, built from the standard library (``commands/doctor.py`` and this package's
    ``__init__`` import nothing else): what ``main`` uses for it."""
    from .commands import doctor

    p = _Parser(prog="python -m backend")
    doctor.add_parser(p.add_subparsers(dest="command", required=True))
    return p


def build_parser() -> argparse.ArgumentParser:
    """The whole command line: every command module's parser, in their ``ORDER`` (numpy only: no torch or CUDA at
    start-up)."""
    from . import commands

    # the console command (pyproject.toml) names itself in usage and hints; `python -m backend` otherwise
    command = os.path.basename(sys.argv[0]) if sys.argv else ""
    p = _Parser(prog=CONSOLE_COMMAND if command == CONSOLE_COMMAND else "python -m backend", description=(
        "SCPainter's backend: render a job's condition layers, generate its video (the SCPainter model, or the "
        "inpainting baseline without a checkpoint), run many jobs, train and evaluate. Standard output carries one "
        f"JSON event per line; exit codes: {events.EXIT_OK} done, {events.EXIT_FAILED} failed, "
        f"{events.EXIT_BAD_INPUT} bad input, {events.EXIT_INTERRUPTED} interrupted."))
    commands.add_parsers(p.add_subparsers(dest="command", required=True))
    return p


def main(argv: list[str] | None = None) -> int:
    """``python -m backend <argv>`` (default: this process's arguments); the exit code (module docstring)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    # doctor first imports nothing but the standard library: it reports what this Python lacks instead of failing
    # on it; every other command needs numpy to parse its arguments, and says what to install when it is missing
    try:  # argparse errors: usage on standard error, an error event, exit 2
        parser = _doctor_parser() if argv[:1] == ["doctor"] else build_parser()
        args = parser.parse_args(argv)
    except ModuleNotFoundError as e:
        from scpainter_blender.core.backend_protocol import install_hint

        events.error(f"this Python ({sys.executable}) lacks the package {e.name!r} the backend needs",
                     hint=install_hint(sys.executable), file="(environment)", field=e.name)
        return events.EXIT_BAD_INPUT
    from scpainter_blender.core.errors import InputError  # (stdlib only, as is CleanFailure's module)

    from .errors import CleanFailure, explained

    try:
        if argv[:1] != ["doctor"]:  # (doctor imports the standard library alone)
            from .commands.options import check_names

            check_names(parser, args)
        with events.log_scope():  # a bug's traceback goes to the log the command had open (backend.log)
            try:
                return args.func(args)
            except OSError as e:  # a name too long (bad input) or a full disk (explained): not a bug
                known = explained(e)
                if known is None:
                    raise
                raise known from e
    except InputError as e:  # bad input, and only that: the message names the file and field
        events.error(str(e), hint=e.hint or "check the input file and arguments", file=e.path, field=e.field)
        return events.EXIT_BAD_INPUT
    except CleanFailure as e:  # explained by the command itself: no traceback
        events.error(str(e), hint=e.hint, **e.fields)
        return events.EXIT_FAILED
    except KeyboardInterrupt:  # Ctrl-C (for batch and evaluate --ray the second one: the first stops)
        events.error("interrupted (Ctrl-C)", hint="finished frames and checkpoints are kept (each written whole); run "
                                                  "the same command again to resume")
        return events.EXIT_INTERRUPTED
    except Exception as e:  # a bug (a plain ValueError included): the whole traceback, never "bad input"
        log = events.report_bug(e, f"{args.command} failed")
        where = f"{log} and standard error" if log else "standard error"
        events.error(f"{type(e).__name__}: {e}", hint=f"an internal error in SCPainter, not a problem with the "
                                                      f"input: the traceback is in {where}; please report it",
                     log=log)
        return events.EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
