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

import json
import queue
import signal
import sys
import threading

from scpainter_blender.core import backend_protocol as protocol

from . import events

#: A line the reader thread hands to the main loop when standard input has ended.
_EOF = object()


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

    def read(self, stream) -> None:
        """The reader thread: cancel and quit act at once; requests queue for the main loop."""
        for line in stream:
            try:
                msg = json.loads(line)
            except json.JSONDecodeError:
                events.log(f"scpainter-serve: not a JSON line, ignored: {line.strip()[:200]!r}")
                continue
            if not isinstance(msg, dict):
                events.log(f"scpainter-serve: not a request object, ignored: {line.strip()[:200]!r}")
            elif protocol.REQUEST_CANCEL in msg:
                with self.lock:
                    if self.current is not None and self.current[0] == msg[protocol.REQUEST_CANCEL]:
                        self.current[1].append(True)
                    else:
                        self.cancelled.add(msg[protocol.REQUEST_CANCEL])
            elif msg.get(protocol.REQUEST_QUIT):
                self.ending = True
                self.lines.put(_EOF)
            else:
                self.lines.put(msg)
        self.ending = True  # Blender has gone: whatever runs stops, nothing else starts
        self.stop_current()
        self.lines.put(_EOF)

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
    threading.Thread(target=server.read, args=(sys.stdin,), daemon=True).start()
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
        server.run(msg)
    return events.EXIT_OK
