"""Start the backend (``python -m backend ...``) in a subprocess and read its event stream (DESIGN §4.4).

No bpy, no torch: the add-on calls this from Blender's Python, where neither torch nor open3d exist; the
backend runs under the interpreter chosen in the add-on preferences.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

#: The folder that holds both ``backend/`` and ``scpainter_blender/`` (the extension root).
EXTENSION_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class BackendError(RuntimeError):
    """The backend reported an error (or died); ``exit_code`` 2 means bad input."""

    def __init__(self, message, hint=None, exit_code=None, log=""):
        self.hint, self.exit_code, self.log = hint, exit_code, log
        super().__init__(message + (f" ({hint})" if hint else ""))


def backend_python(preference: str = "") -> str:
    """The interpreter that runs the backend: the preference if set, else the running one."""
    if preference:
        if not os.path.isfile(preference):
            raise BackendError(f"Backend Python not found: {preference}",
                               hint="set it in Preferences > Add-ons > SCPainter")
        return preference
    return sys.executable


def run(args, python: str = "", on_event=None, cwd=None, timeout=None) -> dict:
    """Run ``python -m backend *args`` to the end; returns the ``done`` event, raises BackendError on failure.

    ``on_event(event_dict)`` sees every event as it arrives (progress for a UI, artifacts).
    """
    exe = backend_python(python)
    env = dict(os.environ)
    env["PYTHONPATH"] = EXTENSION_ROOT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.setdefault("PYTHONUNBUFFERED", "1")
    proc = subprocess.Popen([exe, "-m", "backend", *map(str, args)], cwd=cwd or EXTENSION_ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    done, error = None, None
    try:
        for line in proc.stdout:
            line = line.strip()
            if not line:
                continue
            try:
                ev = json.loads(line)
            except json.JSONDecodeError:
                continue  # not an event (a library printing to stdout): ignore rather than fail the job
            if on_event is not None:
                on_event(ev)
            if ev.get("event") == "done":
                done = ev
            elif ev.get("event") == "error":
                error = ev
        stderr = proc.stderr.read()
        code = proc.wait(timeout=timeout)
    except BaseException:
        proc.kill()
        proc.wait()
        raise
    if error is not None or code != 0 or done is None:
        if error is not None:
            raise BackendError(error.get("message", "backend error"), error.get("hint"), code, stderr)
        tail = stderr.strip().splitlines()[-1:] or ["no output"]
        raise BackendError(f"backend exited with code {code}: {tail[0]}", exit_code=code, log=stderr)
    return done
