"""The backend's event stream (docs/design.md §4.4): one JSON object per line on standard output.

Human-readable logs go to standard error (and to ``<output_dir>/backend.log`` for commands that have one);
standard output carries nothing but events, so a client can parse every line.

Bugs (an exception that is neither bad input nor a failure the command explains): ``log_scope`` marks an
exception leaving it with the innermost ``FileLog`` open at that moment, and ``report_bug`` writes its whole
traceback to standard error and to that log, however deep in a command the log was opened.
"""

from __future__ import annotations

import contextlib
import json
import math
import signal
import sys
import traceback
from typing import TYPE_CHECKING

from scpainter_blender.core import backend_protocol as protocol
# the exit codes, here too: the commands return events.EXIT_* (their values: core/backend_protocol.py)
from scpainter_blender.core.backend_protocol import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK  # noqa: F401

if TYPE_CHECKING:
    from collections.abc import Iterator
    from typing import TextIO


def json_safe(value: object) -> object:
    """JSON has no NaN/inf: ``value`` with them as None (null), so every event line, and every result file written
    with ``core.outputs.write_json`` (which refuses NaN/inf), parses with a strict parser."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


#: Where events go once ``reserve_stdout`` ran (the process's real standard output); None: ``sys.stdout``.
_EVENT_STREAM = None


def reserve_stdout() -> None:
    """From now on, standard output carries only events: anything else printed to ``sys.stdout`` (a library's own
    messages: Ray's driver prints its workers' failures there, from a thread of its own) goes to standard error.
    For the rest of the process (such a thread may print after the command's work)."""
    global _EVENT_STREAM
    if _EVENT_STREAM is None:
        _EVENT_STREAM = sys.stdout
        sys.stdout = sys.stderr


def write(ev: dict, /, stream: TextIO | None = None) -> None:
    """One event (``core.backend_protocol``'s dict) as a line of standard output."""
    stream = stream or _EVENT_STREAM or sys.stdout
    stream.write(json.dumps(json_safe(ev), allow_nan=False) + "\n")
    stream.flush()


#: Fields every ``progress``, ``artifact`` and ``warning`` event carries while a ``tagged`` block runs.
_tags: dict = {}


@contextlib.contextmanager
def tagged(**fields: object) -> Iterator[None]:
    """Inside the block every ``progress``, ``artifact`` and ``warning`` event also carries ``fields`` (a rig job's
    camera: ``protocol.CAMERA_FIELD``), under the event's own fields of the same name."""
    global _tags
    before = _tags
    _tags = {**before, **fields}
    try:
        yield
    finally:
        _tags = before


def emit(kind: str, /, stream: TextIO | None = None, **fields: object) -> None:
    if _tags and kind in (protocol.PROGRESS, protocol.ARTIFACT, protocol.WARNING):
        fields = {**_tags, **fields}
    write(protocol.event(kind, **fields), stream)


def progress(stage: str, done: int, total: int, **fields: object) -> None:
    emit(protocol.PROGRESS, stage=stage, done=done, total=total, **fields)


def artifact(path: str, **fields: object) -> None:
    emit(protocol.ARTIFACT, path=path, **fields)


def done(**fields: object) -> None:
    emit(protocol.DONE, **fields)


def error(message: str, hint: str | None = None, **fields: object) -> None:
    write(protocol.error_event(message, hint, **fields))


def warning(message: str, code: str, **fields: object) -> None:
    """A ``warning`` event (``core.backend_protocol.WARNING_FIELDS``), also written to the human log: the command's
    open ``FileLog`` (``<output_dir>/backend.log``, where Blender's report tells the user to look) and stderr."""
    emit(protocol.WARNING, message=message, code=code, **fields)
    log(f"warning: {message}")
    if _open_logs:
        _open_logs[-1].record(f"warning: {message}")


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


#: The FileLogs opened in the ``log_scope`` blocks in progress, innermost (most recent) last.
_open_logs: list = []
#: The attribute ``log_scope`` sets on an exception leaving it: the FileLog that was open.
_LOG_ATTR = "scpainter_log"


class FileLog:
    """Human log lines to standard error and appended to a file (``<output_dir>/backend.log``).

    Opening one makes it the log a bug's traceback goes to (``report_bug``) until the enclosing ``log_scope``
    ends."""

    def __init__(self, path: str) -> None:
        from scpainter_blender.core import outputs

        self.path = path
        outputs.check_log(path)  # refused now, before the command writes anything, rather than at its first line
        _open_logs.append(self)

    def __call__(self, message: str) -> None:
        log(self.record(message))

    def record(self, message: str) -> str:
        """``message`` appended to the file only, as a timestamped line; that line."""
        import time

        line = f"{time.strftime('%Y-%m-%d %H:%M:%S')} {message}"
        self.append(line + "\n")
        return line

    def append(self, text: str) -> None:
        """``text`` appended to the file only (not standard error)."""
        from scpainter_blender.core import outputs

        try:
            outputs.append_text(self.path, text)  # never through a planted symbolic link
        except OSError as e:
            if e.filename is None:  # a write's error (a full disk) names no file: the log's
                e.filename = self.path
            raise


@contextlib.contextmanager
def log_scope() -> Iterator[None]:
    """The FileLogs opened inside the block belong to it: an exception leaving the block while one is open is
    marked with the innermost (``log_of``), and they stop being the bug log when the block ends. ``main`` wraps
    each command in one, ``batch`` each job, ``render_job`` / ``generate_job`` their run."""
    mark = len(_open_logs)
    try:
        yield
    except BaseException as e:
        if len(_open_logs) > mark and log_of(e) is None:
            with contextlib.suppress(AttributeError, TypeError):  # an exception type that takes no attributes
                setattr(e, _LOG_ATTR, _open_logs[-1])
        raise
    finally:
        del _open_logs[mark:]


def log_of(e: BaseException) -> FileLog | None:
    """The FileLog that was open where ``e`` was raised (see ``log_scope``), or None."""
    log_ = getattr(e, _LOG_ATTR, None)
    return log_ if isinstance(log_, FileLog) else None


def report_bug(e: BaseException, what: str = "") -> str | None:
    """A bug (an exception that is not bad input): its whole traceback to standard error and, when a ``FileLog``
    was open where it was raised, appended to that file too. Returns that file's path (for the ``error`` event's
    ``log`` field), None when the traceback went to standard error only."""
    import time

    text = "".join(traceback.format_exception(type(e), e, e.__traceback__))
    head = f"{time.strftime('%Y-%m-%d %H:%M:%S')} {what or 'internal error'} (a bug in SCPainter, not bad input):"
    log(f"{head}\n{text.rstrip()}")
    log_ = log_of(e)
    if log_ is None:
        return None
    try:
        log_.append(f"{head}\n{text}")
    except (OSError, ValueError) as failed:  # the log became unwritable (disk full, replaced by a link): say so
        log(f"(the traceback could not be appended to {log_.path}: {failed})")
        return None
    return log_.path


def log_here(message: str) -> None:
    """A line for the log of the command running: its innermost open ``FileLog`` (``<output_dir>/backend.log``),
    else standard error only. For code below the command that has no log handed to it (the warm backend's caches)."""
    if _open_logs:
        _open_logs[-1](message)
    else:
        log(message)


#: The stop list of the request a warm backend (``backend/serve.py``) is running, None outside one.
_request_stop: list | None = None


@contextlib.contextmanager
def serving(stop: list) -> Iterator[list]:
    """The block runs one request of a warm backend: ``stop_on_sigterm`` yields ``stop`` (which the server's cancel
    request and its own SIGTERM handler append to) and leaves the signal handlers alone (the server's stay)."""
    global _request_stop
    _request_stop = stop
    try:
        yield stop
    finally:
        _request_stop = None


@contextlib.contextmanager
def stop_on_sigterm(sigint: bool = False) -> Iterator[list]:
    """Within the block SIGTERM does not kill the process: it appends to the yielded list, which long loops check
    between units of work (a frame, a sampler step) to stop cleanly with finished outputs kept. ``sigint``: the
    first Ctrl-C (SIGINT) does the same, a second one raises KeyboardInterrupt (the impatient user's way out).
    Inside a warm backend's request (``serving``) the request's stop list, which a cancel request or SIGTERM to the
    server fills; the server's handlers stay in place."""
    if _request_stop is not None:
        yield _request_stop
        return
    stop: list = []

    def on_sigint(*_):
        if stop:
            raise KeyboardInterrupt
        stop.append(True)

    previous = signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    previous_int = signal.signal(signal.SIGINT, on_sigint) if sigint else None
    try:
        yield stop
    finally:
        signal.signal(signal.SIGTERM, previous)
        if sigint:
            signal.signal(signal.SIGINT, previous_int)
