"""``backend.render.writer.FrameWriter`` (frames written on worker threads while the next renders) and the render
command through it: each frame's files in order with its labels last, its events in frame order once its files are
on disk, a writer's exception raised as itself, a stop that drains every frame started. Synchronised with events
(threading.Event), never with sleeps."""

import json
import os
import sys
import threading

import numpy as np
import pytest

from backend.render import channels
from backend.render import command as render_cmd
from backend.render import writer
from scpainter_blender.core import job as J
from scpainter_blender.core.output_layout import OutputLayout
from tests_support import small_job


def test_finishes_run_in_submission_order_on_the_callers_thread():
    """Frame 1's write finishes only after frame 2's has: the finishes (and an ``after``) still run 1, 2, 3."""
    second_written = threading.Event()
    done, threads = [], []

    def write(i):
        if i == 1:
            assert second_written.wait(30)
        if i == 2:
            second_written.set()
        return i * 10

    def finish(result):
        done.append(result)
        threads.append(threading.current_thread())

    with writer.FrameWriter(workers=2, in_flight=2) as w:
        w.submit(lambda: write(1), finish)
        w.submit(lambda: write(2), finish)
        w.after(lambda: done.append("progress"))
        w.submit(lambda: write(3), finish)
    assert done == [10, 20, "progress", 30]
    assert set(threads) == {threading.main_thread()}


def test_after_runs_at_once_when_nothing_is_being_written():
    said = []
    w = writer.FrameWriter()
    w.after(lambda: said.append(1))
    assert said == [1]
    w.close()
    w.close()  # idempotent


def test_at_most_in_flight_frames_wait():
    """The third submit waits for the first frame (the bounded queue): it is finished when submit returns."""
    release = threading.Event()
    finished = []
    w = writer.FrameWriter(workers=2, in_flight=2)
    w.submit(lambda: release.wait(30), lambda r: finished.append(1))
    w.submit(lambda: release.wait(30), lambda r: finished.append(2))
    assert finished == []
    release.set()
    w.submit(lambda: None, lambda r: finished.append(3))
    assert finished[:1] == [1]
    w.close()
    assert finished == [1, 2, 3]


class Broken(OSError):
    pass


def test_a_writers_exception_is_raised_as_itself_and_nothing_after_it_is_reported():
    error = Broken(28, "No space left on device")
    reported, go = [], threading.Event()
    w = writer.FrameWriter(workers=1, in_flight=2)

    def fail():
        assert go.wait(30)
        raise error

    w.submit(fail, reported.append)
    w.after(lambda: reported.append("progress"))
    go.set()
    with pytest.raises(Broken) as raised:
        w.close()
    assert raised.value is error
    assert reported == []
    w.close()  # closed: nothing more is raised or run
    with pytest.raises(RuntimeError):
        w.submit(lambda: None)


def test_the_next_submit_raises_an_earlier_frames_exception():
    error = ValueError("bad frame")
    failed = threading.Event()
    w = writer.FrameWriter(workers=1, in_flight=1)

    def fail():
        failed.set()
        raise error

    w.submit(fail)
    assert failed.wait(30)
    with pytest.raises(ValueError) as raised:  # in_flight=1: this submit waits for frame 1, and gets its error
        w.submit(lambda: None)
    assert raised.value is error


def test_close_after_a_stop_waits_for_the_frames_being_written():
    release = threading.Event()
    finished = []
    w = writer.FrameWriter(workers=2, in_flight=2)
    for i in range(2):
        w.submit(lambda i=i: (release.wait(30), i)[1], finished.append)
    release.set()
    w.close()
    assert finished == [0, 1]


# -- the render command through the writer ---------------------------------------------------------------------

class EventLog:
    """Standard output as the backend writes events: each line parsed, and whether the file an artifact event names
    is on disk at the moment the event is written (and, for a frame's labels, its EXR and preview too)."""

    def __init__(self):
        self.events, self.missing = [], []
        self._part = ""

    def write(self, text):
        self._part += text
        while "\n" in self._part:
            line, self._part = self._part.split("\n", 1)
            ev = json.loads(line)
            self.events.append(ev)
            if ev["event"] == "artifact" and not os.path.isfile(ev["path"]):
                self.missing.append(ev["path"])
        return len(text)

    def flush(self):
        pass


def kinds_by_frame(events):
    out = {}
    for e in events:
        if e["event"] == "artifact":
            out.setdefault(e["frame"], []).append(e["kind"])
        elif e["event"] == "progress":
            out.setdefault(e["frame"], []).append("progress")
    return out


def test_render_events_say_each_frame_in_order_once_its_files_are_on_disk(tmp_path, monkeypatch):
    frames = tuple(range(1, 7))
    path = small_job(tmp_path, frames=frames)
    log = EventLog()
    monkeypatch.setattr(sys, "stdout", log)
    result = render_cmd.render_job(path, J.load(path), "cpu")
    monkeypatch.undo()
    assert result["rendered"] == len(frames) and not log.missing
    assert [e["done"] for e in log.events if e["event"] == "progress"] == list(range(1, len(frames) + 1))
    assert kinds_by_frame(log.events) == {f: ["conditions", "preview", "labelled", "labels", "progress"]
                                          for f in frames}
    layout = OutputLayout(str(tmp_path / "out"))
    for f in frames:  # the labels (written last) are no older than the frame's EXR and preview
        labels_time = os.stat(layout.frame_labels(f)).st_mtime_ns
        assert labels_time >= os.stat(layout.condition_exr(f)).st_mtime_ns
        assert labels_time >= os.stat(layout.condition_preview(f)).st_mtime_ns


def test_render_writes_the_same_files_as_inline_writing(tmp_path):
    """The EXR bytes (and the preview's pixels) are what ``channels.write`` and ``png.write_png`` give for the
    layers ``render_frame`` returns, called inline."""
    from backend import png
    from backend.render import frames as fr

    path = small_job(tmp_path, frames=(1, 2, 3))
    job = J.load(path)
    render_cmd.render_job(path, job, "cpu")
    scene = fr.load_scene(job, path, "cpu")
    W, H = job.resolution
    layout = OutputLayout(str(tmp_path / "out"))
    for entry in job.frames:
        layers = fr.render_frame(scene, entry, W, H)
        inline = str(tmp_path / f"inline_{entry.frame}.exr")
        channels.write(inline, layers, camera=channels.camera_attributes(entry.K, entry.world_to_camera, W, H))
        with open(inline, "rb") as a, open(layout.condition_exr(entry.frame), "rb") as b:
            assert a.read() == b.read()
        png.write_png(str(tmp_path / "inline.png"), np.stack([layers[c] for c in channels.IMAGE], -1))
        assert read_png(str(tmp_path / "inline.png")).tobytes() == read_png(
            layout.condition_preview(entry.frame)).tobytes()


def read_png(path):
    import cv2

    return cv2.imread(path, cv2.IMREAD_UNCHANGED)


def test_a_write_error_propagates_from_render_as_inline(tmp_path):
    """Frame 2's EXR cannot be written (a folder stands at its name): render raises the error the writer thread
    raised (``outputs.atomic_path``'s InputError naming the frame); frame 1 is whole and frame 2 has no labels."""
    from scpainter_blender.core.errors import InputError

    path = small_job(tmp_path, frames=(1, 2, 3))
    layout = OutputLayout(str(tmp_path / "out"))
    os.makedirs(layout.condition_exr(2))
    with pytest.raises(InputError) as e:
        render_cmd.render_job(path, J.load(path), "cpu")
    assert e.value.path == layout.condition_exr(2) and "is a folder" in e.value.message
    channels.read(layout.condition_exr(1))
    assert os.path.isfile(layout.frame_labels(1))
    assert not os.path.exists(layout.frame_labels(2))
    assert not [n for n in os.listdir(os.path.dirname(layout.condition_exr(1))) if n.endswith(".tmp")]


def test_a_stop_between_frames_leaves_every_started_frame_whole_and_reported(tmp_path, monkeypatch):
    """The caller stops once frame 1 is reported (its log line): the run returns stopped, every frame with an EXR
    has its preview and labels and was reported, and a second run renders only the rest."""
    frames = tuple(range(1, 9))
    path = small_job(tmp_path, frames=frames)
    stop, lines = [], []

    def log(line):
        lines.append(line)
        if line.startswith("frame 1:"):
            stop.append(True)

    events_out = EventLog()
    monkeypatch.setattr(sys, "stdout", events_out)
    result = render_cmd.render_job(path, J.load(path), "cpu", stop=stop, log=log)
    monkeypatch.undo()
    assert result["stopped"] and 1 <= result["rendered"] < len(frames)
    layout = OutputLayout(str(tmp_path / "out"))
    on_disk = [f for f in frames if os.path.exists(layout.condition_exr(f))]
    reported = [e["frame"] for e in events_out.events if e["event"] == "progress"]
    assert on_disk == reported == list(frames[:result["rendered"]])
    for f in on_disk:
        channels.read(layout.condition_exr(f))
        assert os.path.isfile(layout.condition_preview(f)) and os.path.isfile(layout.frame_labels(f))
    again = render_cmd.render_job(path, J.load(path), "cpu")
    assert again["skipped"] == len(on_disk) and again["rendered"] == len(frames) - len(on_disk)
