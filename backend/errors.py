"""Failures that are not bad input but still end a command cleanly, with a message and no traceback.

``python -m backend`` turns each into an ``error`` event (message, hint, the fields below) and ``EXIT_FAILED``; bad
input (``scpainter_blender.core.errors.InputError`` and nothing else) is ``EXIT_BAD_INPUT``; any other exception (a
plain ``ValueError`` included) is a bug: ``EXIT_FAILED`` with its traceback (``events.report_bug``). The codes and
the event's fields: ``scpainter_blender.core.backend_protocol``.
"""

from __future__ import annotations

import errno
import os

from scpainter_blender.core.errors import DISK_FULL_ERRNOS  # (stdlib only, as this module)


class CleanFailure(RuntimeError):
    """A failure the command explains itself: ``hint`` says what to do, ``fields`` go into the error event."""

    def __init__(self, message: str, hint: str | None = None, **fields):
        self.hint, self.fields = hint, fields
        super().__init__(message)


class NonFiniteError(CleanFailure):
    """A model produced NaN or infinity (sampler latents, decoded frames, a training loss): nothing is written
    from it. ``fields`` name where (``stage``, ``step``, ``sigma``, ``batch``)."""


class FolderBusyError(CleanFailure):
    """Another live process holds the output folder's lock (see ``core.locking.OutputLock``)."""




class DiskFullError(CleanFailure):
    """A write failed because the file system holding ``folder`` is full or the user's quota is spent: nothing
    half-written is left (``core.outputs`` removes its temporaries); ``fields``: ``folder``."""


def explained(e: BaseException) -> Exception | None:
    """What an ``OSError`` the commands do not catch themselves stands for, or None (a bug): a name too long for
    the file system (ENAMETOOLONG) is bad input, an ``InputError`` naming the path; a full file system (ENOSPC,
    EDQUOT) a ``DiskFullError`` naming the folder. ``python -m backend``, ``batch`` and the Ray workers ask this
    before calling an exception a bug."""
    if not isinstance(e, OSError) or e.errno not in DISK_FULL_ERRNOS + (errno.ENAMETOOLONG,):
        return None
    name = e.filename2 if isinstance(e.filename2, (str, bytes)) else e.filename  # a rename's: its target
    path = os.fsdecode(name) if isinstance(name, (str, bytes)) else None
    if e.errno == errno.ENAMETOOLONG:
        from scpainter_blender.core.errors import InputError

        return InputError(path or "(file name)", "(file)", "its name is too long for the file system (at most 255 "
                                                           "bytes a name, 4,096 a path)",
                          hint="choose a shorter name or a folder nearer the root")
    folder = os.path.dirname(os.path.abspath(path)) if path else None
    what = "no space is left on the device" if e.errno == errno.ENOSPC else "the disk quota is spent"
    return DiskFullError(f"{what} writing into {folder or 'the output folder'}: nothing half-written was kept",
                         hint="free space there (or choose an output folder on another disk), then run the same "
                              "command again: finished outputs are kept", folder=folder)
