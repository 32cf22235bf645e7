"""``bench/device_all.sh`` cannot rot: every command line it runs on the device machine, and every one of its CPU dry
run, is accepted by that bench's own argument parser as the bench is now (a renamed or dropped option fails here,
not on a GPU minutes into a lease); and the dry run's machinery (per-part timeout, the JUnit XML turned into
gpu_tests.json, summary.json) runs for real on its cheapest part. Each bench's dry-run size itself runs in that
bench's own smoke test."""

import argparse
import json
import os
import shlex
import subprocess

import pytest

from bench_support import ROOT, load_bench


class _Parsed(Exception):
    """Raised in place of running a bench once its parser accepted the command line."""


def _lines(*flags) -> dict:
    r = subprocess.run(["bash", os.path.join(ROOT, "bench", "device_all.sh"), *flags, "--print"], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return {name: shlex.split(cmd) for name, cmd in (line.split("\t") for line in r.stdout.splitlines())}


@pytest.mark.parametrize("flags", [(), ("--dry-run",)], ids=["device-machine", "dry-run"])
def test_every_command_line_parses_with_its_bench(flags, monkeypatch):
    lines = _lines(*flags)
    assert list(lines) == ["generate", "render", "train", "gpu_tests"]
    original = argparse.ArgumentParser.parse_args

    def parse_then_stop(self, args=None, namespace=None):
        raise _Parsed(original(self, args, namespace))

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
    for name, argv in lines.items():
        if argv[1:3] == ["-m", "pytest"]:
            assert "-m" in argv[3:] and argv[argv.index("-m", 3) + 1] == "gpu"
            paths = [a for a in argv[3:] if a.startswith("tests/")]
            assert "tests/backend/render/test_gaussians.py" in paths, argv    # every file that marks a test gpu
            assert all(os.path.isfile(os.path.join(ROOT, p)) for p in paths), argv
            continue
        script = argv[1]
        assert script.startswith("bench/") and script.endswith(".py"), argv
        with pytest.raises(_Parsed) as parsed:
            try:
                load_bench(os.path.basename(script)[:-3]).main(argv[2:])
            except SystemExit as e:   # argparse's error: the option the line gives is not the bench's
                pytest.fail(f"{name}: {script} refuses {argv[2:]} (exit {e.code})")
        args = vars(parsed.value.args[0])
        assert args.get("out") == "/tmp/device_all", (name, args)
        if flags:
            assert args.get("smoke") is True, name
        else:
            assert "cuda" in (args.get("device"), *(args.get("devices") or ())), name


def test_the_dry_run_writes_each_parts_json_and_the_summary(tmp_path):
    env = {**os.environ, "OUT": str(tmp_path), "DEVICE_ALL_PARTS": "gpu_tests",
           "GPU_TESTS": "tests/backend/render/test_gaussians.py"}
    r = subprocess.run(["bash", os.path.join(ROOT, "bench", "device_all.sh"), "--dry-run"], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["mode"] == "dry" and summary["ok"] and summary["total_s"] >= 0
    part = summary["parts"]["gpu_tests"]
    assert part["status"] == "ok" and part["exit_code"] == 0 and part["json"] == ["gpu_tests.json"]
    tests = json.loads((tmp_path / "gpu_tests.json").read_text())
    assert tests["failed"] == 0 and tests["passed"] + tests["skipped"] > 10   # skipped here: no CUDA
    assert "== gpu_tests: ok" in (tmp_path / "device_all.log").read_text()
