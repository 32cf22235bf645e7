"""Helpers shared by the tests (data they make themselves; nothing is downloaded)."""

import os
import subprocess

import numpy as np

from scpainter_blender.core.geometry import cameras as C


def synthetic_predictions(S=3, H=14, W=21, seed=0):
    """Synthetic predictions shaped exactly as VGGT's demo saves them (float32, no batch axis)."""
    rng = np.random.default_rng(seed)
    ext = np.zeros((S, 3, 4), np.float32)
    for i in range(S):
        R = C.quaternion_to_rotation(np.array([1.0, *rng.normal(0, 0.05, 3)]))
        ext[i, :, :3] = R
        ext[i, :, 3] = rng.normal(0, 0.2, 3)
    ext[0] = np.eye(3, 4)
    intr = np.zeros((S, 3, 3), np.float32)
    intr[:, 0, 0] = intr[:, 1, 1] = 20.0
    intr[:, 0, 2], intr[:, 1, 2], intr[:, 2, 2] = W / 2, H / 2, 1.0
    return {
        "images": rng.random((S, 3, H, W), dtype=np.float32),
        "depth": rng.uniform(0.5, 3.0, (S, H, W, 1)).astype(np.float32),
        "depth_conf": (1.0 + rng.exponential(2.0, (S, H, W))).astype(np.float32),
        "extrinsic": ext,
        "intrinsic": intr,
        "world_points": rng.normal(0, 1, (S, H, W, 3)).astype(np.float32),
        "world_points_conf": (1.0 + rng.exponential(2.0, (S, H, W))).astype(np.float32),
    }


def evaluated_counts(obj) -> tuple[int, int]:
    """What ``obj``'s modifiers make of it, counted in the depsgraph: (points of its point-cloud component,
    instances of its instances component).

    Read from ``Depsgraph.object_instances`` (every Blender from 4.2), where each component beyond the object's own
    data comes out as an instance entry whose ``parent`` is ``obj``: a point cloud as one entry with ``PointCloud``
    data, each instance as an entry of its own. ``Object.evaluated_geometry()`` says the same directly, but it came
    in 4.3 and the Blender-side tests also run on 4.2 LTS (docs/design.md §6).
    """
    import bpy

    points = instances = 0
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for inst in depsgraph.object_instances:
        if not inst.is_instance or inst.parent is None or inst.parent.original != obj.original:
            continue
        if isinstance(inst.object.data, bpy.types.PointCloud):
            points += len(inst.object.data.attributes["position"].data)
        else:
            instances += 1
    return points, instances


def run_backend(*args, timeout=900, env=None):
    """``python -m backend *args`` from the repo: (exit code, the events, standard error); ``env``: variables set
    on top of this process's."""
    import json
    import os
    import subprocess
    import sys

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    p = subprocess.run([sys.executable, "-m", "backend", *map(str, args)], cwd=root, capture_output=True, text=True,
                       timeout=timeout, env=None if env is None else {**os.environ, **env})
    return p.returncode, [json.loads(line) for line in p.stdout.splitlines() if line.strip()], p.stderr


def run_backend_here(*args):
    """What ``run_backend(*args)`` gives (exit code, the events, standard error), from the same entry point,
    ``backend.__main__.main``, run in this process in the folder ``run_backend`` runs in.

    For the tests that are not about the process itself (signals, kills, the environment it starts with, what
    reaches its file descriptors): a ``python -m backend`` start imports torch, and ``generate`` diffusers, again
    (2 to 8 s each on the CI machine), which this process has imported once. A command that reserves standard output
    for its events (``events.reserve_stdout``: ``batch --ray``, ``evaluate --ray``, ``serve``) changes this
    process for good: it fails the test here, saying to use ``run_backend``."""
    import contextlib
    import io
    import json
    import os

    from backend import events
    from backend.__main__ import main

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out, err = io.StringIO(), io.StringIO()
    with contextlib.chdir(root), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in args])
        except SystemExit as e:  # argparse's errors, as `python -m backend` exits with them
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    if events._EVENT_STREAM is not None:
        events._EVENT_STREAM = None
        raise AssertionError(f"backend {args[0]} reserved standard output for this process: use run_backend")
    return code, [json.loads(line) for line in out.getvalue().splitlines() if line.strip()], err.getvalue()


def street_with_car(street, folder, count=3000, seed=7, paint=(0.1, 0.3, 0.8), location=(-3.5, 9.0, 0.0),
                    shift=2.0):
    """In the current bpy session: the ground-truth street imported at its true scale, a procedural Gaussian car
    (saved as Amodal3R saves it, in ``folder``) at ``location``, and a camera path ``shift`` m to the left, which
    becomes the scene camera. Returns the scene."""
    import os

    import bpy

    from scpainter_blender.core import shapes

    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, scale_mode="TRAJECTORY",
                                  trajectory_path=os.path.join(street.root, "metric.npz"))
    ply = os.path.join(str(folder), "car.ply")
    shapes.save_as_amodal3r(ply, shapes.procedural_car_gaussians(count=count, seed=seed, paint=paint))
    bpy.context.scene.cursor.location = location
    bpy.ops.scpainter.import_gaussians(filepath=ply)
    bpy.ops.scpainter.new_camera_path(shift=shift)
    return bpy.context.scene


def realdata(relpath):
    """A real public file from ``../shared/realdata`` (or ``$SCPAINTER_REALDATA``), or skip the test saying so.

    These files are never committed (PROVENANCE.md in that folder says where each comes from)."""
    import os

    import pytest

    root = os.environ.get("SCPAINTER_REALDATA") or os.path.join(
        os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "..", "shared", "realdata")
    path = os.path.join(root, relpath)
    if not os.path.isfile(path):
        pytest.skip(f"real data file {relpath} not found under {os.path.abspath(root)} (set SCPAINTER_REALDATA)")
    return os.path.abspath(path)


def small_job(folder, frames=(1, 2), resolution=(16, 12), asset=True, **extra):
    """A self-contained job in ``folder`` that renders in milliseconds: ``predictions.npz`` (2 frames of 12 x 16
    synthetic predictions), ``car.ply`` (300 procedural Gaussians as Amodal3R saves them) when ``asset``, and
    ``job.json`` (``frames`` seen from the recorded camera, output ``out``); ``extra`` updates the job's top level.
    Returns the job file's path."""
    import os

    from scpainter_blender.core import job as J
    from scpainter_blender.core import shapes
    from scpainter_blender.core.vggt import npz as vggt_io

    folder = str(folder)
    os.makedirs(folder, exist_ok=True)
    pred = synthetic_predictions(S=2, H=12, W=16, seed=3)
    vggt_io.save_predictions(os.path.join(folder, "predictions.npz"), images=pred["images"], depth=pred["depth"],
                             depth_conf=pred["depth_conf"], extrinsic=pred["extrinsic"],
                             intrinsic_vggt=pred["intrinsic"])
    W, H = resolution
    w2c = np.eye(4)
    K = [[12.0 * W / 16, 0, W / 2], [0, 12.0 * W / 16, H / 2], [0, 0, 1]]
    job = {"schema": J.SCHEMA, "resolution": [W, H], "output_dir": "out",
           "frames": [{"frame": f, "K": K, "world_to_camera": w2c.tolist(), "source_frames": [0, 1]} for f in frames],
           "scene": {"predictions": "predictions.npz", "vggt_to_world": np.eye(4).tolist()}}
    if asset:
        shapes.save_as_amodal3r(os.path.join(folder, "car.ply"), shapes.procedural_car_gaussians(count=300, seed=2))
        place = np.diag([4.0, 4.0, 4.0, 1.0])
        place[:3, 3] = [0.0, 0.0, 6.0]
        job["assets"] = [{"name": "car", "ply": "car.ply", "object_to_world": {str(f): place.tolist() for f in frames}}]
    job.update(extra)
    path = os.path.join(folder, "job.json")
    J.save(path, job)
    return path


def variant_jobs(folder, names=("v1", "v2")):
    """The usual layout of many variants of one recording: ``folder/shared`` holds the recording's
    ``predictions.npz`` and the asset ``car.ply`` (``small_job``'s), and each ``folder/<name>/job.json`` reads them
    through ``../shared/`` and writes its own ``out``. Returns (the shared folder, the job paths)."""
    import os

    from scpainter_blender.core import job as J

    shared = os.path.join(str(folder), "shared")
    os.remove(small_job(shared))
    jobs = []
    for name in names:
        path = small_job(os.path.join(str(folder), name))
        for own in ("predictions.npz", "car.ply"):
            os.remove(os.path.join(os.path.dirname(path), own))
        job = J.load(path).to_dict()
        job["scene"]["predictions"] = "../shared/predictions.npz"
        job["assets"][0]["ply"] = "../shared/car.ply"
        J.save(path, job)
        jobs.append(path)
    return shared, jobs


def copy_clip(clip_json_path, tmp_path, edit, name="clip"):
    """A copy of a clip folder (the one holding ``clip_json_path``) at ``tmp_path / name``, its clip.json passed
    through ``edit(data, folder)`` (which changes ``data`` in place and may write files into the copy)."""
    import json
    import os
    import shutil

    folder = tmp_path / name
    shutil.copytree(os.path.dirname(clip_json_path), folder)
    with open(folder / "clip.json") as f:
        data = json.load(f)
    edit(data, folder)
    with open(folder / "clip.json", "w") as f:
        json.dump(data, f)
    return folder


def refusal_beside_fifo(load, fifo, error, what: str, timeout: float = 20.0):
    """The ``error`` that ``load()`` raises when a file it reads is the FIFO ``fifo``, asserting it came at once: a
    loader still waiting after ``timeout`` s fails the test with "``what`` blocked on a FIFO" (the FIFO is then
    opened for writing, so the waiting thread ends)."""
    import threading

    import pytest

    result = {}

    def attempt():
        try:
            load()
        except error as e:
            result["error"] = e

    worker = threading.Thread(target=attempt, daemon=True)
    worker.start()
    worker.join(timeout)
    if worker.is_alive():
        with open(fifo, "wb"):
            pass
        pytest.fail(f"{what} blocked on a FIFO")
    return result["error"]


#: The top-level parts of the checkout that ship or run for a user: the extension and the backend.
SHIPPED = ("scpainter_blender", "operators", "panels", "backend", "__init__.py")


def tracked_sources(exclude=(), shipped_only=False) -> dict:
    """{path: text} of the checkout's .py files outside tests/ (paths relative to the checkout, with "/"), for the
    tests that check a fact is spelled only in its one home and for the documents' tests: the git-tracked files and
    the untracked ones git does not ignore (a new module counts before it is staged), less those deleted from disk.
    ``shipped_only`` keeps only ``SHIPPED``; ``exclude`` leaves out paths and folder prefixes ("bench/", the fact's
    home). Skips the calling test outside a git checkout."""
    import pytest

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:
        listed = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "*.py"], cwd=root,
                                capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    out = {}
    for path in listed.stdout.split():
        if path.startswith("tests/") or (shipped_only and path.split("/")[0] not in SHIPPED) or \
                any(path == e or (e.endswith("/") and path.startswith(e)) for e in exclude) or \
                not os.path.isfile(os.path.join(root, path)):
            continue
        with open(os.path.join(root, path), encoding="utf-8") as f:
            out[path] = f.read()
    assert "backend/__main__.py" in out or "backend/__main__.py" in exclude, "the checkout was not listed"
    return out


def street_base_job(street, path, recorded_cars: bool = False, fps: float = 10.0, resolution=None):
    """A job of the street's recorded drive written to ``path`` without Blender (from ``metric.npz``: the true
    metric cameras and ``vggt_to_world``); ``recorded_cars``: the parked cars of ``street.json`` as the scene's
    recorded objects (their true boxes, at every frame). Returns the job."""
    import json

    from scpainter_blender.core import job as J

    m = np.load(os.path.join(street.root, "metric.npz"))
    # every recorded frame's points in every output frame, as Blender exports a points object showing all frames
    frames = [J.Frame(i + 1, m["K"][i], m["world_to_camera"][i], list(range(len(m["K"])))) for i in range(len(m["K"]))]
    scene = J.Scene(street.predictions_path, m["vggt_to_world"])
    if recorded_cars:
        with open(os.path.join(street.root, "street.json")) as f:
            cars = json.load(f)["cars"]
        scene.recorded_objects = [J.RecordedObject(c["name"], np.array(c["size"]),
                                                   {fr.frame: np.array(c["box_to_world"]) for fr in frames})
                                  for c in cars]
    W, H = street.params.width, street.params.height
    job = J.Job((W, H), frames, ".", scene, fps=fps)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    return J.save(path, job)


def street_parked_cars(street) -> list:
    """(box_to_world (4, 4), size (3,)) of the street's parked cars: the ground truth."""
    import json

    with open(os.path.join(street.root, "street.json")) as f:
        return [(np.array(c["box_to_world"]), np.array(c["size"])) for c in json.load(f)["cars"]]
