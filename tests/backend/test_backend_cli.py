"""``python -m backend``: the event stream, exit codes, and the ground-plane metric scale on the street."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from scpainter_blender import backend_client
from scpainter_blender.core import cameras as C

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def run_backend(*args):
    proc = subprocess.run([sys.executable, "-m", "backend", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)
    events = [json.loads(line) for line in proc.stdout.splitlines() if line.strip()]  # every line is JSON
    return proc.returncode, events, proc.stderr


def test_doctor():
    code, events, _ = run_backend("doctor")
    assert code == 0
    assert events[-1]["event"] == "done"
    report = events[-1]["report"]
    assert report["numpy"] and report["python"].startswith("3.")


def test_ground_plane_recovers_metric_scale(street):
    code, events, err = run_backend("ground-plane", street.predictions_path, "--camera-height", 1.6)
    assert code == 0, err
    assert [e["event"] for e in events] == ["progress", "progress", "done"]
    r = events[-1]["result"]
    metric = street.metric()
    truth = float(metric["metres_per_unit"])
    assert r["scale"] == pytest.approx(truth, rel=0.005)
    assert r["residual_m"] < 0.01 and r["details"]["tilt_deg"] < 5
    # the levelled world: cameras 1.6 m over z = 0, the road's own points at z ≈ 0
    M = np.array(r["world_from_vggt"])
    from scpainter_blender.core import vggt as V

    pred = V.load_predictions(street.predictions_path)
    cams = C.camera_centers(C.transform_world_to_camera(C.orthonormalize(pred.world_to_camera), M))
    assert np.abs(cams[:, 2] - 1.6).max() < 0.01


def test_ground_plane_is_deterministic(street):
    a = run_backend("ground-plane", street.predictions_path, "--camera-height", 1.5)[1][-1]["result"]
    b = run_backend("ground-plane", street.predictions_path, "--camera-height", 1.5)[1][-1]["result"]
    assert a == b


def test_bad_input_exit_code_and_error_event(tmp_path):
    bad = tmp_path / "broken.npz"
    bad.write_bytes(b"PK\x03\x04 not really")
    code, events, _ = run_backend("ground-plane", bad, "--camera-height", 1.6)
    assert code == 2
    assert events[-1]["event"] == "error" and "broken.npz" in events[-1]["message"]


def test_client_raises_with_message(tmp_path):
    with pytest.raises(backend_client.BackendError, match="missing.npz") as e:
        backend_client.run(["ground-plane", tmp_path / "missing.npz", "--camera-height", 1.6])
    assert e.value.exit_code == 2
    seen = []
    done = backend_client.run(["doctor"], on_event=seen.append)
    assert done["event"] == "done" and seen[-1] == done
    with pytest.raises(backend_client.BackendError, match="not found"):
        backend_client.run(["doctor"], python=str(tmp_path / "no-python"))
