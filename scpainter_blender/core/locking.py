"""One run per output folder (issue 14): ``OutputLock``, and ``lock_owner`` for ``--check``.

The lock file ``<output folder>/.scpainter.lock`` (``OutputLayout.LOCK``) holds the owner's pid, host, process
start time, command and start date. A second run is refused naming the owner; a lock whose owner died (on this
host), that nobody can read for ``UNREADABLE_LOCK_S``, or that an earlier attempt of the same scheduled task left
(``TASK_ENV``), is taken over.

stdlib only (no bpy): the add-on and the backend share it.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import socket
import time

from .errors import InputError
from .files import open_regular
from .output_layout import OutputLayout
from .outputs import make_folder, open_folder

LOCK_NAME = OutputLayout.LOCK  # the lock's name in any folder it guards (a job's output folder, train's)
UNREADABLE_LOCK_S = 60   # a lock file nobody can read is taken over after this (a crash mid-write on old systems)
#: Set by a scheduler that retries a job only after the job's previous attempt ended (``backend/batch/ray_pool.py``: the
#: Ray task's id): the lock records it, and a lock holding the same id is taken over on any host — the previous
#: attempt's worker died, possibly on another machine, where its pid cannot be checked.
TASK_ENV = "SCPAINTER_LOCK_TASK"


def _process_start(pid: int):
    """The process's start time in clock ticks (Linux ``/proc``), to tell a live owner from a reused pid; None
    where unknown."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return int(f.read().rsplit(b")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return None


def _process_state(pid: int):
    """The process's state letter (``Z`` zombie) from Linux ``/proc``; None where unknown."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0]
    except (OSError, IndexError, ValueError):
        return None


def _alive(pid: int, started) -> bool:
    if pid <= 0:  # kill(0) and kill(-1) would test our own process group / every process: garbage, not an owner
        return False
    if _process_state(pid) == b"Z":  # a zombie has exited; only its exit status waits for its parent
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except (OverflowError, ValueError):
        return False
    return started is None or _process_start(pid) in (None, started)


class OutputLock:
    """``with OutputLock(folder, command):`` — at most one run writes an output folder at a time.

    The lock file ``<folder>/.scpainter.lock`` (created exclusively, never through a link) holds the owner's pid,
    host, process start time, command and start date, and appears whole (see ``_take``). A second run raises
    ``busy(message, hint, file=, owner=)`` naming the owner; a lock left by a process that no longer runs on this
    host, or unreadable for ``UNREADABLE_LOCK_S``, is taken over (``stale`` is then the old owner's record, for a
    log line). The file is removed when the block ends."""

    def __init__(self, folder, command: str, busy=None):
        self.folder, self.command = os.fspath(folder), command
        self.path = os.path.join(self.folder, LOCK_NAME)
        self.busy = busy or (lambda message, hint, **fields: RuntimeError(f"{message} ({hint})"))
        self.stale = None
        self._held = False

    def _owner(self):
        try:
            with open_regular(self.path) as f:
                return json.loads(f.read(4096).decode("utf-8"))
        except (InputError, ValueError, OSError, RecursionError):
            return None

    def _take(self, me: dict) -> bool:
        """Create the lock file whole or not at all: written to a private temporary file, then hard-linked to its
        name (``link`` fails if the name exists, never follows a planted link), so no reader sees it empty. All of
        it relative to the folder opened once (``outputs.open_folder``): an output folder swapped for a link since
        it was made is an InputError, and no lock file is written through it."""
        dfd = open_folder(self.folder)
        try:
            return self._take_in(dfd, me)
        finally:
            if dfd is not None:
                os.close(dfd)

    def _take_in(self, dfd, me: dict) -> bool:
        def at(name):   # a name in the folder: relative to its descriptor where the system has one
            return (name, {"dir_fd": dfd}) if dfd is not None else (os.path.join(self.folder, name), {})

        nofollow = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
        for _ in range(100):
            tmp = f"{LOCK_NAME}.{secrets.token_hex(4)}"
            try:
                where, kw = at(tmp)
                fd = os.open(where, os.O_WRONLY | os.O_CREAT | os.O_EXCL | nofollow, 0o600, **kw)
                break
            except FileExistsError:
                continue
        else:
            raise FileExistsError(f"{self.path}: no free temporary name")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(me, f)
            try:
                src, kw = at(tmp)
                dst, _ = at(LOCK_NAME)
                os.link(src, dst, **({"src_dir_fd": dfd, "dst_dir_fd": dfd} if dfd is not None else {}))
            except FileExistsError:
                return False
            except OSError:  # a file system without hard links: exclusive create, then write
                try:
                    where, kw = at(LOCK_NAME)
                    fd2 = os.open(where, os.O_WRONLY | os.O_CREAT | os.O_EXCL | nofollow, 0o644, **kw)
                except FileExistsError:
                    return False
                with os.fdopen(fd2, "w", encoding="utf-8") as f:
                    json.dump(me, f)
            return True
        except OSError as e:
            if e.filename is None:  # a write's error (a full disk) names no file: the lock's
                e.filename = self.path
            raise
        finally:
            with contextlib.suppress(OSError):
                where, kw = at(tmp)
                os.remove(where, **kw)

    def __enter__(self):
        make_folder(self.folder)
        if os.path.islink(self.path):   # planted: never read or followed (taking the lock never writes through it)
            raise InputError(self.path, "(file)", "is a symbolic link where the output folder's lock goes: "
                                                  "SCPainter never makes one, and never follows it",
                             hint="remove it, then run again")
        me = {"pid": os.getpid(), "host": socket.gethostname(), "started": _process_start(os.getpid()),
              "command": self.command, "since": time.strftime("%Y-%m-%d %H:%M:%S")}
        if os.environ.get(TASK_ENV):
            me["task"] = os.environ[TASK_ENV]
        for _ in range(3):
            if self._take(me):
                self._held = True
                return self
            owner = self._owner()
            if owner is None:  # unreadable: written by a file system without links this instant, or damaged
                time.sleep(0.05)
                owner = self._owner()
            if isinstance(owner, dict) and owner.get("host") == me["host"] and isinstance(owner.get("pid"), int) \
                    and not _alive(owner["pid"], owner.get("started")):
                self.stale = owner
            elif isinstance(owner, dict) and me.get("task") and owner.get("task") == me["task"]:
                self.stale = owner  # this job's previous attempt, which the scheduler saw end
            elif owner is None and self._age() > UNREADABLE_LOCK_S:
                self.stale = {"unreadable lock file, age s": round(self._age())}
            elif owner is None:
                raise self.busy(f"{self.path}: the output folder is locked and the lock file is unreadable",
                                f"it is taken over when older than {UNREADABLE_LOCK_S} s; delete it if no other "
                                "SCPainter run uses this folder", file=self.path, owner=None)
            else:
                raise self.busy(f"{self.folder} is being written by another run: pid {owner.get('pid')} on "
                                f"{owner.get('host')} ({owner.get('command')}, since {owner.get('since')})",
                                f"wait for it to finish or stop it; if it is gone, delete {self.path}",
                                file=self.path, owner=owner)
            self._remove()
        raise self.busy(f"{self.path}: could not take the output folder's lock", "try again", file=self.path,
                        owner=None)

    def took_over(self) -> str | None:
        """A log line when the lock was taken over from a run that ended without releasing it, else None."""
        o = self.stale
        if o is None:
            return None
        who = (f"pid {o.get('pid')} on {o.get('host')} ({o.get('command')}, since {o.get('since')})"
               if "pid" in o else "an unreadable lock file")
        return f"took over the output folder's lock from {who}: that run ended without releasing it"

    def _age(self) -> float:
        try:
            return time.time() - os.lstat(self.path).st_mtime
        except OSError:
            return 0.0

    def _remove(self) -> None:
        """Delete the lock file, relative to the folder checked again (``open_folder``): swapped for a link
        meanwhile, nothing is removed there (InputError)."""
        dfd = open_folder(self.folder)
        try:
            with contextlib.suppress(FileNotFoundError):
                if dfd is None:
                    os.remove(self.path)
                else:
                    os.remove(LOCK_NAME, dir_fd=dfd)
        finally:
            if dfd is not None:
                os.close(dfd)

    def __exit__(self, *exc):
        if self._held:
            self._held = False
            with contextlib.suppress(OSError, InputError):   # a folder swapped meanwhile keeps its lock file
                self._remove()
        return False


def lock_owner(folder):
    """The record of the run holding ``folder``'s lock if that run is alive on this host (or elsewhere: unknown,
    taken as alive), else None: for ``--check`` to say a run would be refused."""
    owner = OutputLock(folder, "check")._owner()
    if not isinstance(owner, dict) or not isinstance(owner.get("pid"), int):
        return None
    if owner.get("host") == socket.gethostname() and not _alive(owner["pid"], owner.get("started")):
        return None
    return owner
