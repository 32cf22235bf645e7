"""``backend/commands/``: every module with a ``NAME`` is a command, found without a list anywhere; ``--help`` lists
them in ``ORDER``; a module without ``NAME`` is not one; ``doctor`` parses with the standard library alone."""

import argparse
import importlib
import inspect
import os
import pkgutil
import subprocess
import sys

from backend import commands
from backend.__main__ import build_parser

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def _sub_parsers(parser: argparse.ArgumentParser) -> dict:
    """{command name: its parser}, in the order --help lists them."""
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return action.choices


def _package_modules() -> list:
    return [importlib.import_module(f"backend.commands.{m.name}") for m in pkgutil.iter_modules(commands.__path__)]


def test_every_module_with_a_name_is_registered_in_order_and_the_help_lists_them_so():
    named = [m for m in _package_modules() if hasattr(m, "NAME")]
    found = commands.command_modules()
    assert sorted(m.__name__ for m in found) == sorted(m.__name__ for m in named)
    orders = [m.ORDER for m in found]
    assert orders == sorted(orders) and len(set(orders)) == len(orders), orders
    names = [m.NAME for m in found]
    assert len(set(names)) == len(names), names
    parser = build_parser()
    assert list(_sub_parsers(parser)) == names
    assert "{" + ",".join(names) + "}" in parser.format_help()
    for m in found:  # each parser runs its own module's handler
        assert _sub_parsers(parser)[m.NAME].get_default("func") is m.run, m.__name__


def test_the_commands_of_the_old_parser_keep_their_order():
    """The commands and order --help listed before the commands had modules; a command added later may sit
    anywhere among them (this list is not a registry to extend)."""
    old = ["doctor", "render", "generate", "export", "batch", "init-checkpoint", "train", "evaluate", "mesh-asset",
           "splat-asset", "serve", "vary", "contact-sheet"]
    assert [name for name in _sub_parsers(build_parser()) if name in old] == old


def test_a_module_without_a_name_is_not_a_command_and_a_new_module_is_one(tmp_path, monkeypatch):
    """Adding a command is adding its module: a module with NAME in the package joins the parser at its ORDER; one
    without (``options.py``) does not."""
    assert not hasattr(importlib.import_module("backend.commands.options"), "NAME")
    before = list(_sub_parsers(build_parser()))
    assert before[:3] == ["doctor", "render", "generate"]
    (tmp_path / "zz_added.py").write_text(
        "import argparse\nNAME = 'added'\nORDER = 25\n"
        "def add_parser(sub):\n    p = sub.add_parser(NAME, help='a new command')\n"
        "    p.set_defaults(func=run)\n    return p\n"
        "def run(args):\n    return 0\n")
    (tmp_path / "zz_helper.py").write_text("HELP = 'shared by commands, not one'\n")
    monkeypatch.setattr(commands, "__path__", [*commands.__path__, str(tmp_path)])
    try:
        names = list(_sub_parsers(build_parser()))
    finally:
        sys.modules.pop("backend.commands.zz_added", None)
        sys.modules.pop("backend.commands.zz_helper", None)
    assert names == before[:2] + ["added"] + before[2:]  # ORDER 25: after render (20), before generate (30)


def test_served_commands_are_commands():
    from scpainter_blender.core.backend_protocol import SERVE, SERVED_COMMANDS

    names = [m.NAME for m in commands.command_modules()]
    assert set(SERVED_COMMANDS) <= set(names) and SERVE in names


def test_precision_choices_are_auto_and_the_dtypes_generate_knows():
    from backend.commands import options
    from backend.generate.command import PRECISIONS

    assert options.PRECISION_CHOICES == ("auto", *PRECISIONS)


def test_every_function_of_the_command_modules_is_annotated():
    for module in _package_modules():
        for name, fn in inspect.getmembers(module, inspect.isfunction):
            if fn.__module__ != module.__name__:
                continue
            sig = inspect.signature(fn)
            missing = [p for p in sig.parameters.values() if p.annotation is inspect.Parameter.empty]
            assert not missing and sig.return_annotation is not inspect.Signature.empty, f"{module.__name__}.{name}"


def test_doctor_parses_with_the_standard_library_alone():
    """``main`` parses ``doctor`` with ``commands/doctor.py`` alone: nothing beyond the standard library and the
    stdlib-only ``backend_protocol`` / ``user_cache`` is imported before the report runs."""
    code = ("import sys; from backend.__main__ import _doctor_parser; "
            "_doctor_parser().parse_args(['doctor', '--checkpoint', 'x']); "
            "print(' '.join(m for m in sys.modules if m.split('.')[0] in ('numpy', 'torch', 'cv2')))")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == ""
    loaded = subprocess.run([sys.executable, "-c", "import sys; from backend.commands import doctor; "
                             "print(sorted(m for m in sys.modules if m.startswith('backend.commands.')))"],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert loaded.stdout.strip() == "['backend.commands.doctor']", loaded  # not every command (they import numpy)


def test_the_export_help_names_every_export_format():
    """The export formats' one home is ``core.backend_protocol.EXPORT_FORMATS``: ``export``'s summary is made from
    its labels, and its ``--format`` help (which says what each writes) names every format, so a format added there
    without a word in the help fails here rather than going unexplained."""
    from backend.__main__ import build_parser
    from scpainter_blender.core.backend_protocol import EXPORT_FORMATS, export_format_labels

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    export = sub.choices["export"]
    assert export_format_labels() in next(a.help for a in sub._choices_actions if a.dest == "export")
    fmt = next(a for a in export._actions if a.dest == "format")
    assert tuple(fmt.choices) == tuple(EXPORT_FORMATS)
    unnamed = [n for n in EXPORT_FORMATS if n not in fmt.help]
    assert not unnamed, (f"export --format's help (backend/commands/export.py, written by hand: it says what each "
                         f"format writes) does not name {unnamed}: add a few words for each")
