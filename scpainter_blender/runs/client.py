"""Start the backend (``python -m backend ...``) in a subprocess and read its event stream (docs/design.md,
"Running the backend from Blender").

``Invocation`` is the one place the add-on spells the backend's command line: the operators build it from the
preferences, ``blender -c scpainter`` from its arguments; ``argv()`` turns it into arguments, ``start()`` into a
``BackendJob``. ``BackendRun`` is what a follower sees of a run, one-shot (``BackendJob``) or sent to a warm
backend (``warm_process``). Device names, exit codes and event kinds: ``core.backend_protocol``.

No bpy, no torch: the add-on calls this from Blender's Python, where neither torch nor open3d exist; the
backend runs under the interpreter chosen in the add-on preferences.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

from ..core import backend_protocol as protocol

#: The folder that holds both ``backend/`` and ``scpainter_blender/`` (the extension root).
EXTENSION_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class BackendError(RuntimeError):
    """The backend reported an error (or died). ``exit_code`` 2 means bad input: ``file`` and ``field`` (the error
    event's) name it; 1 a failure the backend explains or an internal error, whose traceback is in ``log_path``
    (the event's ``log``: ``<output_dir>/backend.log``) when the command had an output folder. ``log``: the tail
    of the backend's standard error. ``str()`` is the message, the hint and where the log is."""

    def __init__(self, message, hint=None, exit_code=None, log="", file=None, field=None, log_path=None):
        self.hint, self.exit_code, self.log = hint, exit_code, log
        self.file, self.field, self.log_path = file, field, log_path
        text = message + (f" ({hint})" if hint else "")
        if log_path and log_path not in text:
            text += f" (log: {log_path})"
        super().__init__(text)

    @property
    def bad_input(self) -> bool:
        """The backend refused its input (exit code 2): ``file`` and ``field`` say which."""
        return self.exit_code == protocol.EXIT_BAD_INPUT


def backend_python(preference: str = "") -> str:
    """The interpreter that runs the backend: the preference if set, else the running one when it can import torch
    (the bpy module in a project venv; Blender's bundled Python usually cannot)."""
    if preference:
        if not os.path.isfile(preference):
            raise BackendError(f"Backend Python not found: {preference}",
                               hint="set it in Preferences > Add-ons > SCPainter")
        return preference
    import importlib.util

    if importlib.util.find_spec("torch") is None:
        raise BackendError("Blender's Python cannot run the backend (no torch)",
                           hint="set Backend Python in Preferences > Add-ons > SCPainter to an interpreter with "
                                "the backend's packages, e.g. the project's .venv/bin/python")
    return sys.executable


def backend_env() -> dict:
    """The environment a backend process runs in: this process's, with the extension root first on ``PYTHONPATH``
    (so ``python -m backend`` finds ``backend`` and ``scpainter_blender``) and unbuffered output."""
    env = dict(os.environ)
    env["PYTHONPATH"] = EXTENSION_ROOT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


class BackendRun:
    """One backend command followed from the add-on, however it runs: ``BackendJob`` (its own process) or
    ``warm_process.WarmRun`` (a request to a warm backend). Its events arrive on a queue filled by a reader thread,
    so ``poll()`` never blocks (what Blender's modal operators need); ``wait()`` blocks instead. ``done``,
    ``error``, ``progress`` (the last one) and ``warnings`` (all, in order) hold what ``poll`` has seen;
    ``returncode`` is the command's exit code once it ended (None before); ``finished`` says it ended and every
    event arrived; ``cancel(grace)`` stops it as SIGTERM stops a command (its unit of work finishes, finished
    outputs are kept), by force after ``grace`` seconds."""

    def _init_events(self):
        import queue

        self._events = queue.Queue()
        self.done = self.error = None
        self.progress = None          # the last progress event
        self.warnings = []            # every warning event, in order (core.backend_protocol.WARNING)
        self.cancelled = False

    returncode: int | None
    finished: bool
    stderr_tail: str
    log_path: str | None = None

    def cancel(self, grace: float = 10.0) -> None:
        raise NotImplementedError

    def _abandon(self) -> None:
        """The caller gives up on the run (an exception while waiting): nothing of it may outlive the caller."""
        raise NotImplementedError

    def _ended_text(self, code) -> str:
        """Why a run ended without a ``done`` event or an ``error`` event (the process died)."""
        tail = self.stderr_tail.strip().splitlines()[-1:] or ["no output"]
        return f"backend exited with code {code}: {tail[0]}"

    def poll(self) -> list:
        """The events that arrived since the last call (never blocks)."""
        import queue

        out = []
        while True:
            try:
                ev = self._events.get_nowait()
            except queue.Empty:
                break
            kind = protocol.kind_of(ev)
            if kind == protocol.DONE:
                self.done = ev
            elif kind == protocol.ERROR:
                self.error = ev
            elif kind == protocol.PROGRESS:
                self.progress = ev
            elif kind == protocol.WARNING:
                self.warnings.append(ev)
            out.append(ev)
        return out

    def result(self) -> dict:
        """The ``done`` event of a finished run, or BackendError with the backend's message and log tail."""
        self.poll()
        code = self.returncode
        if self.error is not None:
            e = self.error
            raise BackendError(e.get("message", "backend error"), e.get("hint"), code, self.stderr_tail,
                               file=e.get("file"), field=e.get("field"), log_path=e.get("log"))
        if self.cancelled:
            raise BackendError("cancelled", "finished outputs are kept", code, self.stderr_tail)
        if code != protocol.EXIT_OK or self.done is None:
            raise BackendError(self._ended_text(code), exit_code=code, log=self.stderr_tail)
        return self.done

    def wait(self, timeout: float | None = None, on_event=None, idle_timeout: float | None = None) -> dict:
        """Block until the run ends; ``on_event`` sees each event. Past ``timeout`` seconds in all, or
        ``idle_timeout`` seconds without an event, the run is cancelled and BackendError says it hung."""
        import time

        start = last = time.monotonic()
        try:
            while not self.finished:
                events = self.poll()
                now = time.monotonic()
                if events:
                    last = now
                for ev in events:
                    if on_event is not None:
                        on_event(ev)
                total = timeout is not None and now - start > timeout
                if total or (idle_timeout is not None and now - last > idle_timeout):
                    self.cancel()
                    why = f"after {now - start:.0f} s" if total else f"with no event for {now - last:.0f} s"
                    raise BackendError(f"backend stopped: it hung {why}",
                                       hint=f"see {self.log_path}" if self.log_path else None, log=self.stderr_tail)
                time.sleep(0.05)
            for ev in self.poll():
                if on_event is not None:
                    on_event(ev)
        except BaseException:
            if not self.finished:
                self._abandon()
            raise
        return self.result()


class BackendJob(BackendRun):
    """``python -m backend *args`` in a subprocess of its own (arguments as a list, no shell), its event stream read
    by a thread (``BackendRun``). ``cancel()`` sends SIGTERM (the backend finishes its unit of work and keeps what is
    done), then kills after ``grace`` seconds. Standard error is kept (its tail for messages) and appended to
    ``log_path`` if given.
    """

    def __init__(self, args, python: str = "", cwd=None, log_path: str | None = None):
        import collections
        import threading

        exe = backend_python(python)
        self.args = [str(a) for a in args]
        self.log_path = log_path
        self.proc = subprocess.Popen([exe, "-m", "backend", *self.args], cwd=cwd or EXTENSION_ROOT, env=backend_env(),
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self._init_events()
        self._stderr = collections.deque(maxlen=200)
        self._threads = [threading.Thread(target=self._read_stdout, daemon=True),
                         threading.Thread(target=self._read_stderr, daemon=True)]
        for t in self._threads:
            t.start()

    def _read_stdout(self):
        for line in self.proc.stdout:
            ev = parse_event(line)
            if ev is not None:
                self._events.put(ev)

    def _read_stderr(self):
        log = open(self.log_path, "a", encoding="utf-8") if self.log_path else None
        try:
            for line in self.proc.stderr:
                self._stderr.append(line.rstrip("\n"))
                if log:
                    log.write(line)
                    log.flush()
        finally:
            if log:
                log.close()

    @property
    def returncode(self) -> int | None:
        """The process's exit code once it exited (None while it runs)."""
        return self.proc.poll()

    @property
    def finished(self) -> bool:
        """The process has exited and both streams are read to the end."""
        return self.proc.poll() is not None and not any(t.is_alive() for t in self._threads)

    @property
    def stderr_tail(self) -> str:
        return "\n".join(self._stderr)

    def cancel(self, grace: float = 10.0) -> None:
        """SIGTERM, then SIGKILL if the backend has not stopped after ``grace`` seconds."""
        self.cancelled = True
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=grace)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def _abandon(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def parse_event(line: str) -> dict | None:
    """A line of the backend's standard output as an event; None for a blank line or one that is not JSON (a
    library printing to stdout: ignored rather than failing the run)."""
    line = line.strip()
    if not line:
        return None
    try:
        return json.loads(line)
    except json.JSONDecodeError:
        return None


def run(args, python: str = "", on_event=None, cwd=None, timeout=None) -> dict:
    """Run ``python -m backend *args`` to the end; returns the ``done`` event, raises BackendError on failure.

    ``on_event(event_dict)`` sees every event as it arrives (progress for a UI, artifacts).
    """
    return BackendJob(args, python, cwd).wait(timeout=timeout, on_event=on_event)


#: ``Invocation``'s fields that are backend options, each with its flag, in the order ``argv()`` writes them. A
#: value of None, False or () leaves the flag out; True writes the flag alone; a tuple repeats it per value.
_FLAGS = (("batch_command", "--command"), ("lists", "--list"), ("trusted_lists", "--trusted-list"),
          ("idle_timeout", "--idle-timeout"), ("device", "--device"), ("checkpoint", "--checkpoint"),
          ("model", "--model"), ("steps", "--steps"),
          ("seed", "--seed"), ("inpaint", "--inpaint"), ("point_radius", "--point-radius"), ("force", "--force"),
          ("allow_outside", "--allow-outside"), ("data_roots", "--data-root"), ("shard", "--shard"), ("ray", "--ray"),
          ("retries", "--retries"), ("cpus_per_job", "--cpus-per-job"), ("export_format", "--format"), ("out", "--out"),
          ("count", "--count"), ("proposals", "--proposals"))
#: How ``argv()`` writes a value other than ``str``: the idle time as ``serve --help`` does ("600", not "600.0").
_SPELLING = {"idle_timeout": lambda seconds: f"{float(seconds):g}"}


@dataclasses.dataclass(frozen=True)
class Invocation:
    """One ``python -m backend`` command: ``command`` (render, generate, export, batch, doctor, mesh-asset,
    splat-asset, serve), its positional ``jobs`` (job.json paths) or ``asset`` (the file mesh-asset / splat-asset
    converts) and the options below (None / False: the backend's default), run by ``python`` (the
    ``backend_python`` rule: "" for the running interpreter when it has torch). Which command takes which option
    is the backend's parser's to say (``backend/commands/``, one module per command; ``build_parser`` in
    ``backend/__main__.py``); a test parses ``argv()`` with it.

    ``device``: one of ``core.backend_protocol.DEVICE_NAMES``. ``checkpoint``: overrides the job's (generate,
    batch) or the folder to check (doctor). ``allow_outside``: the job's paths may lead anywhere; ``data_roots``:
    folders they may lead into besides the job's (render, generate, export, batch). ``ray``: None without Ray, ""
    for the default cluster, else its address. ``shard``: "K/N" (batch). ``export_format``: one of
    ``core.backend_protocol.EXPORT_FORMAT_NAMES`` and ``out`` the destination folder (export) or file (mesh-asset,
    splat-asset: the Gaussian PLY). ``count``: Gaussians of a mesh (mesh-asset). ``idle_timeout``: seconds a
    ``serve`` process waits for a request (0: never ends by itself). ``proposals``: accept, ignore or off (render,
    generate, export, batch: ``core.variation.proposals.MODES``)."""

    command: str
    jobs: tuple = ()
    asset: str | None = None
    batch_command: str | None = None
    lists: tuple = ()
    trusted_lists: tuple = ()
    device: str | None = None
    checkpoint: str | None = None
    model: str | None = None
    steps: int | None = None
    seed: int | None = None
    inpaint: str | None = None
    point_radius: int | None = None
    force: bool = False
    allow_outside: bool = False
    data_roots: tuple = ()
    shard: str | None = None
    ray: str | None = None
    retries: int | None = None
    cpus_per_job: float | None = None
    export_format: str | None = None
    out: str | None = None
    count: int | None = None
    proposals: str | None = None
    idle_timeout: float | None = None
    python: str = ""

    def __post_init__(self):
        if self.device is not None and self.device not in protocol.DEVICE_NAMES:
            raise ValueError(f"device {self.device!r} is not one of {protocol.DEVICE_NAMES}")  # a bug of the caller
        if self.export_format is not None and self.export_format not in protocol.EXPORT_FORMAT_NAMES:
            raise ValueError(f"format {self.export_format!r} is not one of {protocol.EXPORT_FORMAT_NAMES}")

    def argv(self) -> list[str]:
        """The arguments after ``python -m backend``: the command, the jobs (or the asset), then each option that is
        set."""
        out = [self.command, *(os.fspath(j) for j in self.jobs)]
        if self.asset is not None:
            out.append(os.fspath(self.asset))
        for name, flag in _FLAGS:
            value = getattr(self, name)
            if value is None or value is False or value == ():
                continue
            if value is True or (name == "ray" and value == ""):
                out.append(flag)
            elif isinstance(value, tuple):
                out += [a for v in value for a in (flag, os.fspath(v))]
            else:
                out += [flag, _SPELLING.get(name, str)(value)]
        return out

    def replace(self, **changes) -> Invocation:
        return dataclasses.replace(self, **changes)

    def start(self, cwd=None, log_path: str | None = None) -> BackendJob:
        """Start it (``BackendJob``); BackendError when the interpreter cannot run the backend."""
        return BackendJob(self.argv(), self.python, cwd, log_path)

    def run(self, on_event=None, cwd=None, timeout=None) -> dict:
        """Run it to the end (``run``): the ``done`` event; BackendError on failure."""
        return run(self.argv(), self.python, on_event, cwd, timeout)
