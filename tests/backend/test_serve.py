"""``python -m backend serve`` (a warm backend) through its client ``runs.warm_process.WarmBackend``: requests run as
one-shot commands run, in one process that keeps the points and assets it loaded (bit-identical layers); cancel,
SIGTERM, SIGKILL, idle time and the end of its input; the renderer's kernels made ready before the first frame."""

import os
import signal
import sys

import numpy as np
import pytest

from scpainter_blender.runs.client import BackendError
from scpainter_blender.runs.warm_process import WarmBackend
from scpainter_blender.core import backend_protocol as protocol
from tests_support import run_backend, small_job, variant_jobs

#: Generous bounds for a loaded 2-core machine: a server's start (torch, kernels) and a small request.
START_S, REQUEST_S = 180, 180


@pytest.fixture
def warm():
    backend = WarmBackend(sys.executable, "cpu", idle_timeout=0)
    yield backend
    backend.close(grace=10)
    assert backend.proc.returncode is not None


def _render(job, *extra):
    return ["render", str(job), "--device", "cpu", *extra]


def _layers(job_path):
    from backend.render import channels

    folder = os.path.join(os.path.dirname(job_path), "out", "conditions")
    return {f: channels.read(os.path.join(folder, f)) for f in sorted(os.listdir(folder)) if f.endswith(".exr")}


def _log(job_path):
    with open(os.path.join(os.path.dirname(job_path), "out", "backend.log")) as f:
        return f.read()


def test_requests_reuse_the_process_and_its_cache_bit_for_bit(warm, tmp_path):
    _, (v1, v2) = variant_jobs(tmp_path)          # two jobs reading one predictions file and one car
    code, events, err = run_backend(*_render(v1, "--allow-outside"))  # cold: a process of its own
    assert code == 0, err
    cold = _layers(v1)
    first = warm.submit(_render(v2, "--allow-outside"))
    assert first.wait(timeout=START_S)["rendered"] == 2 and first.returncode == 0
    assert "served from memory" not in _log(v2)
    second = warm.submit(_render(v1, "--force", "--allow-outside"))   # the same points and car: served from memory
    seen = []
    done = second.wait(timeout=REQUEST_S, on_event=seen.append)
    assert done["rendered"] == 2 and second.returncode == 0 and second.server_pid == first.server_pid
    log = _log(v1)
    assert "warm backend: the points of" in log and "warm backend: the Gaussians of" in log
    warm_layers = _layers(v1)
    assert warm_layers.keys() == cold.keys()
    for name in cold:
        for channel in cold[name]:
            assert np.array_equal(cold[name][channel], warm_layers[name][channel], equal_nan=True), (name, channel)
    # the events are the one-shot command's (served is the client's own: never passed on)
    def steps(evs):
        return [(protocol.kind_of(e), e.get("stage"), e.get("done"), e.get("path")) for e in evs
                if protocol.kind_of(e) in (protocol.PROGRESS, protocol.ARTIFACT)]

    assert steps(seen) == steps(events)
    assert [protocol.kind_of(e) for e in seen].count(protocol.DONE) == 1
    assert protocol.SERVED not in [protocol.kind_of(e) for e in seen]


def test_bad_requests_are_answered_and_the_server_lives_on(warm, tmp_path):
    refused = warm.submit(["train", "x.json"])
    with pytest.raises(BackendError, match="'train' is not run by a warm backend") as e:
        refused.wait(timeout=START_S)
    assert e.value.bad_input and refused.returncode == protocol.EXIT_BAD_INPUT
    parse = warm.submit(["render", "job.json", "--no-such-option"])
    with pytest.raises(BackendError, match="no-such-option") as e:
        parse.wait(timeout=REQUEST_S)
    assert e.value.exit_code == protocol.EXIT_BAD_INPUT and "usage:" in parse.stderr_tail
    missing = warm.submit(_render(tmp_path / "nothing.json"))
    with pytest.raises(BackendError, match="nothing.json") as e:
        missing.wait(timeout=REQUEST_S)
    assert e.value.bad_input
    ok = warm.submit(_render(small_job(tmp_path / "a")))
    assert ok.wait(timeout=REQUEST_S)["rendered"] == 2 and warm.alive


def _long_job(folder):
    """A job of 400 small frames: seconds of work, stopped long before its end."""
    return small_job(folder, frames=tuple(range(1, 401)), resolution=(64, 48))


def _first_frame(run, timeout=START_S):
    """Wait (bounded) until the run's first frame is rendered."""
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end and not run.finished:
        run.poll()
        if run.progress and run.progress.get("stage") == "render":
            return
        time.sleep(0.05)
    pytest.fail("no frame rendered in time")


def test_cancel_stops_the_request_cleanly_and_the_server_lives_on(warm, tmp_path):
    job = _long_job(tmp_path / "a")
    run = warm.submit(_render(job))
    _first_frame(run)
    run.cancel(grace=60)
    assert run.finished and run.returncode == protocol.EXIT_FAILED
    with pytest.raises(BackendError, match="stopped by SIGTERM after .* of 400 frames"):
        run.result()
    assert warm.alive
    kept = len([f for f in os.listdir(tmp_path / "a" / "out" / "conditions") if f.endswith(".exr")])
    assert 0 < kept < 400
    again = warm.submit(_render(small_job(tmp_path / "b")))
    assert again.wait(timeout=REQUEST_S)["rendered"] == 2 and again.server_pid == run.server_pid


def test_sigterm_stops_the_request_then_the_server(warm, tmp_path):
    run = warm.submit(_render(_long_job(tmp_path)))
    _first_frame(run)
    os.kill(warm.pid, signal.SIGTERM)
    assert warm.proc.wait(timeout=REQUEST_S) == 0
    with pytest.raises(BackendError, match="stopped by SIGTERM after"):
        run.wait(timeout=60)
    assert run.returncode == protocol.EXIT_FAILED


def test_a_killed_server_fails_its_request_clearly(warm, tmp_path):
    run = warm.submit(_render(_long_job(tmp_path)))
    _first_frame(run)
    os.kill(warm.pid, signal.SIGKILL)
    with pytest.raises(BackendError, match=r"the warm backend \(pid \d+\) was killed by SIGKILL during this run") as e:
        run.wait(timeout=60)
    assert e.value.exit_code == -signal.SIGKILL and not warm.alive
    late = warm.submit(_render(small_job(tmp_path / "b")))  # a dead server fails at once, never hangs
    with pytest.raises(BackendError, match="was killed by SIGKILL during this run"):
        late.wait(timeout=60)


def test_idle_time_and_end_of_input_end_the_server(tmp_path):
    idle = WarmBackend(sys.executable, "cpu", idle_timeout=1)
    try:
        assert idle.submit(_render(small_job(tmp_path))).wait(timeout=START_S)["rendered"] == 2
        assert idle.proc.wait(timeout=START_S) == 0          # ended itself a second after the request
    finally:
        idle.close(grace=5)
    eof = WarmBackend(sys.executable, "cpu", idle_timeout=0)
    eof.proc.stdin.close()                                   # Blender gone
    assert eof.proc.wait(timeout=START_S) == 0


def test_warm_up_compiles_every_kernel_a_render_uses(tmp_path):
    """After ``warmup.warm`` a real render (points, a car, amodal counts) makes numba compile nothing more."""
    from backend.render import frames as fr
    from backend.render import warmup
    from scpainter_blender.core import job as job_mod

    warmup.warm("cpu")
    before = {k: len(k.signatures) for k in warmup.kernels()}
    assert all(before.values())
    job_path = small_job(tmp_path)
    job = job_mod.load(job_path)
    scene = fr.load_scene(job, job_path, "cpu")
    kept = {}
    fr.render_frame(scene, job.frames[0], *job.resolution, keep=kept)
    fr.amodal_pixels(scene, job.frames[0], *job.resolution, projection=kept["projection"])
    assert {k: len(k.signatures) for k in warmup.kernels()} == before


def test_one_shot_render_says_it_compiles_the_kernels(tmp_path):
    """Kernels not cached yet (an empty NUMBA_CACHE_DIR): a one-shot render emits ``compile`` progress before its
    first frame; the next run finds them cached and says nothing."""
    cache = str(tmp_path / "numba")
    job = small_job(tmp_path / "a")
    code, events, err = run_backend(*_render(job), env={"NUMBA_CACHE_DIR": cache})
    assert code == 0, err
    stages = [e["stage"] for e in events if protocol.kind_of(e) == protocol.PROGRESS]
    assert stages[:2] == [protocol.COMPILE_STAGE] * 2 and stages[2] == "render"
    assert events[0]["cached"] is False and events[1]["seconds"] > 0
    assert "compiling the renderer's kernels" in _log(job)
    code, events, err = run_backend(*_render(small_job(tmp_path / "b")), env={"NUMBA_CACHE_DIR": cache})
    assert code == 0, err
    assert protocol.COMPILE_STAGE not in [e.get("stage") for e in events]


def test_malformed_requests_are_each_answered_and_the_server_serves_on(tmp_path):
    """Issue 42: a non-integer id killed the server; deep nesting, a 5,000-digit integer, ``{"cancel": [1]}`` or
    invalid UTF-8 killed its reader thread (it then answered nothing until the idle timeout). Each malformed line
    now gets an error event naming the problem (file "(request)", the field, the id where one can be read, then a
    ``served`` event with exit code 2), in order, and a valid request after them all is still served. One real
    server process for every case (bounded waits on its events, no sleeps)."""
    import json
    import queue
    import subprocess
    import threading

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    proc = subprocess.Popen([sys.executable, "-m", "backend", "serve", "--device", "cpu", "--idle-timeout", "0"],
                            cwd=root, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    got: queue.Queue = queue.Queue()
    reader = threading.Thread(target=lambda: [got.put(json.loads(line)) for line in proc.stdout], daemon=True)
    reader.start()
    limit = protocol.MAX_REQUEST_BYTES
    cases = [  # (line, the field named, the id the answer carries)
        (b'{"id": "seven", "argv": ["render", "job.json"]}', "id", None),
        (b'{"id": 1.5, "argv": ["render"]}', "id", None),
        (b"[" * 100_000 + b"]" * 100_000, "(line)", None),
        (b'{"id": 1' + b"2" * 5000 + b', "argv": ["render"]}', "id", None),
        (b'{"cancel": [1]}', "cancel", None),
        (b'{"cancel": "all"}', "cancel", None),
        (b'{"id": 8, "argv": ["render", "caf\xc3"]}', "(line)", None),                  # invalid UTF-8
        (b"\xff\xfe{}", "(line)", None),
        (b'{"id": 9, "argv": "render job.json"}', "argv", 9),
        (b'{"id": 10, "argv": ["render", 5]}', "argv[1]", 10),
        (b'{"id": 11, "argv": ["render", "a\\u0000b"]}', "argv[1]", 11),
        (b'{"id": 12}', "argv", 12),
        (b'{"id": 13, "argv": ["render"], "extra": 1}', "extra", 13),
        (b'{"quit": "yes"}', "quit", None),
        (b"not json", "(line)", None),
        (b"[1, 2]", "(top level)", None),
        (b"{}", "(top level)", None),
        (b'{"id": 14, "argv": ["' + b"x" * limit + b'"]}', "(line)", None),           # longer than the bound
        (b'{"id": NaN, "argv": ["render"]}', "id", None),
    ]
    job = small_job(tmp_path / "a")
    try:
        for line, *_ in cases:
            proc.stdin.write(line + b"\n")
        proc.stdin.write(json.dumps(protocol.request(99, ["render", str(job), "--check"])).encode() + b"\n")
        proc.stdin.flush()

        def next_event(timeout):
            try:
                return got.get(timeout=timeout)
            except queue.Empty:
                pytest.fail(f"no event in {timeout} s (server alive: {proc.poll() is None})")

        for line, field, rid in cases:
            ev = next_event(START_S)
            while protocol.kind_of(ev) == protocol.PROGRESS:  # the kernels' warm-up, before the first answer
                ev = next_event(START_S)
            assert protocol.kind_of(ev) == protocol.ERROR, (line[:60], ev)
            assert ev["file"] == protocol.REQUEST_SOURCE and ev["field"] == field and ev["id"] == rid, (line[:60], ev)
            assert ev["hint"] and len(ev["message"]) < 500
            if rid is not None:
                assert next_event(REQUEST_S) == protocol.event(protocol.SERVED, id=rid,
                                                               exit_code=protocol.EXIT_BAD_INPUT)
        answer = [next_event(REQUEST_S)]
        while protocol.kind_of(answer[-1]) != protocol.SERVED:
            answer.append(next_event(REQUEST_S))
        assert answer[-1]["id"] == 99 and answer[-1]["exit_code"] == protocol.EXIT_OK, answer
        assert any(protocol.kind_of(e) == protocol.DONE and e.get("check") for e in answer)
        # lines queued when a quit arrives are answered, not dropped (a burst of requests then a quit gave no
        # answer): the malformed line's error, then the request run or "cancelled before it started", and its served
        # event; nothing after the quit is read, and the server ends with exit 0
        proc.stdin.write(b"not json\n" + json.dumps(protocol.request(100, ["render", str(job), "--check"])).encode()
                         + b'\n{"quit": true}\n{"id": 101, "argv": ["render"]}\n')
        proc.stdin.flush()
        assert proc.wait(timeout=START_S) == 0
        proc.stdin.close()
        reader.join(timeout=REQUEST_S)                        # every event it wrote is read (its output ended)
        assert not reader.is_alive()
        rest = [next_event(REQUEST_S)]
        while protocol.kind_of(rest[-1]) != protocol.SERVED:
            rest.append(next_event(REQUEST_S))
        assert protocol.kind_of(rest[0]) == protocol.ERROR and rest[0]["field"] == "(line)", rest
        assert rest[-1]["id"] == 100 and rest[-1]["exit_code"] in (protocol.EXIT_OK, protocol.EXIT_FAILED), rest
        if rest[-1]["exit_code"] == protocol.EXIT_FAILED:
            assert any("cancelled before it started" in e.get("message", "") for e in rest), rest
        assert got.empty(), got.get()                         # nothing for the line after the quit
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
