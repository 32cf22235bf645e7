"""The one error type for bad input, ``InputError``, and its command-line form ``ArgumentError``.

Every reader's and validator's error derives from ``InputError``: ``python -m backend`` exits 2 for it (and only for
it) with an ``error`` event naming ``file`` and ``field``; ``blender -c scpainter`` and the operators catch it by
name. Failures a command explains that are not bad input are ``backend.errors.CleanFailure``; anything else is a
bug (docs/design.md §14).

stdlib only: the add-on and the backend share it.
"""

from __future__ import annotations

import difflib
import errno
import os
import re


class InputError(ValueError):
    """Bad input: ``path`` (the file), ``field`` (the key, property or header line; ``"(file)"`` for the file as
    a whole), ``message`` (what is wrong), ``hint`` (what to do, optional). ``str()`` is
    ``"<file name>: <field>: <message>"``.

    The one error type for bad input: ``python -m backend`` exits 2 for it (and only for it), the Blender command
    and the operators catch it by name. A plain ``ValueError`` is a bug of ours, never a user's mistake. Input
    that is not a file names its source in parentheses as ``path``: ``COMMAND_LINE`` with the option as field
    (``ArgumentError``), ``"(environment)"`` with the variable, ``"(add-on preferences)"`` with the preference;
    a scene setting names the .blend (``"(unsaved .blend)"``) and the datablock or property.

    It derives from ``ValueError`` only so that callers written before it still catch it; catch it by name."""

    def __init__(self, path, field, message, hint=None):
        self.path, self.field, self.message, self.hint = str(path), field or "(file)", message, hint
        super().__init__(f"{os.path.basename(self.path) or self.path}: {self.field}: {message}")

    def __reduce__(self):
        # pickle (a worker process's error sent back) rebuilds from the state, not by calling __init__ with args:
        # subclasses take other arguments than the one text their args hold
        return _rebuild_error, (self.__class__, self.args, self.__dict__)


def _rebuild_error(cls, args, state):
    e = cls.__new__(cls, *args)
    e.args = args
    e.__dict__.update(state)
    return e


#: The errnos of a full file system: no space left (ENOSPC) or the user's quota spent (EDQUOT). Not bad input: the
#: backend reports them as ``backend.errors.DiskFullError`` naming the folder; readers and folder makers let them
#: pass.
DISK_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)

#: The ``path`` of an InputError about a command-line argument.
COMMAND_LINE = "(command line)"


def did_you_mean(name: str, names) -> str:
    """``" (did you mean 'X'?)"`` for the one of ``names`` closest to ``name`` (letter case ignored:
    ``NUSCENES-32`` finds ``nuscenes-32``; ``difflib``'s ratio at least 0.6), else ``""``: the tail of a message
    refusing an unknown name, which stays refused (names are matched exactly)."""
    by_lower = {str(n).lower(): str(n) for n in names}
    close = difflib.get_close_matches(str(name).lower(), list(by_lower), n=1)
    return f" (did you mean {by_lower[close[0]]!r}?)" if close else ""


class ArgumentError(InputError):
    """A bad command-line argument (``--device cuda`` without a GPU, no job given): ``path`` is ``COMMAND_LINE``,
    ``field`` the option (``--device``) or a positional argument's name (``jobs``)."""

    def __init__(self, field, message, hint=None):
        super().__init__(COMMAND_LINE, field, message, hint)

    @classmethod
    def from_argparse(cls, message: str, prog: str) -> ArgumentError:
        """argparse's error message as an ArgumentError: the argument it names ("argument --device: invalid
        choice …") or the required ones it lists as ``field``, else "(arguments)"; the hint points at ``--help``."""
        named = re.match(r"argument ([^:]+): (.*)", message, re.S)
        required = re.match(r"the following arguments are required: (.*)", message, re.S)
        field = named.group(1) if named else required.group(1) if required else "(arguments)"
        return cls(field, named.group(2) if named else message, hint=f"see {prog} --help")
