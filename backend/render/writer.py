"""Writing rendered frames in the background: a frame's files are encoded and written on worker threads while the
next frame renders (docs/design.md §10, "A frame's whole cost").

``render`` spends about as long writing a frame as rendering it (at 576 × 1024 on the CPU: the ZIP EXR ~70 ms, the
preview ~14 ms, the labels and labelled preview ~17 ms; a frame ~110 ms on average), and the encoders run outside
the GIL (OpenEXR's write and zlib release it for their work: measured by how long a Python thread is kept waiting
while they run, ``bench/render_writes.py``), so the writes overlap the next frame's rendering where a core is free.

Per frame the caller gives two callables (``FrameWriter.submit``):

* ``write()`` runs on a worker thread and writes the frame's files in the order that makes it finished last (the
  EXR and preview, then its labels, whose file marks the frame finished): one frame's writes are never split
  across threads, so a kill at any moment leaves each frame whole or not finished, as inline writing did;
* ``finish(result)`` runs on the thread that submits, with what ``write`` returned, once the frame's files are on
  disk, in submission order: the events (artifacts, warnings, progress) and log lines, so the event stream is
  written by one thread, in frame order, and says only what is on disk.

Bounded: at most ``in_flight`` frames (their layers, ~17 MB each at 576 × 1024) are waiting or being written;
``submit`` waits for the oldest beyond that. An exception raised by a ``write`` is raised again, the same object,
by the next ``submit``, ``after`` or ``close`` of the caller (frames queued behind it are not written; those
already being written finish first, whole). ``close`` waits for every frame and runs their ``finish``: call it
before returning, including after a stop (SIGTERM), so every frame the run started writing is whole and reported.
"""

from __future__ import annotations

import collections
from concurrent.futures import Future, ThreadPoolExecutor

#: Worker threads: two frames can be written at once when writing a frame takes longer than rendering one.
WORKERS = 2
#: Frames rendered but not finished at most (the bounded queue: their layers stay in memory until written).
IN_FLIGHT = 2


class FrameWriter:
    """Frames' writes on ``workers`` threads, finished in submission order on the caller's thread (module
    docstring). Use ``close`` (or ``with``) to wait for all of them."""

    def __init__(self, workers: int = WORKERS, in_flight: int = IN_FLIGHT):
        if workers < 1 or in_flight < 1:
            raise ValueError("workers and in_flight must be at least 1")
        self._pool = ThreadPoolExecutor(workers, thread_name_prefix="scpainter-frame-writer")
        self._in_flight = in_flight
        self._queue: collections.deque = collections.deque()  # (Future or None, finish) in submission order
        self._closed = False

    def submit(self, write, finish=None) -> None:
        """Write a frame: ``write()`` on a worker thread, then ``finish(write's result)`` here, in order (module
        docstring). Finishes the frames already written first; waits while ``in_flight`` frames are unfinished.
        Raises what an earlier frame's ``write`` raised."""
        if self._closed:
            raise RuntimeError("FrameWriter is closed")
        self._finish_ready()
        while sum(f is not None for f, _ in self._queue) >= self._in_flight:
            self._finish_first()
        self._queue.append((self._pool.submit(write), finish))

    def after(self, fn) -> None:
        """``fn()`` on this thread once every frame submitted so far is finished, in order with their ``finish``:
        at once when none is waiting (a frame that was not rendered reports its progress after the frames before
        it). Raises what an earlier frame's ``write`` raised."""
        self._queue.append((None, lambda _: fn()))
        self._finish_ready()

    def close(self) -> None:
        """Wait for every frame's write and run the ``finish`` callables in order; then stop the threads. Raises the
        first ``write``'s exception (later frames not yet started are not written). Idempotent."""
        if self._closed:
            return
        try:
            while self._queue:
                self._finish_first()
        finally:
            self._closed = True
            self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self):
        return self

    def __exit__(self, kind, value, tb):
        if kind is None:
            self.close()
        else:  # the caller's own error goes on: only the frames being written finish (whole), none is reported
            self._abandon()

    def _finish_ready(self) -> None:
        while self._queue and (self._queue[0][0] is None or self._queue[0][0].done()):
            self._finish_first()

    def _finish_first(self) -> None:
        future, finish = self._queue[0]
        try:
            result = None if future is None else future.result()
        except BaseException:
            self._abandon()
            raise
        self._queue.popleft()
        if finish is not None:
            finish(result)

    def _abandon(self) -> None:
        """Cancel the frames not started, wait for those being written (so no thread writes after this returns),
        forget them all."""
        for future, _ in self._queue:
            if isinstance(future, Future):
                future.cancel()
        self._queue.clear()
        self._closed = True
        self._pool.shutdown(wait=True, cancel_futures=True)
