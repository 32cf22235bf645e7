"""``python -m backend doctor`` (backend/commands/doctor.py): what an interpreter has and lacks, reported with the
standard library alone."""

import os

from tests_support import run_backend  # every line of standard output is JSON

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def ray_version():
    import importlib.metadata

    try:
        return importlib.metadata.version("ray")
    except importlib.metadata.PackageNotFoundError:
        return None


def test_doctor():
    code, events, _ = run_backend("doctor")
    assert code == 0
    assert events[-1]["event"] == "done"
    report = events[-1]["report"]
    assert report["numpy"] and report["python"].startswith("3.")
    assert report["ray"] == ray_version() and "ray" not in report["missing"]   # optional: batch --ray


def test_doctor_reports_opencv():
    """cv2's version, the one OpenCV distribution the pins install (two overwrite each other's cv2), contrib's
    modules, and the video back-ends of its build (the PyPI wheels are built with FFmpeg)."""
    import cv2

    code, events, _ = run_backend("doctor")
    assert code == 0
    report = events[-1]["report"]
    assert report["cv2"] == cv2.__version__ and "cv2" not in report["missing"]
    opencv = report["opencv"]
    assert list(opencv["distributions"]) == ["opencv-contrib-python-headless"]
    assert opencv["distributions"]["opencv-contrib-python-headless"].startswith(cv2.__version__ + ".")
    assert opencv["contrib"] is True
    assert opencv["video_io"]["FFMPEG"] == "YES" and opencv["video_io"]["GStreamer"] == "NO"


def _without_numpy(tmp_path) -> dict:
    """An environment whose Python cannot import numpy (a package of that name that fails as a missing one would),
    as a Blender interpreter without the backend's packages is."""
    fake = tmp_path / "no_numpy" / "numpy"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ModuleNotFoundError(\"No module named 'numpy'\", name='numpy')\n")
    return {"PYTHONPATH": os.pathsep.join([str(tmp_path / "no_numpy"), ROOT])}


def test_doctor_without_numpy_says_what_to_install(tmp_path):
    """doctor imports nothing but the standard library before it reports: the missing packages and the README's fix;
    any other command says the same in its error, never a traceback."""
    env = _without_numpy(tmp_path)
    code, events, err = run_backend("doctor", "--checkpoint", str(tmp_path), env=env)
    assert code == 0, err
    report = events[-1]["report"]
    assert "numpy" in report["missing"] and "pip install -r requirements.txt" in report["install"]
    assert report["checkpoint"].startswith("not checked")
    code, events, err = run_backend("render", "job.json", env=env)
    assert code == 2 and "Traceback" not in err
    assert events[-1]["field"] == "numpy" and "tools/setup.sh" in events[-1]["hint"]
