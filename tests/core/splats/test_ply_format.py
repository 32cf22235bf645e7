"""core.splats.ply_format: the PLY header (where it ends, CRLF, its limits, what is refused, naming the line) and element
counts the file cannot hold (issue 14), through the Gaussian readers."""

import time

import numpy as np
import pytest

from tests.core.splats import splat_fixtures as F
from scpainter_blender.core import errors
from scpainter_blender.core.splats import ply_format, gaussians as splats, inria as splats_inria, reader as splats_io


def _with_header_lines(data: bytes, before_elements=(), before_end=()) -> bytes:
    """``data`` (a PLY written by write_ply) with extra header lines after the format line and before end_header."""
    head, body = data.split(b"\nend_header\n", 1)
    lines = head.split(b"\n")
    lines[2:2] = list(before_elements)
    return b"\n".join(lines + list(before_end)) + b"\nend_header\n" + body


@pytest.mark.parametrize("where", ["before_elements", "before_end"])
@pytest.mark.parametrize("line", [b"comment made by the end_header tool", b"obj_info end_header", b"comment end_header",
                                  b"comment \xe2\x9c\x93 caf\xc3\xa9 end_header"])
def test_comment_containing_end_header_does_not_shift_the_data(tmp_path, where, line):
    """The header ends at the first line that is only ``end_header``: a comment holding the words once ended it
    early (no elements) or, placed after the properties, silently shifted every value by 11 bytes."""
    ply = F.random_ply(N=20, degree=1)
    splats_inria.write_ply(tmp_path / "plain.ply", ply)
    data = _with_header_lines((tmp_path / "plain.ply").read_bytes(), **{where: [line]})
    (tmp_path / "commented.ply").write_bytes(data)
    back = splats_io.read_ply(tmp_path / "commented.ply")
    F.assert_raw_equal(ply, back)
    g, want = splats_io.load(tmp_path / "commented.ply"), splats.decode(ply)
    assert np.array_equal(g.means, want.means) and np.array_equal(g.sh, want.sh)
    assert np.array_equal(g.scales, want.scales) and np.array_equal(g.quats, want.quats)


def test_crlf_header_and_spaces_around_end_header(tmp_path):
    ply = F.random_ply(N=7, degree=0)
    splats_inria.write_ply(tmp_path / "lf.ply", ply)
    head, body = (tmp_path / "lf.ply").read_bytes().split(b"end_header\n", 1)
    (tmp_path / "crlf.ply").write_bytes(head.replace(b"\n", b"\r\n") + b"end_header\r\n" + body)
    F.assert_raw_equal(ply, splats_io.read_ply(tmp_path / "crlf.ply"))
    (tmp_path / "spaces.ply").write_bytes(head + b"end_header  \n" + body)
    F.assert_raw_equal(ply, splats_io.read_ply(tmp_path / "spaces.ply"))


def test_header_problems_are_clean_errors(tmp_path):
    ply = F.random_ply(N=4, degree=0, extras=False)
    splats_inria.write_ply(tmp_path / "ok.ply", ply)
    data = (tmp_path / "ok.ply").read_bytes()
    head, body = data.split(b"end_header\n", 1)

    def err(name, raw, match):
        (tmp_path / name).write_bytes(raw)
        with pytest.raises(splats.SplatsError, match=match) as e:
            splats_io.read(tmp_path / name)
        assert isinstance(e.value, errors.InputError) and name in str(e.value)
        return e.value

    err("glued.ply", head + b"end_header", "ends without a newline after 'end_header'")
    err("noend.ply", head, "no 'end_header' line: the file is truncated")
    err("long.ply", head + b"comment " + b"x" * ply_format.MAX_HEADER + b"\nend_header\n",
        "no 'end_header' line in the first")
    err("lines.ply", head + b"\n" * (ply_format.MAX_HEADER_LINES + 5) + b"end_header\n" + body, "more than 4096 lines")
    e = err("utf8.ply", head.replace(b"property float opacity", b"property float opacit\xc3\xa9") + b"end_header\n"
            + body, r"header line \d+: is not ASCII text")
    assert e.field.startswith("header line ") and not e.message.startswith("header line")
    e = err("element.ply", head.replace(b"element vertex 4", b"element vertex -4") + b"end_header\n" + body,
            r"header line 3: malformed element line")
    assert e.field == "header line 3"
    err("list.ply", head.replace(b"element vertex 4", b"element junk 1\nproperty list uchar\nelement vertex 4")
        + b"end_header\n" + body, "malformed list property")
    err("magic.ply", b"plyx" + data[3:], "its first line is not 'ply'")
    e = err("missing.ply", head.replace(b"property float rot_3\n", b"") + b"end_header\n" + body,
            r"missing required properties \['rot_3'\]")
    assert e.field == "rot_3"
    comment_utf8 = head.replace(b"format", b"comment caf\xc3\xa9 \xff\nformat") + b"end_header\n" + body
    (tmp_path / "comment.ply").write_bytes(comment_utf8)  # free text: any bytes, never parsed
    F.assert_raw_equal(ply, splats_io.read(tmp_path / "comment.ply"))


@pytest.mark.parametrize("count", ["999999999999999", "2147483648", "5"])
def test_element_counts_beyond_the_file_are_refused_before_allocation(tmp_path, count):
    splats_inria.write_ply(tmp_path / "ok.ply", F.random_ply(N=4, degree=0, extras=False))
    data = (tmp_path / "ok.ply").read_bytes()
    cases = {"vertex.ply": data.replace(b"element vertex 4", b"element vertex " + count.encode()),
             "before.ply": data.replace(b"element vertex 4", b"element junk " + count.encode()
                                        + b"\nproperty double a\nproperty double b\nelement vertex 4")}
    for name, raw in cases.items():
        (tmp_path / name).write_bytes(raw)
        t = time.process_time()   # CPU: an allocation would cost it, a busy machine does not
        with pytest.raises(splats.SplatsError, match=r"truncated: the header promises \d+ Gaussians .* but the file "
                                                     r"has \d+ bytes") as e:
            splats_io.read(tmp_path / name)
        assert time.process_time() - t < 0.5 and e.value.field == "vertex"
