"""core.files: readers that cannot be made to traceback or hang (issue 14): regular files only, JSON within limits
and named by field, npz members checked before a byte is allocated; InputError and ArgumentError. Writing is
tested in test_outputs.py, the output lock in test_locking.py."""

import io
import json
import os
import threading
import time
import zipfile

import numpy as np
import pytest

from scpainter_blender.core import errors as E
from scpainter_blender.core import files as F


def npy_bytes(arr) -> bytes:
    b = io.BytesIO()
    np.save(b, arr)
    return b.getvalue()


def write_zip(path, members: dict, compression=zipfile.ZIP_STORED):
    with zipfile.ZipFile(path, "w", compression) as z:
        for name, data in members.items():
            z.writestr(name, data)
    return path


def refused(fn, *args, match=None, **kwargs) -> E.InputError:
    with pytest.raises(E.InputError, match=match) as e:
        fn(*args, **kwargs)
    return e.value


# -- regular files -------------------------------------------------------------------------------------------------

@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_fifo_is_refused_without_blocking(tmp_path):
    """A plain open() of a FIFO waits for a writer forever; every reader here must refuse it at once."""
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    result = {}

    def attempt():
        t = time.perf_counter()
        for name, call in (("open_regular", lambda: F.open_regular(fifo)),
                           ("check_regular", lambda: F.check_regular(fifo)), ("read_json", lambda: F.read_json(fifo)),
                           ("read_npz", lambda: F.read_npz(fifo, ["a"])), ("npz_shapes", lambda: F.npz_shapes(fifo))):
            try:
                call()
                result[name] = "accepted"
            except E.InputError as e:
                result[name] = e
        result["seconds"] = time.perf_counter() - t

    worker = threading.Thread(target=attempt, daemon=True)  # a daemon: a regression hangs this test, not pytest
    worker.start()
    worker.join(5.0)
    if worker.is_alive():  # unblock the reader so the thread can end, then fail
        with open(fifo, "wb"):
            pass
        pytest.fail("a reader blocked on a FIFO")
    assert result.pop("seconds") < 1.0
    for name, e in result.items():
        assert isinstance(e, E.InputError), name
        assert "FIFO" in str(e) and "pipe.json" in str(e) and e.field == "(file)", (name, str(e))


def test_directory_device_and_missing_file_are_refused(tmp_path):
    e = refused(F.open_regular, tmp_path, match="is a directory, not a regular file")
    assert e.path == str(tmp_path) and e.field == "(file)"
    refused(F.read_json, tmp_path, match="directory")
    refused(F.read_npz, tmp_path, ["a"], match="directory")
    if os.path.exists("/dev/zero"):  # would otherwise be read for ever (read_json reads up to its limit)
        refused(F.read_json, "/dev/zero", match="character device")
        refused(F.check_regular, "/dev/null", match="character device")
    refused(F.open_regular, tmp_path / "missing.json", match="missing.json: \\(file\\): not found")
    (tmp_path / "ok.bin").write_bytes(b"abc")
    assert F.check_regular(tmp_path / "ok.bin") == 3
    with F.open_regular(tmp_path / "ok.bin") as f:
        assert f.read() == b"abc"


def test_the_error_callback_decides_the_class(tmp_path):
    class MyError(ValueError):
        def __init__(self, path, field, message):
            super().__init__(f"{field}|{message}")

    with pytest.raises(MyError, match=r"\(file\)\|is a directory"):
        F.open_regular(tmp_path, MyError)
    with pytest.raises(MyError, match="directory"):
        F.read_json(tmp_path, MyError)


# -- JSON ----------------------------------------------------------------------------------------------------------

def test_read_json_accepts_ordinary_files(tmp_path):
    value = {"schema": "x/1", "frames": [{"K": [[1.5, 0, 2], [0, 1, 3], [0, 0, 1]]}], "n": -12,
             "s": "é ☃ \U0001F600"}
    (tmp_path / "a.json").write_text(json.dumps(value, ensure_ascii=False), encoding="utf-8")
    assert F.read_json(tmp_path / "a.json") == value
    (tmp_path / "bom.json").write_bytes(b"\xef\xbb\xbf" + json.dumps(value).encode())
    assert F.read_json(tmp_path / "bom.json") == value
    (tmp_path / "pair.json").write_text('{"s": "\\ud83d\\ude00"}')  # an escaped surrogate pair is one character
    assert F.read_json(tmp_path / "pair.json") == {"s": "\U0001F600"}


@pytest.mark.parametrize("text, field, message", [
    ('{"frames": [{"K": NaN}]}', "frames[0].K", "NaN is not a JSON number"),
    ('{"a": 1, "b": [1, 2, -Infinity]}', "b[2]", "-Infinity is not a JSON number"),
    ('{"fps": 1e999}', "fps", "out of range"),
    ('{"seed": ' + "9" * 500 + "}", "seed", "digits"),
    ('{"a": {"b": ' + "[" * 40 + "]" * 40 + "}}", "a.b" + "[0]" * 30, "nested deeper than 32 levels"),
    ("[" * 100_000 + "]" * 100_000, None, "nested deeper"),
    ('{"name": "\\udc80"}', "name", "not valid Unicode"),
    ('{"a": 1,}', "(file)", "not valid JSON: .* at line 1 column 9"),
    ("", "(file)", "not valid JSON"),
])
def test_read_json_limits_name_the_field(tmp_path, text, field, message):
    p = tmp_path / "job.json"
    p.write_text(text, encoding="utf-8")
    e = refused(F.read_json, p, match=message)
    if field is not None:
        assert e.field == field, str(e)
    assert str(e).startswith("job.json: ")


def test_read_json_size_and_encoding(tmp_path):
    p = tmp_path / "big.json"
    p.write_text("[" + "0," * 600 + "0]")
    assert len(F.read_json(p)) == 601
    refused(F.read_json, p, max_bytes=1000, match="larger than")
    p.write_bytes(b'{"a": "\xff"}')
    refused(F.read_json, p, match="not UTF-8 text \\(byte 7\\)")


def test_first_problem_in_document_order(tmp_path):
    p = tmp_path / "two.json"
    p.write_text('{"a": [1, NaN], "b": Infinity}')
    assert refused(F.read_json, p).field == "a[1]"


# -- npz -----------------------------------------------------------------------------------------------------------

def test_read_npz_reads_what_np_load_reads(tmp_path):
    arrays = {"f": np.arange(12, dtype=np.float32).reshape(3, 4), "b": np.arange(6, dtype=">f8").reshape(2, 3),
              "fortran": np.asfortranarray(np.arange(6, dtype=np.int16).reshape(2, 3)), "u8": np.zeros(0, np.uint8),
              "mask": np.array([True, False]), "scalar": np.float64(2.5), "half": np.ones((2, 2), np.float16)}
    for saver, name in ((np.savez, "plain.npz"), (np.savez_compressed, "packed.npz")):
        saver(tmp_path / name, **arrays)
        got = F.read_npz(tmp_path / name, ["f", "b"], optional=["fortran", "u8", "mask", "scalar", "half", "nope"])
        assert set(got) == set(arrays)
        for k, v in arrays.items():
            assert got[k].dtype == v.dtype and got[k].shape == v.shape and np.array_equal(got[k], v), k
        assert F.npz_shapes(tmp_path / name) == {k: v.shape for k, v in arrays.items()}
        assert F.npz_shapes(tmp_path / name, ["f"]) == {"f": (3, 4)}


def test_missing_keys_are_listed(tmp_path):
    np.savez(tmp_path / "p.npz", a=np.zeros(2), b=np.zeros(2))
    e = refused(F.read_npz, tmp_path / "p.npz", ["a", "x", "y"], match=r"missing key\(s\) \['x', 'y'\]; the file has "
                                                                       r"\['a', 'b'\]")
    assert e.field == "x"


def test_member_without_npy_suffix(tmp_path):
    p = write_zip(tmp_path / "raw.npz", {"depth": npy_bytes(np.zeros(3))})
    assert refused(F.read_npz, p, ["depth"], match="stored without the .npy suffix").field == "depth"


def test_corrupt_deflate_stream(tmp_path):
    """Bytes flipped in the middle of a member's compressed data: a zlib error or a CRC mismatch, each named."""
    p = tmp_path / "c.npz"
    np.savez_compressed(p, depth=np.random.default_rng(0).random((64, 64)), other=np.zeros(3))
    data = bytearray(p.read_bytes())
    with zipfile.ZipFile(p) as z:
        info = z.getinfo("depth.npy")
    local = info.header_offset  # the local header: 30 bytes, the name (length at 26) and an extra field (at 28)
    start = local + 30 + int.from_bytes(data[local + 26:local + 28], "little") + \
        int.from_bytes(data[local + 28:local + 30], "little")
    seen = set()
    for offset in (0.2, 0.5, 0.8):
        bad = bytearray(data)
        i = start + int(offset * info.compress_size)
        bad[i:i + 4] = bytes(b ^ 0x5A for b in bad[i:i + 4])
        q = tmp_path / "bad.npz"
        q.write_bytes(bytes(bad))
        e = refused(F.read_npz, q, ["depth"])
        assert e.field == "depth" and str(e).startswith("bad.npz: depth: "), str(e)
        seen.add("corrupt" in str(e) or "broken header" in str(e))
        assert F.read_npz(q, ["other"])["other"].shape == (3,)  # the other member still reads
    assert seen == {True}


def test_broken_header(tmp_path):
    good = npy_bytes(np.zeros((2, 3), np.float32))
    cases = {
        "garbage.npz": b"\x93NUMPY\x01\x00" + b"\x10\x00" + b"{not a dict}    ",
        "keys.npz": good.replace(b"'descr'", b"'descx'"),
        "dtype.npz": good.replace(b"'<f4'", b"'zz9'"),
        "deep.npz": good.replace(b"(2, 3)", b"(" * 200 + b")" * 200),
        "negative.npz": good.replace(b"(2, 3)", b"(-2,-3)"),
        "empty.npz": b"",
        "short.npz": good[:20],
        "magic.npz": b"NOTNUMPY" + good[8:],
    }
    for name, member in cases.items():
        p = write_zip(tmp_path / name, {"a.npy": member})
        e = refused(F.read_npz, p, ["a"], match="a: is not a readable .npy array")
        assert e.field == "a" and name in str(e)
        refused(F.npz_shapes, p, match="broken header")


def test_header_claiming_more_elements_than_stored(tmp_path):
    """The shape text patched in place (same length, so the header still parses): refused before allocation."""
    p = tmp_path / "plain.npz"
    np.savez(p, depth=np.zeros((2, 3), np.float32))
    data = p.read_bytes()
    assert data.count(b"(2, 3)") == 1
    (tmp_path / "more.npz").write_bytes(data.replace(b"(2, 3)", b"(9, 3)"))
    # zipfile checks the CRC as soon as a small member is buffered, so here that fails first: a clean error too
    e = refused(F.read_npz, tmp_path / "more.npz", ["depth"], match=r"more\.npz: depth: .*(CRC|claims shape)")
    assert e.field == "depth"
    # the same member with a matching CRC: the shape's claim itself is refused
    with zipfile.ZipFile(p) as z:
        member = z.read("depth.npy").replace(b"(2, 3)", b"(9, 3)")
    write_zip(tmp_path / "more2.npz", {"depth.npy": member})
    e = refused(F.read_npz, tmp_path / "more2.npz", ["depth"],
                match=r"depth: its header claims shape \(9, 3\) \(108 bytes\) but the member holds 24 bytes")
    assert e.field == "depth"
    # a claim of petabytes (written into the header's padding, so its length stays) is refused by arithmetic alone
    member = npy_bytes(np.zeros((2, 3), np.float32))
    huge = member.replace(b"(2, 3), }" + b" " * 14, b"(99999999, 99999999), }")
    assert len(huge) == len(member) and huge != member
    p2 = write_zip(tmp_path / "peta.npz", {"depth.npy": huge})
    t = time.process_time()   # CPU: an allocation or a read would cost it, a busy machine does not
    refused(F.read_npz, p2, ["depth"], match=r"claims shape \(99999999, 99999999\) \(39,999,999,200,000,004 bytes\)")
    assert time.process_time() - t < 0.5
    assert F.npz_shapes(p2) == {"depth": (99999999, 99999999)}  # headers alone: nothing read, nothing refused


def test_zip_directory_with_impossible_sizes(tmp_path):
    """A central directory claiming a member expands 10,000-fold: refused before anything is allocated."""
    p = tmp_path / "z.npz"
    np.savez_compressed(p, a=np.zeros(1000))
    data = bytearray(p.read_bytes())
    with zipfile.ZipFile(p) as z:
        info = z.getinfo("a.npy")
    cd = data.rfind(b"PK\x01\x02")
    claimed = info.compress_size * 10_000
    data[cd + 24:cd + 28] = claimed.to_bytes(4, "little")  # uncompressed size in the central directory
    (tmp_path / "forged.npz").write_bytes(bytes(data))
    refused(F.read_npz, tmp_path / "forged.npz", ["a"], match="impossible sizes")


def test_object_string_and_complex_dtypes(tmp_path):
    np.savez(tmp_path / "o.npz", obj=np.array([None, {"a": 1}], dtype=object), s=np.array(["x"]),
             c=np.zeros(2, np.complex64), rec=np.zeros(2, [("x", "f4")]), ok=np.ones(2))
    assert refused(F.read_npz, tmp_path / "o.npz", ["obj"], match="pickles").field == "obj"
    for key in ("s", "c", "rec"):
        assert refused(F.read_npz, tmp_path / "o.npz", [key], match="not a numeric array").field == key
    assert F.read_npz(tmp_path / "o.npz", ["ok"])["ok"].tolist() == [1.0, 1.0]  # other members never touched


def test_single_npy_and_not_a_zip(tmp_path):
    np.save(tmp_path / "one.npy", np.zeros(3))
    os.replace(tmp_path / "one.npy", tmp_path / "one.npz")
    e = refused(F.read_npz, tmp_path / "one.npz", ["a"], match="is a single .npy array, expected an .npz archive")
    assert e.field == "(file)"
    refused(F.npz_shapes, tmp_path / "one.npz", match="single .npy")
    (tmp_path / "text.npz").write_text("hello")
    refused(F.read_npz, tmp_path / "text.npz", ["a"], match="not a readable .npz")
    np.savez(tmp_path / "t.npz", a=np.zeros(100))
    data = (tmp_path / "t.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    refused(F.read_npz, tmp_path / "cut.npz", ["a"], match="cut.npz")


def test_other_compressions_read_and_their_corruption_is_named(tmp_path):
    member = npy_bytes(np.arange(5000.0))
    for method in (zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA):
        p = write_zip(tmp_path / f"{method}.npz", {"a.npy": member}, method)
        assert np.array_equal(F.read_npz(p, ["a"])["a"], np.arange(5000.0))
        data = bytearray(p.read_bytes())
        data[200:210] = b"\xff" * 10
        p.write_bytes(bytes(data))
        assert refused(F.read_npz, p, ["a"]).field == "a"


def test_nul_in_a_name_and_a_socket_are_named(tmp_path):
    refused(F.open_regular, str(tmp_path / "a\0b.json"), match="NUL character")
    refused(F.check_regular, str(tmp_path / "a\0b.json"), match="NUL character")
    import socket

    if hasattr(socket, "AF_UNIX") and len(str(tmp_path / "s.sock")) < 100:
        with socket.socket(socket.AF_UNIX) as s:
            s.bind(str(tmp_path / "s.sock"))
            refused(F.open_regular, tmp_path / "s.sock", match="is a socket, not a regular file")
            refused(F.read_json, tmp_path / "s.sock", match="is a socket")


@pytest.mark.parametrize("text, value", [("3", 3), ('"x"', "x"), ("null", None), ("1e308", 1e308),
                                         ("-" + "9" * 400, -int("9" * 400)), ('{"a": "\\ud83d\\ude00"}', {"a": "😀"})])
def test_read_json_scalars_and_limits_at_the_edge(tmp_path, text, value):
    (tmp_path / "v.json").write_text(text, encoding="utf-8")
    assert F.read_json(tmp_path / "v.json") == value


def test_read_json_top_level_refusals(tmp_path):
    for text, message in (("NaN", "NaN is not a JSON number"), ('"\\udc80"', "not valid Unicode"),
                          ("1" * 5000, "digits"), ('{"\\ud800": 1}', "key is not valid Unicode")):
        (tmp_path / "v.json").write_text(text)
        e = refused(F.read_json, tmp_path / "v.json", match=message)
        assert e.field == "(top level)" or "\\ud800" in e.field, (text, e.field)


def test_input_errors_survive_pickling():
    """A worker process's error reaches its parent by pickle; every reader's subclass takes other arguments than
    the one text in its args."""
    import pickle

    from backend.mesh.load import MeshAssetError
    from backend.train.clip import ClipError
    from backend.train.config import TrainConfigError
    from scpainter_blender.core.splats.gaussians import SplatsError
    from scpainter_blender.core.vggt.predictions import PredictionsError

    from backend.evaluate.inception import EvaluationError
    from backend.render.channels import ExrError

    for e in (E.InputError("/a/job.json", "frames[0]", "bad", hint="fix it"), SplatsError("/a/car.ply", "bad", "x"),
              PredictionsError("/a/p.npz", "depth", "bad"), MeshAssetError("/a/m.glb", "bad"),
              TrainConfigError("/a/train.json", "steps", "bad"), ClipError("/a/clip.json", "cars", "bad"),
              E.ArgumentError("--device", "no GPU", hint="use --device cpu"), ExrError("/a/f.exr", None, "bad"),
              EvaluationError("/a/w.pth", "bad")):
        back = pickle.loads(pickle.dumps(e))
        assert type(back) is type(e) and str(back) == str(e) and back.__dict__ == e.__dict__
        assert isinstance(back, E.InputError) and back.field == e.field and back.hint == e.hint


def test_an_argument_error_names_the_command_line_and_the_option():
    e = E.ArgumentError("--device", "cuda: torch sees no CUDA GPU", hint="use --device cpu or auto")
    assert isinstance(e, E.InputError) and e.path == E.COMMAND_LINE == "(command line)" and e.field == "--device"
    assert str(e) == "(command line): --device: cuda: torch sees no CUDA GPU" and e.hint == "use --device cpu or auto"
