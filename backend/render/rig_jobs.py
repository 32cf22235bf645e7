"""A rig job (docs/design.md §17) run camera by camera: ``render``, ``generate`` and ``export`` run each camera job
(``core.job.Job.camera_jobs``: an ordinary single-camera job writing ``<output_dir>/<camera>/``) through their
single-camera code, so frame keys, resume, incremental labels and each camera's labels from its own instance pass
are exactly a single camera's. What a rig adds is here:

- the scene is loaded once for all cameras: the cleaned points and the assets' Gaussians are kept while the rig
  runs (``scene_cache.shared``), so six cameras read and clean the predictions once;
- the cameras' ``progress``, ``artifact`` and ``warning`` events name the camera (``events.tagged``,
  ``backend_protocol.CAMERA_FIELD``);
- one result for the ``done`` event: the counts summed over the cameras, ``cameras`` (their names, in the rig's
  order) and ``per_camera`` (each camera's own result).

The cameras run in the rig's order and stop at the first one stopped (SIGTERM): what finished is kept, and running
again resumes camera by camera.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from scpainter_blender.core import job as job_mod
from scpainter_blender.core.backend_protocol import CAMERA_FIELD

from .. import events
from . import scene_cache

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence


def run_cameras(job: job_mod.Job, run: Callable[[object, job_mod.Job], dict], stop: Sequence[object] = ()) -> list:
    """[(camera name, ``run(camera, camera_job)``'s result)] for each camera of the rig job ``job`` in the rig's
    order, each run's events tagged with its camera, the scene's loads shared between them; stops before the next
    camera once ``stop`` is non-empty or a result says ``stopped``."""
    results = []
    with scene_cache.shared("rig job", "an earlier camera of this rig job"):
        for cam, camera_job in job.camera_jobs():
            if stop:
                break
            with events.tagged(**{CAMERA_FIELD: cam.name}):
                r = run(cam, camera_job)
            results.append((cam.name, r))
            if r.get("stopped"):
                break
    return results


def combined(job: job_mod.Job, results: list, output_dir: str, summed: Sequence[str], stop: Sequence[object] = ()) \
        -> dict:
    """The rig's result: the first camera's result, the ``summed`` counts summed over the cameras, ``output_dir``
    (the rig's folder), ``cameras`` (every camera's name), ``per_camera`` ({name: its result}) and ``stopped``
    (a camera stopped, or cameras left unrun)."""
    out = dict(results[0][1]) if results else {}
    for key in summed:
        out[key] = sum(int(r.get(key) or 0) for _, r in results)
    out.update(output_dir=output_dir, cameras=[c.name for c in job.rig.cameras],
               per_camera={name: r for name, r in results},
               stopped=bool(stop) or len(results) < len(job.rig.cameras) or any(r.get("stopped") for _, r in results))
    return out


def camera_output(output_dir: str, camera: str) -> str:
    """The output folder of rig camera ``camera`` in the rig job's ``output_dir`` (absolute)."""
    from scpainter_blender.core.output_layout import OutputLayout

    return os.path.abspath(OutputLayout(output_dir).camera(camera).root)
