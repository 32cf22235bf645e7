"""The warm backend's memory of loaded inputs (docs/design.md §12): a scene's cleaned point cloud and an asset's
Gaussians on the device, kept between the requests of one ``python -m backend serve`` process, so that a second
render of the same scene does not read, clean and upload them again. Off unless ``enable`` ran (a one-shot process
loads everything once anyway); ``frames.load_points`` and ``frames.load_asset`` ask it.

Keys (what the cached value depends on, and nothing a request can change without changing the key):

- points: the predictions file (``identity``: real path, device and inode, size, mtime and ctime in ns) and the
  job's scene settings the cloud is made from (``Job.layers_dict()["scene"]`` without the path as the job wrote it:
  ``vggt_to_world``, confidence, extrinsic convention, crop, removal boxes, point cleaning). The value is
  ``frames.KeptCloud`` (``cleaning.clean_cloud``'s points); each job then takes its own copy relative to its own
  scene origin on its device (``frames.load_points``), so a moved camera path or another device still finds it.
- assets: the file (``identity``) and the device; the value is ``frames.make_asset``'s, whose tensors are only
  ever read (each job's ``Asset`` gets its own name and transforms).

A file replaced (a new inode) or written again in place (a new ctime, which no program can set back, even with
the same size and a restored mtime) is read again.

Bounded: the last ``POINTS_KEPT`` clouds and ``ASSETS_KEPT`` assets used. A hit is logged to the log of the
command running (``events.log_here``: the output folder's ``backend.log``).
"""

from __future__ import annotations

import collections
import contextlib
import json
import os
from typing import TYPE_CHECKING

from .. import events

if TYPE_CHECKING:
    from collections.abc import Iterator

#: How many point clouds and assets a warm backend keeps (the last used): a scene or two and their cars.
POINTS_KEPT, ASSETS_KEPT = 2, 8

#: {"points": OrderedDict, "assets": OrderedDict} while enabled; None: nothing is kept.
_kept: dict | None = None
#: (whose memory, who loaded what a hit serves): the log line's words, a warm backend's or ``shared``'s.
_source = ("warm backend", "an earlier request")


def enable(source: tuple[str, str] | None = None) -> None:
    """Keep what is loaded from now on (the warm backend, at its start; a Ray worker of a batch). ``source``: the
    words of a hit's log line (whose memory, who loaded it), default a warm backend's."""
    global _kept, _source
    if source is not None:
        _source = source
    if _kept is None:
        _kept = {"points": collections.OrderedDict(), "assets": collections.OrderedDict()}


@contextlib.contextmanager
def shared(whose: str, what: str) -> Iterator[None]:
    """Inside the block what is loaded is kept, as a warm backend keeps it (``enable``), so that the cameras of one
    rig job (docs/design.md §17) read and clean the scene's points once; on leaving, a process that kept nothing
    before forgets it again. ``whose``, ``what``: the log line of a hit ("rig job", "its first camera")."""
    global _kept, _source
    was, before = _kept is not None, _source
    enable()
    _source = (whose, what)
    try:
        yield
    finally:
        _source = before
        if not was:
            disable()


def disable() -> None:
    """Forget everything and keep nothing from now on."""
    global _kept
    _kept = None


def _get(kind: str, key: str, make, limit: int, what: str):
    """The value under ``key`` (moved to the newest place) or ``make()``'s, kept; the oldest beyond ``limit``
    dropped."""
    if _kept is None:
        return make()
    kept = _kept[kind]
    if key in kept:
        kept.move_to_end(key)
        events.log_here(f"{_source[0]}: {what} served from memory (loaded by {_source[1]})")
        return kept[key]
    value = make()
    kept[key] = value
    while len(kept) > limit:
        kept.popitem(last=False)
    return value


def identity(path: str) -> list[int]:
    """What a kept value takes of an input file: [st_dev, st_ino, size, mtime ns, ctime ns] of its real path
    (``os.stat``; OSError when it is gone)."""
    st = os.stat(path)
    return [int(st.st_dev), int(st.st_ino), int(st.st_size), int(st.st_mtime_ns), int(st.st_ctime_ns)]


def points(path: str, scene_settings: dict, make):
    """The cleaned cloud of the predictions at ``path`` under ``scene_settings`` (the job's ``layers_dict``
    scene): ``make()``'s result, or the one kept for the same file and settings."""
    real = os.path.realpath(path)
    settings = {k: v for k, v in scene_settings.items() if k != "predictions"}  # the file is named by ``real``
    key = json.dumps([real, identity(real), settings], sort_keys=True)
    return _get("points", key, make, POINTS_KEPT, f"the points of {path}")


def asset(path: str, device, make):
    """The asset made from the Gaussian file at ``path`` on ``device``: ``make()``'s result, or the one kept."""
    real = os.path.realpath(path)
    key = json.dumps([real, identity(real), str(device)])
    return _get("assets", key, make, ASSETS_KEPT, f"the Gaussians of {path}")
