"""How the operators report a failure (docs/design.md §4.4, §14): bad input, caught by name as an
``InputError`` (a file, a scene setting, a preference), with its file, field and hint; a backend run that failed
(``BackendError``) with the backend's message and log; anything else is a bug of the add-on, reported with the
exception's type and its traceback printed to the system console (standard error)."""

from __future__ import annotations

import functools
import os
import sys
import traceback

from ..scpainter_blender.runs.client import BackendError
from ..scpainter_blender.core.errors import InputError


def describe(e: InputError) -> str:
    """``"<file name>: <field>: <message> (<hint>)"``, plus the full path when the file name alone is not it."""
    text = str(e) + (f" ({e.hint})" if e.hint and e.hint not in str(e) else "")
    if os.path.isabs(e.path) and e.path not in text:
        text += f" [{e.path}]"
    return text


def message(e: BaseException) -> str:
    """The report line for an exception an operator caught (see the module docstring); a bug's traceback is
    printed to standard error here."""
    if isinstance(e, InputError):
        return describe(e)
    if isinstance(e, BackendError):
        return str(e) + (f" [{e.file}]" if e.bad_input and e.file and e.file not in str(e) else "")
    traceback.print_exception(type(e), e, e.__traceback__, file=sys.stderr)
    return (f"{type(e).__name__}: {e} (an internal error in SCPainter, not a problem with the input: the "
            "traceback is in the system console; please report it)")


def _report(op, e: BaseException) -> set:
    op.report({"ERROR"}, message(e))
    return {"CANCELLED"}


def reported(method):
    """Decorates an operator's ``execute(self, context)``: an ``InputError`` (caught by name), a ``BackendError``
    or any other exception becomes an error report (``message``) and ``{"CANCELLED"}``. (Blender checks the
    argument count of an operator's functions: one wrapper per signature.)"""
    @functools.wraps(method)
    def execute(self, context):
        try:
            return method(self, context)
        except Exception as e:  # noqa: BLE001  bad input, a failed run or a bug: ``message`` tells them apart
            return _report(self, e)
    return execute


def reported_invoke(method):
    """``reported`` for ``invoke(self, context, event)``."""
    @functools.wraps(method)
    def invoke(self, context, event):
        try:
            return method(self, context, event)
        except Exception as e:  # noqa: BLE001
            return _report(self, e)
    return invoke
