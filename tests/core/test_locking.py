"""core.locking: one run per output folder; a second run is refused naming the owner, a lock left by a dead
process (or unreadable for long enough) is taken over, and nothing is left behind (issue 14)."""

import json
import os
import subprocess
import sys
import time

import pytest

from scpainter_blender.core import locking


class Busy(Exception):
    def __init__(self, message, hint, **fields):
        self.fields = fields
        super().__init__(f"{message} | {hint}")


def test_second_lock_is_busy_and_the_file_goes_on_exit(tmp_path):
    with locking.OutputLock(tmp_path, "render", busy=Busy) as lock:
        assert os.path.exists(lock.path)
        record = json.loads(open(lock.path).read())
        assert record["pid"] == os.getpid() and record["command"] == "render"
        with pytest.raises(Busy, match=f"being written by another run: pid {os.getpid()}.*render"):
            with locking.OutputLock(tmp_path, "generate", busy=Busy):
                pass
        assert os.path.exists(lock.path)  # the refused second lock did not remove the first one's file
    assert not os.path.exists(os.path.join(tmp_path, locking.LOCK_NAME))
    with pytest.raises(KeyError):  # removed on an error too
        with locking.OutputLock(tmp_path, "render"):
            raise KeyError("x")
    assert not os.path.exists(os.path.join(tmp_path, locking.LOCK_NAME))


def test_stale_lock_of_a_finished_process_is_taken_over(tmp_path):
    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                           check=True)
    dead = int(child.stdout)
    import socket

    stale = {"pid": dead, "host": socket.gethostname(), "started": 1, "command": "render", "since": "yesterday"}
    lock_path = tmp_path / locking.LOCK_NAME
    lock_path.write_text(json.dumps(stale))
    with locking.OutputLock(tmp_path, "generate", busy=Busy) as lock:
        assert lock.stale == stale
        assert json.loads(lock_path.read_text())["pid"] == os.getpid()
    assert not lock_path.exists()
    for garbage in ({"pid": 0, "host": socket.gethostname()}, {"pid": -1, "host": socket.gethostname()}):
        lock_path.write_text(json.dumps(garbage))  # kill(0) / kill(-1) would "find" a process: not an owner
        with locking.OutputLock(tmp_path, "generate", busy=Busy) as lock:
            assert lock.stale == garbage
    lock_path.write_text("[" * 5000)  # unreadable: busy, with what to do, never a traceback
    with pytest.raises(Busy, match="lock file is unreadable") as e:
        with locking.OutputLock(tmp_path, "generate", busy=Busy):
            pass
    assert e.value.fields == {"file": str(lock_path), "owner": None}
    old = time.time() - locking.UNREADABLE_LOCK_S - 5          # ... until it is old: a crash mid-write, taken over
    os.utime(lock_path, (old, old))
    with locking.OutputLock(tmp_path, "generate", busy=Busy) as lock:
        assert "unreadable lock file" in str(lock.stale)
    assert sorted(os.listdir(tmp_path)) == []            # neither lock nor its temporary file is left


def test_a_retried_task_takes_over_its_own_lock_from_another_host(tmp_path, monkeypatch):
    """A scheduler's retry (``TASK_ENV``: the same task id) takes over the lock its dead attempt left on another
    machine, where the pid cannot be checked; another task's lock from another machine stays busy."""
    left = {"pid": 4242, "host": "node-that-died", "started": 1, "command": "render", "since": "now",
            "task": "run1:7"}
    lock_path = tmp_path / locking.LOCK_NAME
    lock_path.write_text(json.dumps(left))
    monkeypatch.setenv(locking.TASK_ENV, "run1:8")
    with pytest.raises(Busy, match="node-that-died"):
        with locking.OutputLock(tmp_path, "render", busy=Busy):
            pass
    monkeypatch.setenv(locking.TASK_ENV, "run1:7")
    with locking.OutputLock(tmp_path, "render", busy=Busy) as lock:
        assert lock.stale == left and json.loads(lock_path.read_text())["task"] == "run1:7"
    monkeypatch.delenv(locking.TASK_ENV)
    lock_path.write_text(json.dumps(left))
    with pytest.raises(Busy):  # a run outside any scheduler never takes over another host's lock
        with locking.OutputLock(tmp_path, "render", busy=Busy):
            pass


def test_the_lock_is_never_taken_through_a_folder_swapped_for_a_link(tmp_path):
    """render: job/out swapped for a link after it was made: the lock file was made in the link's target (fuzz
    race 7). The lock is taken relative to the folder checked once (``outputs.open_folder``): an InputError, and
    nothing is made there."""
    from scpainter_blender.core import outputs
    from scpainter_blender.core.errors import InputError

    out, outside = tmp_path / "out", tmp_path / "outside"
    outside.mkdir()
    root = outputs.make_folder(str(out), root=True)
    os.rename(root, str(out) + ".moved")
    os.symlink(outside, root)
    with pytest.raises(InputError) as e:
        with locking.OutputLock(root, "render"):
            pass
    assert e.value.path == root
    assert os.listdir(outside) == []


@pytest.mark.parametrize("target", ["outside/lock.json", "outside/missing"])
def test_a_link_planted_at_the_lock_file_is_refused_by_name_never_followed(tmp_path, target):
    """fuzz links 6/26/46: a symbolic link at ``.scpainter.lock`` (into another folder, or dangling) was read as an
    unreadable lock ("the output folder is locked", naming no field). It is bad input naming the file; the link's
    target is neither read nor written, and the link stays for the user to remove."""
    from scpainter_blender.core.errors import InputError

    (tmp_path / "outside").mkdir()
    (tmp_path / "outside" / "lock.json").write_text('{"pid": 1}')
    out = tmp_path / "out"
    out.mkdir()
    lock = out / locking.LOCK_NAME
    os.symlink(tmp_path / target, lock)
    with pytest.raises(InputError) as e:
        with locking.OutputLock(str(out), "render"):
            pass
    assert (e.value.path, e.value.field) == (str(lock), "(file)") and "symbolic link" in e.value.message
    assert os.path.islink(lock) and sorted(os.listdir(tmp_path / "outside")) == ["lock.json"]
    assert (tmp_path / "outside" / "lock.json").read_text() == '{"pid": 1}'
