"""core.outputs: atomic writes (nothing half-written survives, a planted link is replaced, not followed), log
appends never through a link, listed removals that stay in their folder (issue 14)."""

import os

import pytest

from scpainter_blender.core import errors, files, outputs


def test_atomic_write_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "out.json"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with outputs.atomic_write(target, "w") as f:
            f.write("half")
            raise RuntimeError("stop")
    assert target.read_text() == "old" and sorted(os.listdir(tmp_path)) == ["out.json"]
    with pytest.raises(ValueError):  # NaN is refused before anything is written
        outputs.write_json(tmp_path / "nan.json", {"a": float("nan")})
    assert sorted(os.listdir(tmp_path)) == ["out.json"]
    with outputs.atomic_path(tmp_path / "video.mp4") as tmp:
        assert os.path.dirname(tmp) == str(tmp_path) and os.path.exists(tmp)
        with open(tmp, "wb") as f:
            f.write(b"data")
    assert (tmp_path / "video.mp4").read_bytes() == b"data" and len(os.listdir(tmp_path)) == 2
    outputs.write_json(tmp_path / ("x" * 250 + ".json"), [1])  # a long name still leaves room for the temporary one
    assert files.read_json(tmp_path / ("x" * 250 + ".json")) == [1]


def test_a_folder_where_an_output_file_goes_is_an_input_error_naming_it(tmp_path):
    """Issue 30: a folder in a frame's place once escaped as IsADirectoryError from the rename."""
    (tmp_path / "frame.exr").mkdir()
    with pytest.raises(errors.InputError) as e:
        outputs.write_json(tmp_path / "frame.exr", [1])
    assert e.value.path == str(tmp_path / "frame.exr") and "folder" in e.value.message and "remove" in e.value.hint
    assert sorted(os.listdir(tmp_path)) == ["frame.exr"]  # the temporary file is gone


def test_atomic_write_replaces_a_planted_link(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "out"
    out.mkdir()
    (out / "result.json").symlink_to(victim)
    outputs.write_json(out / "result.json", {"ok": True})
    assert victim.read_text() == "precious"
    assert not (out / "result.json").is_symlink() and files.read_json(out / "result.json") == {"ok": True}
    mask = os.umask(0o022)
    os.umask(mask)
    assert (out / "result.json").stat().st_mode & 0o777 == 0o666 & ~mask


def test_append_text_refuses_links_and_fifos(tmp_path):
    log = tmp_path / "run.log"
    outputs.append_text(log, "a\n")
    outputs.append_text(log, "b\n")
    assert log.read_text() == "a\nb\n"
    (tmp_path / "link.log").symlink_to(tmp_path / "elsewhere.log")
    with pytest.raises(errors.InputError, match="symbolic link"):
        outputs.append_text(tmp_path / "link.log", "x")
    assert not (tmp_path / "elsewhere.log").exists()
    if hasattr(os, "mkfifo"):
        os.mkfifo(tmp_path / "fifo.log")
        with pytest.raises(errors.InputError, match="not a regular file"):
            outputs.append_text(tmp_path / "fifo.log", "x")
    (tmp_path / "dir.log").mkdir()
    with pytest.raises(errors.InputError, match="not a regular file"):
        outputs.append_text(tmp_path / "dir.log", "x")


def test_remove_listed_ignores_names_with_separators(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    for name in ("a.png", "b.png", "keep.png"):
        (folder / name).write_text("x")
    (tmp_path / "outside.png").write_text("x")
    (folder / "sub").mkdir()
    (folder / "sub" / "c.png").write_text("x")
    (folder / "link.png").symlink_to(tmp_path / "outside.png")
    names = ["a.png", "b.png", "../outside.png", "sub/c.png", str(tmp_path / "outside.png"), "..", ".", "", None, 3,
             "nul\0.png", "link.png", "missing.png", "sub"]
    assert outputs.remove_listed(folder, names) == 3
    assert sorted(os.listdir(folder)) == ["keep.png", "sub"]
    assert (tmp_path / "outside.png").exists() and (folder / "sub" / "c.png").exists()


def test_atomic_folder_appears_whole_or_not_at_all(tmp_path):
    target = tmp_path / "ckpt"
    with pytest.raises(RuntimeError):
        with outputs.atomic_folder(target) as tmp:
            assert os.path.dirname(tmp) == str(tmp_path) and os.listdir(tmp) == []
            (tmp_path / os.path.basename(tmp) / "half.bin").write_bytes(b"x")
            raise RuntimeError("stop")
    assert os.listdir(tmp_path) == []  # neither the target nor the temporary folder
    with outputs.atomic_folder(target) as tmp:
        os.makedirs(os.path.join(tmp, "unet"))
        (tmp_path / os.path.basename(tmp) / "unet" / "w.bin").write_bytes(b"w")
    assert os.listdir(tmp_path) == ["ckpt"] and (target / "unet" / "w.bin").read_bytes() == b"w"
    with pytest.raises(OSError):  # a finished folder is not replaced ...
        with outputs.atomic_folder(target) as tmp:
            (tmp_path / os.path.basename(tmp) / "other").write_bytes(b"o")
    with outputs.atomic_folder(target, keep_existing=True) as tmp:  # ... unless the caller keeps theirs
        (tmp_path / os.path.basename(tmp) / "other").write_bytes(b"o")
    assert os.listdir(tmp_path) == ["ckpt"] and os.listdir(target) == ["unet"]


def test_folders_are_built_whole_only_by_atomic_folder():
    """No hand-rolled copy of atomic_folder (a temporary folder renamed into place) in shipped code."""
    from tests_support import tracked_sources

    copies = []
    for f, text in tracked_sources(exclude=("bench/", "scpainter_blender/core/outputs.py")).items():
        if "mkdtemp(" in text and "rename(" in text:
            copies.append(f)
    assert copies == []


def test_a_log_line_naming_a_non_utf8_file_is_written_escaped(tmp_path):
    """A file name whose bytes are not UTF-8 (Python holds them as surrogates) in a log line: written as \\udce9,
    the log stays UTF-8 text (it raised UnicodeEncodeError, a traceback, issue 42)."""
    log = tmp_path / "backend.log"
    outputs.append_text(log, "render /data/caf\udce9/job.json\n")
    assert log.read_text(encoding="utf-8") == "render /data/caf\\udce9/job.json\n"
