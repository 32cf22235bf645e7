"""One error type for bad input (issue 15): ``python -m backend`` exits 2 only for an ``InputError`` (its error event
names file and field); any other exception, a plain ValueError included, is a bug: exit 1, its traceback on
standard error and in the command's ``backend.log``, which the error event names. Runs ``main`` in-process."""

import json
import os

import pytest

from backend import events
from backend.__main__ import main
from backend.render import frames as fr
from scpainter_blender.core import errors
from tests_support import run_backend_here, small_job


def run(*args):
    """(exit code, events, standard error) of ``python -m backend *args`` run in this process."""
    return run_backend_here(*args)


def broken_job(folder, **top_level):
    """``small_job`` with top-level values the validation refuses, written as text (no validating writer)."""
    path = small_job(folder)
    with open(path, encoding="utf-8") as f:
        job = json.load(f)
    job.update(top_level)
    with open(path, "w", encoding="utf-8") as f:
        json.dump(job, f)
    return path


def _shape_bug(*args, **kwargs):
    raise ValueError("shape bug: (12, 16) and (16, 12)")


def test_a_value_error_inside_render_is_a_bug_with_its_traceback_in_backend_log(tmp_path, monkeypatch):
    job = small_job(tmp_path / "job")
    monkeypatch.setattr(fr, "render_frame", _shape_bug)  # deep inside the command, after backend.log was opened
    code, ev, err = run("render", job, "--device", "cpu")
    log = str(tmp_path / "job" / "out" / "backend.log")
    assert code == events.EXIT_FAILED
    error = ev[-1]
    assert error["event"] == "error" and error["message"] == "ValueError: shape bug: (12, 16) and (16, 12)"
    assert "file" not in error and "field" not in error            # not reported as bad input
    assert "not a problem with the input" in error["hint"] and "check the input" not in error["hint"]
    assert error["log"] == log and log in error["hint"]
    text = open(log, encoding="utf-8").read()
    for where in (text, err):  # the whole traceback, down to the raising function, in both places
        assert "Traceback (most recent call last)" in where and "in _shape_bug" in where and "in _render" in where
        assert "ValueError: shape bug" in where
    assert text.index("render ") < text.index("Traceback")          # appended after the run's own lines


def test_a_bug_without_an_output_folder_goes_to_standard_error(tmp_path, monkeypatch):
    from backend.mesh import asset as mesh_asset

    monkeypatch.setattr(mesh_asset, "convert", _shape_bug)
    code, ev, err = run("mesh-asset", tmp_path / "car.glb", "--out", tmp_path / "car.ply")
    assert code == 1 and ev[-1]["log"] is None and "file" not in ev[-1]
    assert "Traceback" in err and "ValueError: shape bug" in err and "standard error" in ev[-1]["hint"]


def test_bad_input_exits_2_naming_file_and_field(tmp_path):
    job = broken_job(tmp_path / "job", resolution=[16, -12])
    code, ev, err = run("render", job, "--device", "cpu")
    assert code == events.EXIT_BAD_INPUT and "Traceback" not in err
    assert ev[-1]["event"] == "error" and ev[-1]["file"] == job and ev[-1]["field"].startswith("resolution")
    assert "log" not in ev[-1]
    code, ev, err = run("batch", "--device", "cpu")                 # an argument: file "(command line)"
    assert code == 2 and ev[-1]["file"] == errors.COMMAND_LINE and ev[-1]["field"] == "jobs"
    code, ev, _ = run("mesh-asset", tmp_path / "car.glb", "--out", tmp_path / "car.ply", "--count", 0)
    assert code == 2 and ev[-1]["file"] == errors.COMMAND_LINE and ev[-1]["field"] == "--count"


def test_device_cuda_without_a_gpu_is_an_argument_error(tmp_path):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA GPU")
    code, ev, err = run("render", small_job(tmp_path / "job"), "--device", "cuda")
    assert code == 2 and "Traceback" not in err
    assert ev[-1]["file"] == "(command line)" and ev[-1]["field"] == "--device" and "--device cpu" in ev[-1]["hint"]


def test_argparse_errors_exit_2_with_usage_and_an_error_event(capsys):
    with pytest.raises(SystemExit) as e:
        main(["render", "job.json", "--device", "gpu"])
    out, err = capsys.readouterr()
    assert e.value.code == 2 and "invalid choice" in err and "usage:" in err
    (ev,) = [json.loads(line) for line in out.splitlines()]     # standard output: the event, nothing else
    assert ev["event"] == "error" and ev["file"] == errors.COMMAND_LINE and ev["field"] == "--device"
    assert "invalid choice: 'gpu'" in ev["message"] and "--help" in ev["hint"]
    with pytest.raises(SystemExit) as e:
        main(["batch", "--inpaint", "telea", "--bogus"])
    ev = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert e.value.code == 2 and ev["field"] == "(arguments)" and "--bogus" in ev["message"]
    with pytest.raises(SystemExit) as e:
        main(["mesh-asset"])
    ev = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert e.value.code == 2 and ev["field"] == "mesh, --out"


def test_batch_records_a_bug_with_its_jobs_log_and_bad_input_with_file_and_field(tmp_path, monkeypatch):
    good = small_job(tmp_path / "good")
    bad = broken_job(tmp_path / "bad", resolution=[0, 12])
    monkeypatch.setattr(fr, "render_frame", _shape_bug)
    code, ev, err = run("batch", good, bad, "--device", "cpu", "--allow-outside")
    assert code == 1
    items = {os.path.basename(os.path.dirname(r["job"])): r for r in ev[-1]["items"]}
    assert items["good"]["status"] == "failed" and items["good"]["error"].startswith("ValueError: shape bug")
    log = str(tmp_path / "good" / "out" / "backend.log")
    assert items["good"]["log"] == log and "Traceback" in open(log, encoding="utf-8").read() and "Traceback" in err
    assert "file" not in items["good"]
    assert items["bad"]["status"] == "failed" and items["bad"]["file"] == bad
    assert items["bad"]["field"].startswith("resolution")
    assert "log" not in items["bad"]


def test_log_scope_marks_an_exception_with_the_innermost_open_log(tmp_path):
    outer, inner = str(tmp_path / "outer.log"), str(tmp_path / "inner.log")
    with pytest.raises(ValueError) as e:
        with events.log_scope():
            events.FileLog(outer)
            with events.log_scope():
                events.FileLog(inner)
                raise ValueError("in the inner run")
    assert events.log_of(e.value).path == inner
    with pytest.raises(ValueError) as e:  # raised after the inner run ended: its log is no longer the bug's
        with events.log_scope():
            events.FileLog(outer)
            with events.log_scope():
                events.FileLog(inner)
            raise ValueError("after the inner run")
    assert events.log_of(e.value).path == outer
    assert events.report_bug(e.value) == outer and "after the inner run" in open(outer, encoding="utf-8").read()
    with pytest.raises(ValueError) as e:
        with events.log_scope():
            raise ValueError("no log open")
    assert events.log_of(e.value) is None and events.report_bug(e.value) is None


def test_long_non_utf8_and_nul_names_are_refused_by_name(tmp_path):
    """Issue 42: a name too long for the file system, a path that is not UTF-8 and a NUL byte in a batch list gave
    tracebacks ("an internal error, please report it"); each is now bad input naming the path, option or line."""
    job = small_job(tmp_path / "a")
    long_out = tmp_path / ("e" * 300)                           # 300 bytes: beyond NAME_MAX (255)
    code, evs, _ = run("export", job, "--format", "kitti", "--out", long_out, "--device", "cpu")
    assert code == events.EXIT_BAD_INPUT and evs[-1]["file"] == str(long_out), evs[-1]
    assert "too long" in evs[-1]["message"] and not os.path.exists(tmp_path / ("e" * 100))
    assert not [n for n in os.listdir(tmp_path) if n.endswith(".tmp")]   # the export's temporary folder is gone
    odd = os.fsdecode(os.fsencode(str(tmp_path)) + b"/caf\xe9")  # Latin-1 bytes: Python holds \udce9
    code, evs, _ = run("render", small_job(odd), "--device", "cpu")
    assert code == events.EXIT_BAD_INPUT and evs[-1]["field"] == "job" and "UTF-8" in evs[-1]["message"], evs[-1]
    json.dumps(evs[-1])                                          # the event holds the name, escaped
    listed = tmp_path / "list.txt"
    listed.write_bytes(b"a/job.json\nx\x00y/job.json\n")
    code, evs, _ = run("batch", "--list", listed, "--command", "render", "--device", "cpu")
    assert code == events.EXIT_BAD_INPUT and evs[-1]["file"] == str(listed) and evs[-1]["field"] == "line 2"



@pytest.mark.parametrize("command", [("vary", "{job}", "--out"), ("export", "{job}", "--format", "kitti", "--out"),
                                     ("render", "{job}", "--data-root")])
def test_a_nul_byte_in_a_path_option_is_refused_naming_it(tmp_path, command):
    """Issue 42 (fuzz names 7): `vary --out` with a NUL byte gave a traceback (ValueError: embedded null byte).
    The one check of every command's options (``check_names``) refuses it naming the option; nothing is made."""
    job = small_job(tmp_path / "a")
    args = [a.format(job=job) for a in command] + [str(tmp_path / "dir\x00x")]
    code, evs, err = run(*args, "--device", "cpu") if command[0] != "vary" else run(*args)
    assert code == events.EXIT_BAD_INPUT and "Traceback" not in err, (evs, err)
    assert evs[-1]["field"] == command[-1] and "NUL byte" in evs[-1]["message"], evs[-1]
    assert sorted(os.listdir(tmp_path / "a")) == ["car.ply", "job.json", "predictions.npz"]


def test_check_refuses_an_output_folder_name_the_run_could_not_make(tmp_path):
    """Issue 42 (h4's leftover): ``render --check`` passed a job whose ``output_dir`` is longer than the file system
    allows, and the run then failed; now the check refuses it naming ``output_dir``, and makes nothing."""
    job = small_job(tmp_path / "a", output_dir="o" * 300)
    code, evs, _ = run("render", job, "--check", "--device", "cpu")
    assert code == events.EXIT_BAD_INPUT and evs[-1]["field"] == "output_dir", evs[-1]
    assert "longer than its file system allows" in evs[-1]["message"]
    assert sorted(os.listdir(tmp_path / "a")) == ["car.ply", "job.json", "predictions.npz"]


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MB tmpfs (root only; skipped elsewhere), unmounted afterwards."""
    import subprocess

    folder = tmp_path / "disk"
    folder.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    made = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(folder)], capture_output=True,
                          text=True)
    if made.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {made.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True)


def test_a_full_disk_is_an_error_naming_the_folder_with_nothing_half_written(small_disk):
    """Issue 42: a full disk was "an internal error, please report it". Now exit 1 with an error event naming the
    folder (``errors.DiskFullError``, no traceback), no temporary left, the finished frames whole; the same render
    after space is freed finishes. Filled to leave nothing (the lock fails), then a few kilobytes (a frame
    fails)."""
    from backend.render import channels

    job = small_job(small_disk / "a")
    out = small_disk / "a" / "out"
    for leave in (0, 8000):
        st = os.statvfs(small_disk)
        with open(small_disk / "filler", "ab") as f:
            f.write(b"\0" * max(0, st.f_bavail * st.f_frsize - leave))
        code, evs, err = run("render", job, "--device", "cpu")
        assert code == events.EXIT_FAILED and evs[-1]["event"] == "error", evs
        assert "no space is left" in evs[-1]["message"] and "please report" not in evs[-1]["hint"]
        assert evs[-1]["folder"] and evs[-1]["folder"].startswith(str(out)), evs[-1]
        assert "Traceback" not in err
        for root, _, names in os.walk(small_disk):
            assert not [n for n in names if n.endswith(".tmp") or n.startswith(".scpainter.lock")], (root, names)
            for n in names:
                if n.endswith(".exr"):
                    channels.read(os.path.join(root, n))        # every frame written is whole
        os.remove(small_disk / "filler")
    code, evs, err = run("render", job, "--device", "cpu")
    assert code == events.EXIT_OK, evs


def test_a_warning_goes_to_the_output_folders_log_where_blender_says_to_look(tmp_path, capsys):
    """Blender's report of a run with warnings quotes the first and says "see the output folder's log" for the
    rest (``runs.camera_run.with_warnings``): every ``warning`` event is in that ``backend.log`` too."""
    with events.log_scope():
        events.FileLog(str(tmp_path / "backend.log"))    # the command's log, as render opens it
        events.warning("frame 3: coverage 12 %", "low_coverage", frame=3)
    assert "warning: frame 3: coverage 12 %" in (tmp_path / "backend.log").read_text()
    assert capsys.readouterr().err == "warning: frame 3: coverage 12 %\n"   # standard error as before
