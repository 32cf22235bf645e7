"""The backend's event stream (DESIGN §4.4): one JSON object per line on standard output.

Human-readable logs go to standard error (and to ``<output_dir>/backend.log`` for commands that have one);
standard output carries nothing but events, so a client can parse every line.
"""

from __future__ import annotations

import contextlib
import json
import math
import signal
import sys

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2


def _clean(value):
    """JSON has no NaN/inf: write them as null so every line parses with a strict parser."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def emit(event: str, stream=None, **fields) -> None:
    stream = stream or sys.stdout
    stream.write(json.dumps(_clean({"event": event, **fields}), allow_nan=False) + "\n")
    stream.flush()


def progress(stage: str, done: int, total: int, **fields) -> None:
    emit("progress", stage=stage, done=done, total=total, **fields)


def artifact(path: str, **fields) -> None:
    emit("artifact", path=path, **fields)


def done(**fields) -> None:
    emit("done", **fields)


def error(message: str, hint: str | None = None, **fields) -> None:
    emit("error", message=message, hint=hint, **fields)


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


class FileLog:
    """Human log lines to standard error and appended to a file (``<output_dir>/backend.log``)."""

    def __init__(self, path: str):
        from scpainter_blender.core import files

        self.path = path
        files.check_log(path)  # refused now, before the command writes anything, rather than at its first line

    def __call__(self, message: str) -> None:
        import time

        from scpainter_blender.core import files

        line = f"{time.strftime('%Y-%m-%d %H:%M:%S')} {message}"
        log(line)
        files.append_text(self.path, line + "\n")  # never through a planted symbolic link


@contextlib.contextmanager
def stop_on_sigterm():
    """Within the block SIGTERM does not kill the process: it appends to the yielded list, which long loops check
    between units of work (a frame, a sampler step) to stop cleanly with finished outputs kept."""
    stop: list = []
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    try:
        yield stop
    finally:
        signal.signal(signal.SIGTERM, previous)
