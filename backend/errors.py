"""Failures that are not bad input but still end a command cleanly, with a message and no traceback.

``python -m backend`` turns each into an ``error`` event (message, hint, the fields below) and ``EXIT_FAILED``; bad
input (``scpainter_blender.core.errors.InputError`` and nothing else) is ``EXIT_BAD_INPUT``; any other exception (a
plain ``ValueError`` included) is a bug: ``EXIT_FAILED`` with its traceback (``events.report_bug``). The codes and
the event's fields: ``scpainter_blender.core.backend_protocol``.
"""

from __future__ import annotations


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
