"""List files whose lines would change meaning (issue 42): a base job whose folder name held a newline put a
``data-root: /`` line and an extra job into variants.txt, and batch ran that job with / trusted. The writer refuses
such a value, the reader refuses a line holding a control character (``core/batch_items.py``)."""

import os

import pytest

from scpainter_blender.core import batch_items as batch, errors


@pytest.mark.parametrize("value", ["/data/x\ndata-root: /", "/data/x\r", "/data/\x00x", "/data/x\x1c/y",
                                   "/data/x\u2028y", "/data/\x1b[2Jx", " /data/x", "/data/x ", "# note",
                                   "data-root: /"])
def test_the_writer_refuses_a_value_that_would_change_the_list(tmp_path, value):
    path = tmp_path / "variants.txt"
    with pytest.raises(errors.InputError) as e:
        batch.write_job_list(str(path), [value], ["v0000/job.json"])
    assert e.value.path == str(path) and e.value.field == "data-root"
    with pytest.raises(errors.InputError):
        batch.write_job_list(str(path), ["."], [value])
    assert not path.exists()


def test_what_the_writer_writes_reads_back_the_same(tmp_path):
    (tmp_path / "rec ording").mkdir()
    path = tmp_path / "variants.txt"
    batch.write_job_list(str(path), [".", str(tmp_path / "rec ording")], ["v0000/job.json", "v0002/job.json"],
                         comment="made by a test")
    got = batch.read_job_list(str(path))
    assert got.data_roots == (str(tmp_path), str(tmp_path / "rec ording"))
    assert got.paths == [str(tmp_path / "v0000/job.json"), str(tmp_path / "v0002/job.json")]


@pytest.mark.parametrize("line", ["v0000/job\x0b.json", "v0000/job\x0c.json", "v0000/\x1cjob.json",
                                  "v0000/job\u2028.json", "v0000/\x00job.json", "v0000/job\x85.json",
                                  "v0000/\x1b]0;x\x07job.json"])
def test_the_reader_refuses_a_line_with_a_control_character(tmp_path, line):
    """str.splitlines split at \\x0b, \\x0c, \\x1c-\\x1e, \\x85, \\u2028: one line read as two (another job); a NUL
    gave a traceback. Lines now end at a newline alone, and a control character is refused naming the line."""
    (tmp_path / "data").mkdir()
    path = tmp_path / "list.txt"
    path.write_text(f"data-root: data\n{line}\n", encoding="utf-8")
    with pytest.raises(errors.InputError) as e:
        batch.read_job_list(str(path))
    assert e.value.path == str(path) and e.value.field == "line 2" and "control character" in e.value.message
    path.write_text("data-root: data\r\nv0000/job.json\r\n", encoding="utf-8")   # CRLF is still a line end
    assert batch.read_job_list(str(path)).paths == [os.path.join(str(tmp_path), "v0000/job.json")]
