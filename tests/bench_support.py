"""What the bench smoke tests (tests/bench/) share: a bench script loaded in this process (``bench/<name>.py``, its ``main``)."""

import importlib.util
import json
import math
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def load_bench(name: str):
    """``bench/<name>.py`` imported as module ``bench_<name>`` (once per session; bench/ on sys.path for the
    helpers it imports, as when it runs as a script)."""
    key = f"bench_{name}"
    if key not in sys.modules:
        if os.path.join(ROOT, "bench") not in sys.path:
            sys.path.insert(0, os.path.join(ROOT, "bench"))
        spec = importlib.util.spec_from_file_location(key, os.path.join(ROOT, "bench", f"{name}.py"))
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module
        spec.loader.exec_module(module)
    return sys.modules[key]


def run_smoke(name: str, tmp_path, *extra) -> dict:
    """``bench/<name>.py --smoke --out tmp_path [extra]`` in this process; its JSON (``<name>.json`` there)."""
    main = load_bench(name).main
    code = main(["--smoke", "--out", str(tmp_path), *extra])
    assert code in (None, 0), f"bench/{name}.py --smoke exited {code}"
    with open(os.path.join(tmp_path, f"{name}.json"), encoding="utf-8") as f:
        return json.load(f)


def finite(*values) -> bool:
    """All ``values`` are real numbers (not bool, not None) and finite."""
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)


def run_smoke_process(name: str, tmp_path, *extra, timeout: int = 600):
    """``bench/<name>.py --smoke [extra] --out tmp_path`` in a process of its own (a bench that must own its
    process: bpy's user folder set before import, its own Ray or signal handling); the finished
    ``subprocess.CompletedProcess`` (text), after asserting it exited 0."""
    import subprocess

    r = subprocess.run([sys.executable, os.path.join(ROOT, "bench", f"{name}.py"), "--smoke", *extra, "--out",
                        str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"bench/{name}.py --smoke exited {r.returncode}:\n{r.stderr[-3000:]}"
    return r
