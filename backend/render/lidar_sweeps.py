"""A rig job's LiDAR sweeps, written by ``render`` after its cameras (docs/design.md §17): per output frame
``<output_dir>/<LIDAR>/sweep_NNNNNN.pcd.bin`` (nuScenes' layout, ``backend.lidar.sweep``) and beside it
``sweep_NNNNNN.json`` (``SWEEP_SCHEMA``: the frame, its key, the sensor's pose, the returns per source).

The sweep is cast from the scene the cameras see (``backend.lidar.simulate.sweep_for_frame``: the cleaned points,
removal boxes applied, every asset's Gaussians at that frame), the sensor at ego_to_world · lidar_to_ego. Like the
conditions, a frame is cast again only when what it depends on changed (``core.frame_keys.sweep_keys``): its
``.json`` is written after its ``.pcd.bin`` and holds the key, so a killed run never leaves a sweep called done
that is not; a second ``render`` casts nothing. The LiDAR's folder is locked while it is written
(``locking.OutputLock``): the rig's cameras lock their own folders.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import time
from collections.abc import Callable, Sequence

import numpy as np

from scpainter_blender.core import errors, files, frame_keys, locking, outputs
from scpainter_blender.core import job as job_mod
from scpainter_blender.core.backend_protocol import COMPILE_STAGE
from scpainter_blender.core import lidar_model
from scpainter_blender.core.output_layout import OutputLayout

from .. import events
from ..errors import FolderBusyError

SWEEP_SCHEMA = "scpainter.sweep/1"


def settings():
    """The caster's settings every sweep uses (``backend.lidar.cast.LidarSettings``' defaults)."""
    from backend.lidar.cast import LidarSettings

    return LidarSettings()


def done(info_path: str, key: str) -> bool:
    """Whether the sweep whose ``.json`` is ``info_path`` was cast under ``key`` (its ``.pcd.bin`` beside it)."""
    try:
        info = files.read_json(info_path)
    except (OSError, ValueError, errors.InputError):
        return False
    return isinstance(info, dict) and info.get("key") == key and \
        os.path.isfile(info_path[: -len(".json")] + ".pcd.bin")


def _ensure_kernels() -> None:
    """Before the first sweep of a process: the LiDAR's numba kernels compiled (or loaded) between two ``compile``
    progress events when numba's cache does not hold them yet, so a first sweep's seconds of compiling are said, as
    the renderer's are (``warmup.announce_and_warm``)."""
    from backend.lidar import cast_cpu

    if cast_cpu.kernels_cached():
        return
    what = "compiling the LiDAR's kernels (once after an install, 5-30 s)"
    events.progress(COMPILE_STAGE, 0, 1, cached=False, message=what)
    seconds = cast_cpu.warm()
    events.progress(COMPILE_STAGE, 1, 1, cached=False, message=what, seconds=seconds)
    events.log_here(f"{what}: {seconds:.1f} s")


def render_sweeps(job_path: str, job: job_mod.Job, root: str, device: str, force: bool, stop: Sequence[object],
                  log: Callable[[str], None] | None, allow_outside: bool = False) -> dict:
    """Cast and write the sweeps of rig job ``job`` (with a LiDAR) not done yet (all with ``force``) into its
    output folder ``root`` (absolute, made); ``progress`` (stage ``lidar``) and ``artifact`` (kind ``lidar``) events
    per frame. Returns {"sweeps", "cast", "skipped", "stopped"}."""
    from backend.lidar import simulate, sweep as sweep_mod

    from . import frames as fr

    rig = job.rig
    model = lidar_model.model(rig.lidar.model, field="rig.lidar.model")
    layout = OutputLayout(root)
    folder = outputs.output_folder(root, rig.lidar.name, allow_outside)
    sets = settings()
    keys = frame_keys.sweep_keys(job, frame_keys.Inputs.of(job_path, job), dataclasses.asdict(sets))
    todo = {e.frame for e in job.frames if force or not done(layout.lidar_sweep_info(e.frame, rig.lidar.name),
                                                             keys[e.frame])}
    total, cast, skipped = len(job.frames), 0, 0
    with locking.OutputLock(folder, "render", busy=FolderBusyError), events.log_scope():
        log = log or events.FileLog(layout.log)   # the rig's own backend.log: its cameras keep theirs
        scene = None
        for n, e in enumerate(job.frames):
            if stop:
                break
            if e.frame not in todo:
                skipped += 1
            else:
                if scene is None:  # the rig's first camera job: the same scene, its origin the renderer's
                    _ensure_kernels()
                    _, camera_job = job.camera_jobs()[0]
                    scene = fr.load_scene(camera_job, job_path, device)
                    log(f"lidar: {len(todo)} of {total} sweeps of {model.name} ({len(model.elevations_deg)} "
                        f"beams, {model.azimuth_step_deg:g}° steps)")
                t = time.perf_counter()
                lidar_to_world = np.asarray(e.ego_to_world, np.float64) @ np.asarray(rig.lidar.lidar_to_ego)
                sw = simulate.sweep_for_frame(scene, e.frame, lidar_to_world, model, sets)
                bin_path = layout.lidar_sweep(e.frame, rig.lidar.name)
                info_path = layout.lidar_sweep_info(e.frame, rig.lidar.name)
                with contextlib.suppress(FileNotFoundError):
                    os.remove(info_path)   # the key goes first: a kill mid-write leaves the frame not done
                sweep_mod.write_pcd_bin(bin_path, sw)
                by_source = np.bincount(sw.source, minlength=len(job.assets) + 1) if len(sw) else \
                    np.zeros(len(job.assets) + 1, np.int64)
                outputs.write_json(info_path, {
                    "schema": SWEEP_SCHEMA, "frame": int(e.frame), "key": keys[e.frame], "model": model.name,
                    "lidar_to_world": lidar_to_world.tolist(), "returns": int(len(sw)),
                    "returns_per_source": {"points": int(by_source[0]),
                                           **{a.name: int(by_source[i + 1]) for i, a in enumerate(job.assets)}}})
                cast += 1
                events.artifact(bin_path, frame=e.frame, kind="lidar")
                log(f"lidar frame {e.frame}: {len(sw):,} returns in {time.perf_counter() - t:.3f} s")
            events.progress("lidar", n + 1, total, frame=e.frame, reused=e.frame not in todo)
    return {"sweeps": total, "cast": cast, "skipped": skipped, "stopped": bool(stop)}
