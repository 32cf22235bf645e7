"""The project installs into its own .venv (pyproject.toml, by tools/setup.sh) with a `scpainter-backend` command,
`python -m backend` keeps working from the repository root, and the extension zip is unaffected."""

import json
import os
import subprocess
import sys
import tomllib
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _toml(name):
    with open(os.path.join(ROOT, name), "rb") as f:
        return tomllib.load(f)


def _events(stdout: str) -> list:
    return [json.loads(line) for line in stdout.splitlines() if line.startswith("{")]


def test_project_version_is_the_extension_version():
    assert _toml("pyproject.toml")["project"]["version"] == _toml("blender_manifest.toml")["version"]


def test_console_command_runs_from_any_folder(tmp_path):
    """tools/setup.sh installs the project (editable) into the interpreter running the tests; its command works
    from a folder that is not the checkout, with no PYTHONPATH, and names itself in its usage."""
    from backend.__main__ import CONSOLE_COMMAND

    assert _toml("pyproject.toml")["project"]["scripts"] == {CONSOLE_COMMAND: "backend.__main__:main"}
    exe = os.path.join(os.path.dirname(sys.executable), CONSOLE_COMMAND)
    assert os.access(exe, os.X_OK), f"{exe} missing: run tools/setup.sh (it installs the project into .venv)"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    r = subprocess.run([exe, "doctor"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    done = [e for e in _events(r.stdout) if e["event"] == "done"]
    assert done and done[-1]["command"] == "doctor", r.stdout
    r = subprocess.run([exe, "--help"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.startswith(f"usage: {CONSOLE_COMMAND} "), r.stdout[:200]
    # the same code as the checkout's: the installed package is this tree, not a copy
    r = subprocess.run([sys.executable, "-c", "import backend; print(backend.__file__)"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and os.path.dirname(r.stdout.strip()) == os.path.join(ROOT, "backend"), r


def test_python_m_backend_still_works_from_the_checkout():
    r = subprocess.run([sys.executable, "-m", "backend", "--help"], cwd=ROOT, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and r.stdout.startswith("usage: python -m backend ") and "generate" in r.stdout, r


def test_extension_zip_leaves_the_packaging_out(extension_zip):
    names = zipfile.ZipFile(extension_zip).namelist()
    assert "pyproject.toml" not in names and not [n for n in names if ".egg-info/" in n]
