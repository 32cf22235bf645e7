"""``python -m backend serve``: a warm backend, one long-lived process that runs requests one after another
(docs/design.md §12, "A warm backend"; the lines: ``core.backend_protocol``, ``SERVE``).

The add-on starts one per Blender session, so a second *Render Conditions* pays no interpreter start, torch import,
kernel load or point loading. Standard input carries request lines; each request runs in this process exactly as
``python -m backend <argv>`` would (``__main__.main``: the same parser, events, exit codes and per-command logs),
then a ``served`` event names it and its exit code. One request at a time, in the main thread; a reader thread
takes the lines, so ``{"cancel": id}`` reaches a request while it runs: it fills the stop list the command's
``events.stop_on_sigterm`` yields (``events.serving``), as SIGTERM does for a one-shot command.

It ends on standard input's end (Blender quit or died: the request running is stopped first), on ``{"quit": true}``
(after the request running), after ``--idle-timeout`` seconds without a request, and on SIGTERM or SIGINT (the
request running stops as a one-shot command stops on SIGTERM, then the server ends). A bug inside a request is
reported as ever (error event, traceback in the command's log) and the server goes on.

At its start it loads (or compiles) the renderer's kernels for ``--device`` (``render.warmup``, a ``compile``
progress event) and keeps loaded points and assets between requests (``render.scene_cache``).
"""

from __future__ import annotations

import functools
import os
import queue
import signal
import sys
import threading

from typing import TYPE_CHECKING

from scpainter_blender.core import backend_protocol as protocol
from scpainter_blender.core import fields, files
from scpainter_blender.core.errors import InputError

from . import events

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

#: A line the reader thread hands to the main loop when standard input has ended.
_EOF = object()


def request_lines(read: Callable[[], bytes], limit: int = protocol.MAX_REQUEST_BYTES) -> Iterator[bytes | None]:
    """The lines (bytes, newline kept) of what ``read()`` returns piece by piece (b"": the end); None for a line
    longer than ``limit`` bytes, whose rest is read past and never held. ``read`` is ``os.read`` on standard
    input's descriptor: a buffered reader's lock, held by this daemon thread while it waits, would abort the
    interpreter's shutdown."""
    pending, skipping = bytearray(), False
    while True:
        chunk = read()
        if not chunk:
            break
        pending += chunk
        while True:
            end = pending.find(b"\n")
            if end < 0:
                if len(pending) > limit:
                    if not skipping:
                        yield None
                    pending.clear()
                    skipping = True
                break
            line = bytes(pending[:end + 1])
            del pending[:end + 1]
            if skipping:
                skipping = False
            elif len(line) > limit:
                yield None
            else:
                yield line
    if pending and not skipping:
        yield bytes(pending)


def _refuse(field: str, message: str, hint: str | None = None) -> InputError:
    return InputError(protocol.REQUEST_SOURCE, field, message, hint=hint)


#: What the lines may be (the hint of every refusal).
_SHAPES = ('one JSON object per line: {"id": N, "argv": ["render", ...]}, {"cancel": N} or {"quit": true} '
           "(core/backend_protocol.py)")


def parse_request(line: bytes | None) -> dict:
    """A request line (``request_lines``) as one of the three requests of ``core.backend_protocol`` (request,
    cancel, quit), checked field by field; ``InputError`` (path ``REQUEST_SOURCE``) naming the field otherwise: a
    line too long, not UTF-8, not JSON or beyond ``core.files``' nesting and number bounds; not an object; an
    unknown or missing key; an ``id`` or cancelled id that is not an integer (int64); an ``argv`` that is not a
    non-empty list of strings (at most ``fields.MAX_STRING`` characters, no NUL)."""
    if line is None:
        raise _refuse("(line)", f"is longer than {protocol.MAX_REQUEST_BYTES:,} bytes", hint=_SHAPES)

    def error(path, field, message):
        return _refuse("(line)" if field == "(file)" else field, message, hint=_SHAPES)

    msg = files.parse_json(line, protocol.REQUEST_SOURCE, error, max_bytes=protocol.MAX_REQUEST_BYTES)
    if not isinstance(msg, dict):
        raise error(None, "(top level)", f"expected a request object, got {fields.short(msg)}")
    for shape in ((protocol.REQUEST_ID, protocol.REQUEST_ARGV), (protocol.REQUEST_CANCEL,), (protocol.REQUEST_QUIT,)):
        if shape[0] in msg:
            break
    else:
        raise error(None, "(top level)", f"is none of the requests: it has no {protocol.REQUEST_ID!r}, "
                                         f"{protocol.REQUEST_CANCEL!r} or {protocol.REQUEST_QUIT!r}")
    unknown = [k for k in msg if k not in shape]
    if unknown or len(msg) != len(shape):
        field = unknown[0] if unknown else next(k for k in shape if k not in msg)
        raise error(None, field, "is not a field of this request" if unknown else "is missing")
    if protocol.REQUEST_QUIT in msg:
        if msg[protocol.REQUEST_QUIT] is not True:
            raise error(None, protocol.REQUEST_QUIT, f"expected true, got {fields.short(msg[protocol.REQUEST_QUIT])}")
        return msg
    key = protocol.REQUEST_CANCEL if protocol.REQUEST_CANCEL in msg else protocol.REQUEST_ID
    fields.integer(msg[key], protocol.REQUEST_SOURCE, key, error=error)
    if key == protocol.REQUEST_ID:
        argv = msg[protocol.REQUEST_ARGV]
        if not isinstance(argv, list) or not argv:
            raise error(None, protocol.REQUEST_ARGV, f"expected a non-empty list of strings, got {fields.short(argv)}")
        for i, a in enumerate(argv):
            if not isinstance(a, str) or len(a) > fields.MAX_STRING or "\0" in a:
                raise error(None, f"{protocol.REQUEST_ARGV}[{i}]", f"expected a string of at most "
                                                                    f"{fields.MAX_STRING} characters without NUL, "
                                                                    f"got {fields.short(a)}")
    return msg


def _readable_id(line: bytes | None) -> int | None:
    """The ``id`` of a malformed request, where it can be read (a JSON object with an integer id), else None."""
    try:
        msg = files.parse_json(line, protocol.REQUEST_SOURCE, max_bytes=protocol.MAX_REQUEST_BYTES)
        rid = msg.get(protocol.REQUEST_ID) if isinstance(msg, dict) else None
        return fields.integer(rid, protocol.REQUEST_SOURCE, protocol.REQUEST_ID)
    except (InputError, TypeError):
        return None


class _Malformed:
    """A malformed line, answered by the main loop in its turn: an error event naming the problem (and the
    request's ``id`` where it could be read, then its ``served`` event with exit code 2)."""

    def __init__(self, error: InputError, rid: int | None):
        self.error, self.id = error, rid

    def answer(self) -> None:
        e = self.error
        events.log(f"scpainter-serve: malformed request refused: {e}")
        events.error(str(e), hint=e.hint, file=e.path, field=e.field, id=self.id)
        if self.id is not None:
            events.log(protocol.served_marker(self.id))
            events.emit(protocol.SERVED, id=self.id, exit_code=events.EXIT_BAD_INPUT)


class _Server:
    def __init__(self):
        self.lines: queue.Queue = queue.Queue()
        self.lock = threading.Lock()
        self.current: tuple[int, list] | None = None   # (id, stop list) of the request running
        self.cancelled: set = set()                     # ids cancelled before they started
        self.ending = False                             # quit, end of input or a signal: no request after this one

    def stop_current(self) -> None:
        with self.lock:
            if self.current is not None:
                self.current[1].append(True)

    def on_signal(self, *_) -> None:
        """SIGTERM / SIGINT: stop the request running, run no other, end."""
        self.ending = True
        self.stop_current()
        self.lines.put(_EOF)  # wakes the main loop when it waits for a request

    def read(self, read: Callable[[], bytes]) -> None:
        """The reader thread (``read``: standard input's next bytes, ``request_lines``): cancel and quit act at once; requests, and the
        answers to malformed lines, queue for the main loop (the one writer of events). Whatever a line holds, the
        thread reads on, up to a quit request (the last line it reads); when it ends (a quit, input closed, or a bug
        here) the server ends too, answering what is queued."""
        quitting = False
        try:
            for line in request_lines(read):
                try:
                    msg = parse_request(line)
                except InputError as e:
                    self.lines.put(_Malformed(e, _readable_id(line)))
                    continue
                if protocol.REQUEST_CANCEL in msg:
                    with self.lock:
                        if self.current is not None and self.current[0] == msg[protocol.REQUEST_CANCEL]:
                            self.current[1].append(True)
                        else:
                            self.cancelled.add(msg[protocol.REQUEST_CANCEL])
                elif protocol.REQUEST_QUIT in msg:   # the last line read: the request running finishes, the
                    quitting = True                    # ones queued before it are answered (``serve``), then it ends
                    break
                else:
                    self.lines.put(msg)
        except Exception as e:  # a bug of the reader: the server cannot hear requests any more, so it ends
            events.report_bug(e, "reading requests")
        finally:
            self.ending = True
            if not quitting:  # input closed (Blender has gone) or a bug here: whatever runs stops, nothing starts
                self.stop_current()
            self.lines.put(_EOF)

    def answer(self, msg) -> None:
        """One queued line: a malformed one's answer, a request's run (the end marker: nothing)."""
        if isinstance(msg, _Malformed):
            msg.answer()
        elif msg is not _EOF:
            self.run(msg)

    def run(self, msg: dict) -> None:
        """One request: its command's events, then the ``served`` event (after the stderr marker)."""
        rid = msg.get(protocol.REQUEST_ID)
        argv = msg.get(protocol.REQUEST_ARGV)
        with self.lock:
            cancelled = rid in self.cancelled
            self.cancelled.discard(rid)
            stop: list = [True] if cancelled or self.ending else []
            self.current = (rid, stop)
        try:
            if stop:
                events.error("cancelled before it started", hint="nothing was done: run it again")
                code = events.EXIT_FAILED
            else:
                code = run_request(argv, stop)
        finally:
            with self.lock:
                self.current = None
        events.log(protocol.served_marker(rid))
        events.emit(protocol.SERVED, id=rid, exit_code=code)


def run_request(argv, stop: list) -> int:
    """``python -m backend <argv>`` in this process with ``stop`` as its stop list; its exit code. Only
    ``SERVED_COMMANDS`` (others change the whole process: Ray, torchrun, a server inside the server)."""
    from scpainter_blender.core.errors import ArgumentError

    from .__main__ import main

    if not isinstance(argv, list) or not argv or argv[0] not in protocol.SERVED_COMMANDS:
        command = argv[0] if isinstance(argv, list) and argv else None
        e = ArgumentError("command", f"{command!r} is not run by a warm backend",
                          hint=f"it runs {', '.join(protocol.SERVED_COMMANDS)}; run anything else as "
                               "`python -m backend ...`")
        events.error(str(e), hint=e.hint, file=e.path, field=e.field)
        return events.EXIT_BAD_INPUT
    with events.serving(stop):
        try:
            return main([str(a) for a in argv])
        except SystemExit as e:  # argparse's errors and --help exit; the server does not
            return e.code if isinstance(e.code, int) else (events.EXIT_OK if e.code is None else events.EXIT_FAILED)
        except Exception as e:  # a bug main() let through: reported like one, the server goes on
            log = events.report_bug(e, f"{argv[0]} failed")
            events.error(f"{type(e).__name__}: {e}", hint="an internal error in SCPainter's warm backend, not a "
                                                          "problem with the input; please report it", log=log)
            return events.EXIT_FAILED


def serve(idle_timeout: float, device: str) -> int:
    """Run requests from standard input until it ends, a quit request, ``idle_timeout`` seconds (0: never) without
    one, or SIGTERM / SIGINT; ``device``: whose kernels to make ready first. Exit code 0."""
    from .render import scene_cache, warmup

    events.reserve_stdout()  # standard output: events only, whatever a library prints
    server = _Server()
    # set explicitly: a parent that ignores SIGINT (a shell's background job) would otherwise hand that down, and
    # Ctrl-C in Blender's terminal must stop a request cleanly, as SIGTERM does
    signal.signal(signal.SIGTERM, server.on_signal)
    signal.signal(signal.SIGINT, server.on_signal)
    read = functools.partial(os.read, sys.stdin.fileno(), 1 << 16)
    threading.Thread(target=server.read, args=(read,), daemon=True).start()
    scene_cache.enable()
    try:  # its events go to the first request's client (it waits for this process anyway)
        warmup.announce_and_warm(device, warmup.kernels_cached() if device == "cpu" else None)
    except Exception as e:  # a first frame would compile them anyway; a request then reports what fails
        events.report_bug(e, "warming the renderer's kernels")
    events.log(f"scpainter-serve: ready (idle timeout {idle_timeout:g} s)")
    while not server.ending:
        try:
            msg = server.lines.get(timeout=idle_timeout or None)
        except queue.Empty:
            events.log(f"scpainter-serve: no request for {idle_timeout:g} s: ending")
            break
        if msg is _EOF:
            continue  # the loop's test says whether to end
        server.answer(msg)
    # what came before the end (or after a quit) is answered, never dropped: a malformed line's error, a request's
    # "cancelled before it started" (``run``: the server is ending)
    while True:
        try:
            server.answer(server.lines.get_nowait())
        except queue.Empty:
            break
    return events.EXIT_OK
