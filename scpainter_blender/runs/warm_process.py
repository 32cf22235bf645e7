"""A warm backend: one ``python -m backend serve`` process that runs the add-on's commands one after another
(docs/design.md §12, "A warm backend"; its lines: ``core.backend_protocol``, ``SERVE``), so a second render pays no
interpreter start, torch import, kernel load or point loading.

``WarmBackend`` owns the process: ``submit(argv)`` sends a request and returns its ``WarmRun``, which a follower
uses as it uses a ``BackendJob`` (``client.BackendRun``: ``poll``, ``finished``, ``returncode``,
``cancel``, ``result``, ``wait``). One request at a time. Reader threads route the server's events to the request
in flight (the server's own ``compile`` progress at its start included: it delays that request) and its standard
error to the request's tail and ``log_path``. A server that died is the caller's to replace (``alive``; the
session's owner, ``warm_session``, starts a new one on its next use); the request in flight then fails
with a BackendError naming the server, its exit code and the end of its standard error. ``close()`` ends it: a quit
request, then SIGTERM, then SIGKILL, each after a bounded wait.

No bpy, no torch (Blender's Python runs it).
"""

from __future__ import annotations

import collections
import json
import signal
import subprocess
import threading

from ..core import backend_protocol as protocol
from .client import EXTENSION_ROOT, BackendRun, Invocation, backend_env, backend_python, parse_event


class WarmRun(BackendRun):
    """One request to a ``WarmBackend``: ``returncode`` is the ``served`` event's exit code (the server's own when
    it died during the request). ``cancel(grace)`` sends a cancel request (the command stops as on SIGTERM); a
    server that has not ended the request after ``grace`` seconds is ended itself."""

    def __init__(self, backend: WarmBackend, request_id: int, args: list, log_path: str | None):
        self.backend, self.id, self.args, self.log_path = backend, request_id, args, log_path
        self._init_events()
        self._stderr = collections.deque(maxlen=200)
        self._log = open(log_path, "a", encoding="utf-8") if log_path else None
        self._code: int | None = None
        self._served = self._stderr_done = False
        self._died: int | None = None          # the server's exit code, when it ended during the request
        self._ended = threading.Event()

    @property
    def server_pid(self) -> int:
        return self.backend.pid

    @property
    def returncode(self) -> int | None:
        return self._code if self._ended.is_set() else None

    @property
    def finished(self) -> bool:
        """The ``served`` event and the request's last stderr line arrived (or the server died)."""
        return self._ended.is_set()

    @property
    def stderr_tail(self) -> str:
        return "\n".join(self._stderr)

    def _ended_text(self, code) -> str:
        if self._died is None:
            return super()._ended_text(code)
        if isinstance(code, int) and code < 0:  # killed: its last log line (a frame's, say) is not the cause
            try:
                how = f"killed by {signal.Signals(-code).name}"
            except ValueError:
                how = f"killed by signal {-code}"
            return (f"the warm backend (pid {self.backend.pid}) was {how} during this run (the next run starts a "
                    "new one)")
        tail = self.stderr_tail.strip().splitlines()[-1:] or ["no output"]
        return (f"the warm backend (pid {self.backend.pid}) ended during this run, exit code {code}: {tail[0]} "
                "(the next run starts a new one)")

    # -- called by WarmBackend's reader threads -------------------------------------------------------------------

    def _stderr_line(self, line: str) -> None:
        if line.rstrip("\n") == protocol.served_marker(self.id):
            self._stderr_done = True
            self._end_if_complete()
            return
        self._stderr.append(line.rstrip("\n"))
        if self._log:
            self._log.write(line)
            self._log.flush()

    def _served_event(self, code: int) -> None:
        self._code, self._served = code, True
        self._end_if_complete()

    def _end_if_complete(self) -> None:
        if self._served and self._stderr_done:
            self._end()

    def _server_died(self, code: int) -> None:
        if not self._ended.is_set():
            self._died = self._code = code
            self._end()

    def _end(self) -> None:
        if self._log:
            self._log.close()
            self._log = None
        self._ended.set()

    # -- the follower's side --------------------------------------------------------------------------------------

    def cancel(self, grace: float = 10.0) -> None:
        """A cancel request; the server ended (``WarmBackend.close``) when the request has not ended after
        ``grace`` seconds."""
        self.cancelled = True
        if self._ended.is_set():
            return
        self.backend._send(protocol.cancel_request(self.id))
        if not self._ended.wait(grace):
            self.backend.close(grace=2.0)
            self._ended.wait(10.0)  # the stdout reader marks it when the pipe closes

    def _abandon(self) -> None:
        self.cancel()


class WarmBackend:
    """``python -m backend serve`` run by ``python`` (the ``backend_python`` rule), making ``device``'s kernels
    ready at its start and ending itself after ``idle_timeout`` seconds without a request (0: never). Its own
    session (``start_new_session``): Ctrl-C in Blender's terminal does not reach it; it ends when Blender does,
    since its standard input then ends. BackendError when the interpreter cannot run the backend."""

    def __init__(self, python: str = "", device: str | None = None, idle_timeout: float = 600.0):
        exe = backend_python(python)
        args = Invocation(protocol.SERVE, idle_timeout=idle_timeout, device=device or None).argv()
        self.python, self.device, self.idle_timeout = python, device, idle_timeout
        self.proc = subprocess.Popen([exe, "-m", "backend", *args], cwd=EXTENSION_ROOT, env=backend_env(),
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, start_new_session=True)
        self._lock = threading.Lock()
        self._run: WarmRun | None = None
        self._next_id = 1
        self._stderr = collections.deque(maxlen=200)   # everything it wrote, for a server that fails to start
        self._threads = [threading.Thread(target=self._read_stdout, daemon=True),
                         threading.Thread(target=self._read_stderr, daemon=True)]
        self._started = threading.Event()  # both readers started: a server that exits at once has its stdout
        for t in self._threads:            # reader reaping it before the stderr reader was started
            t.start()
        self._started.set()

    @property
    def pid(self) -> int:
        return self.proc.pid

    @property
    def alive(self) -> bool:
        """The process runs (it may still be making its kernels ready)."""
        return self.proc.poll() is None

    @property
    def busy(self) -> bool:
        """A request has been sent and has not ended."""
        return self._run is not None and not self._run.finished

    def submit(self, args, log_path: str | None = None) -> WarmRun:
        """Request ``python -m backend *args`` (``args[0]`` one of ``SERVED_COMMANDS``); its ``WarmRun``. A server
        that died fails the run at once (its exit code and stderr). RuntimeError while a request is in flight: the
        caller's bug (one run at a time)."""
        if self.busy:
            raise RuntimeError(f"the warm backend (pid {self.pid}) is running request {self._run.id}")
        with self._lock:
            run = WarmRun(self, self._next_id, [str(a) for a in args], log_path)
            self._next_id += 1
            self._run = run
            # what the server wrote since the last request (starting, idle) goes with this one: a server that
            # failed to start says why in the run's message
            run._stderr.extend(self._stderr)
            self._stderr.clear()
        if not self._send(protocol.request(run.id, run.args)) or not self.alive:
            self._reap()
        return run

    def _send(self, message: dict) -> bool:
        """One request line; False when the server's input is closed (it died)."""
        try:
            with self._lock:
                self.proc.stdin.write(json.dumps(message) + "\n")
                self.proc.stdin.flush()
            return True
        except (BrokenPipeError, ValueError, OSError):
            return False

    def _read_stdout(self) -> None:
        for line in self.proc.stdout:
            ev = parse_event(line)
            if ev is None:
                continue
            run = self._run
            if protocol.kind_of(ev) == protocol.SERVED:
                if run is not None and ev.get("id") == run.id:
                    run._served_event(ev.get("exit_code"))
            elif run is not None and not run.finished:
                run._events.put(ev)
        self._reap()

    def _read_stderr(self) -> None:
        for line in self.proc.stderr:
            with self._lock:  # (submit hands the lines kept here to its run under the same lock)
                run = self._run
                if run is not None and not run.finished:
                    run._stderr_line(line)
                else:
                    self._stderr.append(line.rstrip("\n"))

    def _reap(self) -> None:
        """The server's output has ended: it died or ended; the request in flight fails with its exit code."""
        try:
            code = self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:  # its stdout closed but it lives on: it is no use any more
            self.proc.kill()
            code = self.proc.wait()
        self._started.wait(timeout=5)
        for t in self._threads:
            if t is not threading.current_thread() and t.ident is not None:
                t.join(timeout=5)  # its last stderr lines, for the run's message
        if self._run is not None:
            self._run._server_died(code)

    def close(self, grace: float = 10.0) -> None:
        """End the server: a quit request (after the request in flight, which it stops first when input ends),
        then SIGTERM after ``grace`` seconds, SIGKILL after as many again. Returns when it has exited."""
        if self.proc.poll() is None:
            self._send(protocol.quit_request())
            try:
                self.proc.stdin.close()  # input's end: a request running stops as on SIGTERM
            except OSError:
                pass
            for stop in (None, self.proc.terminate, self.proc.kill):
                if stop is not None:
                    stop()
                try:
                    self.proc.wait(timeout=grace)
                    break
                except subprocess.TimeoutExpired:
                    continue
        self.proc.wait()
