"""Run the add-on inside the ``bpy`` module the way Blender runs it: built, installed, enabled as an extension.

Shared by the tests, the demo and the benchmarks. ``BLENDER_USER_RESOURCES`` must point at a private folder
*before* ``bpy`` is imported, so nothing touches the user's own Blender configuration: call
``use_private_user_resources`` first.
"""

from __future__ import annotations

import glob
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REPO_MODULE = "scpainter_local"
PACKAGE = f"bl_ext.{REPO_MODULE}.scpainter"


def use_private_user_resources(path: str | None = None) -> str:
    if "bpy" in sys.modules:
        raise RuntimeError("use_private_user_resources() must run before bpy is imported")
    path = path or tempfile.mkdtemp(prefix="scpainter-blender-user-")
    os.makedirs(path, exist_ok=True)
    os.environ["BLENDER_USER_RESOURCES"] = path
    return path


def blender_ext_tool() -> str:
    """Blender's own extension command-line tool, shipped inside the bpy wheel."""
    import bpy

    path = os.path.join(bpy.utils.resource_path("LOCAL"), "scripts", "addons_core", "bl_pkg", "cli",
                        "blender_ext.py")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"Blender's extension tool not found ({path})")
    return path


def build_extension(out_dir: str) -> str:
    """Validate and build the extension zip with Blender's tool; returns the zip path."""
    tool = blender_ext_tool()
    os.makedirs(out_dir, exist_ok=True)
    subprocess.run([sys.executable, tool, "validate", ROOT], check=True, capture_output=True, text=True)
    subprocess.run([sys.executable, tool, "build", "--source-dir", ROOT, "--output-dir", out_dir], check=True,
                   capture_output=True, text=True)
    zips = sorted(glob.glob(os.path.join(out_dir, "scpainter-*.zip")), key=os.path.getmtime)
    return zips[-1]


def ensure_repo(directory: str):
    import bpy

    repos = bpy.context.preferences.extensions.repos
    repo = next((r for r in repos if r.module == REPO_MODULE), None)
    if repo is None:
        os.makedirs(directory, exist_ok=True)
        repo = repos.new(name="SCPainter local", module=REPO_MODULE, custom_directory=directory, source="USER")
    return repo


def install_zip(zip_path: str, directory: str) -> str:
    """Install a built zip the way Blender's extension manager does, and enable it; returns the package name."""
    import bpy

    ensure_repo(directory)
    r = bpy.ops.extensions.package_install_files(filepath=zip_path, repo=REPO_MODULE, enable_on_install=True)
    if r != {"FINISHED"}:
        raise RuntimeError(f"installing {zip_path} failed: {r}")
    if PACKAGE not in bpy.context.preferences.addons:
        raise RuntimeError(f"{PACKAGE} was installed but is not enabled")
    return PACKAGE


def install_for_script(work_dir: str) -> str:
    """Private user folder under ``work_dir``, bpy imported, the extension built and installed: the package name.

    For scripts (demo, benchmarks) that use the add-on the way Blender runs it, without touching the user's own
    Blender configuration.
    """
    user = os.path.join(work_dir, "blender-user")
    use_private_user_resources(user)
    return install_zip(build_extension(os.path.join(work_dir, "dist")),
                       os.path.join(user, "extensions", REPO_MODULE))


def write_bench_json(path: str, rows: list) -> None:
    """A benchmark's rows with the machine they ran on, written atomically (``core.outputs.write_json``)."""
    import platform

    import bpy

    from scpainter_blender.core import outputs

    os.makedirs(os.path.dirname(path), exist_ok=True)
    outputs.write_json(path, {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                                          "blender": bpy.app.version_string}, "rows": rows})
