"""The Blender session's warm backend (docs/design.md §12, "A warm backend"): one ``warm_process.WarmBackend``,
started by the first run that wants it, reused by the next ones, so a second *Render Conditions* starts its first
frame within a second of the click.

It is keyed by what it was started with: the Backend Python (resolved: ``client.backend_python``), the
device, the idle time (the preference *Keep Backend*) and the environment Blender hands it. A run whose key differs
(a preference changed) ends it and starts another; so does a server that died or ended itself after its idle
time. The preferences' update callbacks end it at once (``end``), as do ``unregister()`` and the interpreter's exit
(``atexit``); a Blender that dies closes the server's standard input, which ends it too. Nothing is left behind.

``launch(run, keep)`` is how ``camera_run.start`` starts a run: a request to the warm backend for
``SERVED_COMMANDS`` when *Keep Backend* (``keep``, read from the preferences by the caller) is above 0, a one-shot
``BackendJob`` otherwise and inside ``one_shot()`` (what ``blender -c scpainter`` uses: a process that runs one
command and ends has nothing to keep warm). *Check Backend* (``doctor``)
is always one-shot: it reports on a new process of the interpreter the preferences name.
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import os

from ..core import backend_protocol as protocol
from .client import BackendRun, Invocation, backend_env, backend_python
from .warm_process import WarmBackend

#: The session's warm backend and the key it was started with (``_key``); None when there is none.
_SESSION: dict = {"backend": None, "key": None}
#: How many ``one_shot`` blocks are open.
_ONE_SHOT = [0]
#: ``end`` registered with atexit (once per session).
_AT_EXIT = [False]


def _key(python: str, device: str | None, idle_timeout: float) -> tuple:
    """What a warm backend depends on: the interpreter it runs, the device whose kernels it made ready, its idle
    time, and the environment it got (a hash: any variable changed since, e.g. ``CUDA_VISIBLE_DEVICES``, but those
    the backend sets itself, ``protocol.BACKEND_SETS_ENV``)."""
    # the variables python -m backend sets for itself when missing are left out: this Blender has them too once
    # anything in it imported ``backend`` (reading an EXR with backend.render.channels), which changes nothing
    kept = {k: v for k, v in backend_env().items() if k not in protocol.BACKEND_SETS_ENV}
    env = hashlib.sha256(repr(sorted(kept.items())).encode()).hexdigest()
    return (os.path.realpath(backend_python(python)), device, float(idle_timeout), env)


def backend(python: str, device: str | None, idle_timeout: float) -> WarmBackend:
    """The session's warm backend for this key: the running one, or a new one (the old one ended first).
    BackendError when the interpreter cannot run the backend."""
    key = _key(python, device, idle_timeout)
    warm = _SESSION["backend"]
    if warm is not None and (_SESSION["key"] != key or not warm.alive):
        end()
        warm = None
    if warm is None:
        if not _AT_EXIT[0]:
            atexit.register(end)
            _AT_EXIT[0] = True
        warm = WarmBackend(python, device, idle_timeout)
        _SESSION.update(backend=warm, key=key)
    return warm


def current() -> WarmBackend | None:
    """The session's warm backend when one runs (for the tests and the preferences' display)."""
    warm = _SESSION["backend"]
    return warm if warm is not None and warm.alive else None


def end() -> None:
    """End the session's warm backend (a request running stops as on Esc; bounded waits, then SIGKILL)."""
    warm = _SESSION["backend"]
    _SESSION.update(backend=None, key=None)
    if warm is not None:
        warm.close(grace=10.0)


@contextlib.contextmanager
def one_shot():
    """Within the block ``launch`` starts one-shot processes whatever the preferences say."""
    _ONE_SHOT[0] += 1
    try:
        yield
    finally:
        _ONE_SHOT[0] -= 1


def launch(run: Invocation, keep: float) -> BackendRun:
    """Start ``run`` (its jobs set): a request to the session's warm backend when the preferences keep one (``keep``:
    *Keep Backend*, seconds, > 0) and the command is one a warm backend runs, else its own process. BackendError
    when the interpreter cannot run the backend."""
    if keep <= 0 or _ONE_SHOT[0] or run.command not in protocol.SERVED_COMMANDS:
        return run.start()
    return backend(run.python, run.device, keep).submit(run.argv())
