"""Reading files from users safely, for every command that takes them (issue 14).

- Every reader raises ``core.errors.InputError`` (or the caller's subclass of it), naming the file and the field.
- Inputs are opened with ``open_regular``: a FIFO, a directory or a device is refused before anything blocks on it;
  inside ``confined_reads`` the file actually opened (its descriptor's path, not the name) must lie in the folders
  allowed, so a file swapped for a link after a job's paths were checked is refused, not read.
- ``read_json``: size, depth and integer-length limits (validators then name any out-of-range field).
- ``read_npz``: each ``.npy`` member's header is parsed and checked against the member's size before a byte of
  data is allocated; object dtypes (pickles) are refused; every zip/zlib/header failure names the file and key.

Writing (atomic writes, confinement, output folders) is ``core.outputs``; one run per output folder is
``core.locking``.

Why one module of more than 400 lines: it is the shared reader of untrusted input. JSON and npz are the
containers of most input files (jobs, train configs, clips, checkpoints' configs; predictions, camera poses), and
both readers rest on the same two things here, ``open_regular`` and the ``error(path, field, message)`` callback
that lets each caller raise its own InputError subclass; split up, the one contract "no input can traceback, hang
or allocate what it does not hold" would be spread over three modules that only make sense together.

stdlib and numpy only (no bpy): the add-on and the backend share it.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import json
import math
import os
import re
import stat
import zipfile
import zlib
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputError

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator
    from typing import BinaryIO


# ---------------------------------------------------------------------------------------------- regular files

def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _os_error(path, e: OSError, error=InputError):
    if e.errno == errno.ENOENT:
        return error(path, "(file)", "not found")
    if e.errno in (errno.EACCES, errno.EPERM):
        return error(path, "(file)", "cannot be read: permission denied")
    if e.errno == errno.ELOOP:
        return error(path, "(file)", "is a symbolic link loop")
    if e.errno == errno.ENXIO:  # what opening a socket (or a device without its driver) says: say what it is
        with contextlib.suppress(OSError):
            return error(path, "(file)", f"is {_kind(os.stat(path).st_mode)}, not a regular file")
    return error(path, "(file)", f"cannot be read: {e.strerror or e}")


def _bad_name(path, error):
    """os.stat / os.open raise ValueError for a NUL in the name: an error naming it, like the others."""
    return error(path, "(file)", "is not a usable file name (it contains a NUL character)")


#: Windows has no O_NONBLOCK (nor FIFOs that block an open); O_BINARY exists only there (no CRLF translation).
NONBLOCK = getattr(os, "O_NONBLOCK", 0)


def check_regular(path: str | os.PathLike, error: Callable[..., Exception] = InputError) -> int:
    """The size in bytes of ``path`` if it is a regular file (symbolic links followed); ``error(path, "(file)",
    message)`` for a missing file, a directory, FIFO, device or socket. For readers that open the file
    themselves (trimesh); prefer ``open_regular``, which cannot be raced."""
    try:
        st = os.stat(path)
    except OSError as e:
        raise _os_error(path, e, error) from None
    except ValueError:
        raise _bad_name(path, error) from None
    if not stat.S_ISREG(st.st_mode):
        raise error(path, "(file)", f"is {_kind(st.st_mode)}, not a regular file")
    return st.st_size


def open_regular(path: str | os.PathLike, error: Callable[..., Exception] = InputError) -> BinaryIO:
    """``path`` opened for binary reading if it is a regular file, else ``error(path, "(file)", message)``.

    Opened non-blocking and checked with ``fstat`` on the open descriptor: opening a FIFO this way returns at
    once (a plain open waits for a writer, forever), and the check is about the file actually opened. Inside
    ``confined_reads``, the file opened must lie in one of its folders (``error`` otherwise)."""
    try:
        fd = os.open(path, os.O_RDONLY | NONBLOCK | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0))
    except OSError as e:
        raise _os_error(path, e, error) from None
    except ValueError:
        raise _bad_name(path, error) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise error(path, "(file)", f"is {_kind(st.st_mode)}, not a regular file")
        _check_confined(fd, path, error)
        try:  # regular files ignore O_NONBLOCK; clear it anyway so the descriptor behaves as usual
            import fcntl

            fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~NONBLOCK)
        except (ImportError, OSError):
            pass
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


#: The folders reads are confined to in this context (``confined_reads``), resolved; None: anywhere.
_READ_ROOTS: contextvars.ContextVar = contextvars.ContextVar("scpainter_read_roots", default=None)


@contextlib.contextmanager
def confined_reads(folders: Iterable[str | os.PathLike] | None) -> Iterator[None]:
    """Within the block (this thread's context), every file ``open_regular`` opens must lie, as opened, inside one
    of ``folders`` (links and ``..`` resolved): a job's folder and the data roots the user trusts
    (``job_inputs.reading``). The check is on the open descriptor (``/proc/self/fd``), so a path checked first and
    swapped for a link to another file before it is read is refused, not read. ``folders`` None: no limit (the
    user allowed everything)."""
    token = _READ_ROOTS.set(None if folders is None else tuple(os.path.realpath(f) for f in folders))
    try:
        yield
    finally:
        _READ_ROOTS.reset(token)


def _opened_path(fd: int, path) -> str:
    """Where the file open as ``fd`` is (Linux: its descriptor's link in ``/proc``), else ``path`` resolved."""
    with contextlib.suppress(OSError):
        return os.readlink(f"/proc/self/fd/{fd}")
    return os.path.realpath(path)


def _check_confined(fd: int, path, error) -> None:
    roots = _READ_ROOTS.get()
    if roots is None:
        return
    real = _opened_path(fd, path)
    if not any(real == r or real.startswith(r.rstrip(os.sep) + os.sep) for r in roots):
        raise error(path, "(file)", f"leads outside the job's folder and the data roots ({', '.join(roots)}): the "
                                    f"file opened is {real} (a link swapped in after the check?)")


# ------------------------------------------------------------------------------------------------------ JSON

MAX_JSON_BYTES = 256 * 2 ** 20   # a job of 10,000 frames with a few assets is ~10 MB
MAX_JSON_DEPTH = 32              # our schemas nest 5 deep
MAX_INT_DIGITS = 400             # longer integers are refused while parsing; validators bound the rest


class _Refused:
    """Stands in for a number that is refused while ``json.loads`` runs (it does not know where it is); the walk
    after parsing finds it and names its field."""

    __slots__ = ("message",)

    def __init__(self, message):
        self.message = message


def _parse_constant(name):
    return _Refused(f"{name} is not a JSON number (write a finite number, or null where allowed)")


def _parse_float(text):
    value = float(text)
    if not math.isfinite(value):
        return _Refused(f"number {text[:40]} is out of range (beyond ±1.8e308)")
    return value


def _parse_int(text):
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        return _Refused(f"integer {text[:20]}… ({len(text)} digits) is out of range (at most {MAX_INT_DIGITS} "
                        "digits)")
    return int(text)


def _has_lone_surrogate(s: str) -> bool:
    try:
        s.encode("utf-8")
    except UnicodeEncodeError:
        return True
    return False


def _path(node) -> str:
    """``frames[0].K`` from a linked (parent, key) node of the walk below."""
    keys = []
    while node is not None:
        node, key = node
        keys.append(key)
    text = ""
    for key in reversed(keys):
        text += f"[{key}]" if isinstance(key, int) else (f".{key}" if text else str(key))
    return text or "(top level)"


def _bad_string(s) -> bool:
    return isinstance(s, str) and _has_lone_surrogate(s)


def _first_problem(value, max_depth: int, check_strings: bool):
    """(field path like ``frames[0].K``, message) of the first refused value in document order: a value nested
    deeper than ``max_depth``, a refused number, or (``check_strings``) a string or key holding half of a
    surrogate pair (``"\\ud800"``: not text, it cannot be written to a file name or a log); None if all is well.

    Only containers and refused values are pushed (paths are linked (parent, key) pairs, made text only for the
    one reported), so a 10 MB job of plain numbers costs one pass over its containers."""
    def pushed(x) -> bool:
        return isinstance(x, (dict, list, _Refused)) or (check_strings and _bad_string(x))

    stack = [(value, None, 1)] if pushed(value) else []
    while stack:
        v, node, depth = stack.pop()
        if isinstance(v, _Refused):
            return _path(node), v.message
        if not isinstance(v, (dict, list)):  # a string pushed because it is not text
            return _path(node), "is not valid Unicode text (a lone surrogate escape such as \\ud800)"
        if depth > max_depth:
            return _path(node), f"nested deeper than {max_depth} levels"
        children = []
        for k, x in (v.items() if isinstance(v, dict) else enumerate(v)):
            if check_strings and _bad_string(k):
                return _path((node, ascii(k))), "the key is not valid Unicode text (a lone surrogate escape)"
            if pushed(x):
                children.append((x, (node, k), depth + 1))
        stack.extend(reversed(children))
    return None


def read_json(path: str | os.PathLike, error: Callable[..., Exception] = InputError, max_bytes: int = MAX_JSON_BYTES,
              max_depth: int = MAX_JSON_DEPTH) -> object:
    """A JSON file's content, read within limits; ``error(path, field, message)`` otherwise: not found / not a
    regular file / larger than ``max_bytes`` / not UTF-8 / not JSON (with line and column) / NaN or Infinity /
    a float beyond float64 / an integer longer than ``MAX_INT_DIGITS`` digits / nested deeper than ``max_depth`` /
    a lone surrogate escape. Refused values are named by their field (``frames[3].K``)."""
    path = os.fspath(path)
    with open_regular(path, error) as f:
        data = f.read(max_bytes + 1)
    return parse_json(data, path, error, max_bytes, max_depth)


def parse_json(data: bytes, path: str, error: Callable[..., Exception] = InputError,
               max_bytes: int = MAX_JSON_BYTES, max_depth: int = MAX_JSON_DEPTH) -> object:
    """``read_json`` for bytes already read (a warm backend's request line: ``path`` then names the source, such
    as ``"(request)"``): the same limits, the same ``error(path, field, message)`` calls."""
    if len(data) > max_bytes:
        size = f"{max_bytes // 2 ** 20} MB" if max_bytes >= 2 ** 20 else f"{max_bytes:,} bytes"
        raise error(path, "(file)", f"is larger than {size}: not a file this program writes")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise error(path, "(file)", f"is not UTF-8 text (byte {e.start})") from None
    # The number hooks cost a Python call per number: they are set only when the text could hold a number they
    # refuse (a run of digits that long, an exponent of 3 digits); NaN/Infinity literals always call theirs.
    refused = []

    def hook(fn):
        def call(text):
            v = fn(text)
            if isinstance(v, _Refused):
                refused.append(v)
            return v
        return call

    hooks = {"parse_constant": hook(_parse_constant)}
    if _EXPONENT.search(text) or _longest_digit_run(data) >= min(309, MAX_INT_DIGITS + 1):
        hooks["parse_int"], hooks["parse_float"] = hook(_parse_int), hook(_parse_float)
    try:
        value = json.loads(text, **hooks)
    except json.JSONDecodeError as e:
        raise error(path, "(file)", f"not valid JSON: {e.msg} at line {e.lineno} column {e.colno}") from None
    except RecursionError:
        raise error(path, "(file)", f"nested deeper than {max_depth} levels") from None
    except ValueError as e:  # Python's own limit on digits in an int (4300), should a hook not have been set
        raise error(path, "(file)", f"not valid JSON: {e}") from None
    # The walk that names the field runs only when there is something to find: a refused number, a surrogate
    # escape (the only way to a string that is not text), or brackets nested too deep (counted in the text).
    surrogates = "\\u" in text and _SURROGATE_ESCAPE.search(text) is not None
    if refused or surrogates or _nesting(text) > max_depth:
        problem = _first_problem(value, max_depth, check_strings=surrogates)
        if problem is not None:
            raise error(path, *problem)
    return value


#: A JSON string literal (escapes included), to blank before counting brackets.
_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"')


def _nesting(text: str, chunk: int = 1 << 24) -> int:
    """The deepest bracket nesting of (valid) JSON ``text``, strings ignored: numpy over the bytes, in chunks; the
    running level is summed over the brackets only (a 10 MB file is mostly numbers or whitespace)."""
    data = np.frombuffer(_STRING.sub('""', text).encode("ascii", "ignore"), np.uint8)
    deepest, level = 0, 0
    for start in range(0, len(data), chunk):
        b = data[start:start + chunk]
        opens = (b == ord("[")) | (b == ord("{"))
        brackets = np.flatnonzero(opens | (b == ord("]")) | (b == ord("}")))
        if len(brackets):
            levels = np.cumsum(np.where(opens[brackets], 1, -1)) + level
            deepest, level = max(deepest, int(levels.max())), int(levels[-1])
    return deepest


_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89a-fA-F]")
#: An exponent of three digits or more (beyond float64 from 1e309 on).
_EXPONENT = re.compile(r"[eE][+-]?\d{3}")


def _longest_digit_run(data: bytes) -> int:
    """The longest run of ASCII digits in ``data`` (UTF-8: other characters' bytes are never digits), by numpy:
    a regex for a long run of digits costs seconds on a 10 MB file."""
    d = np.frombuffer(data, np.uint8)
    digit = (d >= ord("0")) & (d <= ord("9"))
    if not digit.any():
        return 0
    bounds = np.concatenate(([0], np.flatnonzero(digit[1:] != digit[:-1]) + 1, [len(d)]))
    runs = np.diff(bounds)  # lengths of the alternating runs of digits and other bytes, from the first byte on
    return int(runs[0 if digit[0] else 1::2].max())


# ------------------------------------------------------------------------------------------------------- npz

NUMERIC_KINDS = "fiub"

#: What a corrupt compressed stream raises while being read (zlib for deflate, bz2 an OSError, lzma its own).
try:
    import lzma as _lzma

    _DECOMPRESS_ERRORS = (zlib.error, zipfile.BadZipFile, EOFError, OSError, _lzma.LZMAError)
except ImportError:  # a Python built without lzma cannot open such members at all (NotImplementedError)
    _DECOMPRESS_ERRORS = (zlib.error, zipfile.BadZipFile, EOFError, OSError)

#: Deflate expands at most ~1032:1 (bzip2 and lzma less); a member claiming more than this per stored byte is a
#: forged size, refused before anything is allocated for it.
_MAX_EXPANSION = 1100


def _memory_bytes() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 2 ** 40


def _npy_header(member, path, key, error):
    """(shape, dtype, fortran_order) of an open ``.npy`` member, its header parsed by numpy's own reader.

    numpy parses the header (at most 10,000 characters) as a Python literal, so a forged one can raise nearly
    anything (tokenize errors, RecursionError, MemoryError): all of it is a broken header, except a failure of
    the compressed stream underneath, which is named as such."""
    fmt = np.lib.format
    try:
        version = fmt.read_magic(member)
        if version == (1, 0):
            shape, fortran, dtype = fmt.read_array_header_1_0(member)
        elif version in ((2, 0), (3, 0)):
            shape, fortran, dtype = fmt.read_array_header_2_0(member)
        else:
            raise ValueError(f"unsupported .npy version {version}")
    except _DECOMPRESS_ERRORS as e:
        raise error(path, key, f"cannot be read: the compressed data is corrupt ({e})") from None
    except Exception as e:  # noqa: BLE001  (see the docstring)
        raise error(path, key, f"is not a readable .npy array (broken header: {str(e)[:200]})") from None
    if any(isinstance(n, bool) or n < 0 for n in shape):
        raise error(path, key, f"is not a readable .npy array (broken header: shape {tuple(shape)} has a negative "
                               "or boolean size)")
    return tuple(shape), dtype, fortran


def _open_zip(fh, path, error):
    """The ``zipfile.ZipFile`` of an open ``.npz``, or ``error(path, None, message)``."""
    head = fh.read(6)
    fh.seek(0)
    if head == b"\x93NUMPY":
        raise error(path, None, "is a single .npy array, expected an .npz archive of named arrays")
    try:
        zf = zipfile.ZipFile(fh)
        zf.infolist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError, OverflowError,
            UnicodeDecodeError) as e:
        raise error(path, None, f"is not a readable .npz (zip) archive, truncated or corrupt? ({e})") from None
    return zf


def read_npz(path: str | os.PathLike, keys: Iterable[str], optional: Iterable[str] = (),
             error: Callable[..., Exception] = InputError) -> dict:
    """The named numeric arrays of an ``.npz`` file: ``{key: ndarray}`` for each of ``keys`` (required) and of
    ``optional`` present in the file. Never unpickles, never allocates what the member cannot hold.

    ``error(path, key, message)`` (``key`` None for the file as a whole) for: not a regular file; not a zip
    archive (a single ``.npy`` is named as such); a missing required key (the message lists the keys present); a
    member stored without the ``.npy`` suffix or not an ``.npy`` array; a broken ``.npy`` header; an object,
    string or complex dtype; a header whose shape claims more (or fewer) bytes than the member holds; a corrupt
    compressed stream or CRC; an array larger than this machine's memory."""
    path = os.fspath(path)
    with open_regular(path, lambda p, f, m: error(p, None, m)) as fh:
        archive_size = os.fstat(fh.fileno()).st_size
        with _open_zip(fh, path, error) as zf:
            infos = {i.filename: i for i in zf.infolist()}
            present = sorted(n[:-4] if n.endswith(".npy") else n for n in infos)
            out = {}
            for key in list(keys) + [k for k in optional if k not in keys]:
                info = infos.get(key + ".npy")
                if info is None:
                    if key in infos:
                        raise error(path, key, "is stored without the .npy suffix: not a NumPy array member")
                    if key in keys:
                        missing = [k for k in keys if k + ".npy" not in infos]
                        raise error(path, missing[0], f"missing key(s) {missing}; the file has {present}")
                    continue
                out[key] = _read_member(zf, info, path, key, error, archive_size)
    return out


def _read_member(zf, info, path, key, error, archive_size: int) -> np.ndarray:
    # sizes from the zip directory are claims: check them against the archive before trusting them
    if info.compress_size > archive_size or (info.compress_type == zipfile.ZIP_STORED
                                             and info.compress_size != info.file_size) \
            or info.file_size > _MAX_EXPANSION * max(info.compress_size, 1) + 1024:
        raise error(path, key, f"the archive's directory gives impossible sizes ({info.compress_size:,} bytes "
                               f"stored for {info.file_size:,}): the file is truncated or corrupt")
    try:
        member = zf.open(info)
    except (zipfile.BadZipFile, NotImplementedError, RuntimeError, OSError, ValueError, EOFError) as e:
        raise error(path, key, f"cannot be opened in the archive ({e})") from None
    with member:
        shape, dtype, fortran = _npy_header(member, path, key, error)
        if dtype.hasobject:
            raise error(path, key, "holds Python objects (pickles), which are never loaded: save numeric arrays")
        if dtype.kind not in NUMERIC_KINDS or dtype.fields is not None or dtype.subdtype is not None:
            raise error(path, key, f"is not a numeric array (dtype {dtype})")
        count = math.prod(shape)
        nbytes = count * dtype.itemsize
        stored = info.file_size - member.tell()
        if nbytes != stored:
            raise error(path, key, f"its header claims shape {shape} ({nbytes:,} bytes) but the member holds "
                                   f"{stored:,} bytes: the file is truncated or corrupt")
        if nbytes > _memory_bytes():
            raise error(path, key, f"shape {shape} needs {nbytes / 2 ** 30:.1f} GiB, more than this machine's "
                                   "memory")
        try:
            arr = np.empty(count, dtype)
            view = memoryview(arr.view(np.uint8))
            got = 0
            while got < nbytes:
                n = member.readinto(view[got:])
                if not n:
                    break
                got += n
            # one more read reaches the end of the stream, where zipfile checks the CRC
            trailing = member.read(1) if got == nbytes else b""
        except MemoryError:
            raise error(path, key, f"shape {shape} does not fit in memory") from None
        except _DECOMPRESS_ERRORS + (ValueError,) as e:
            raise error(path, key, f"cannot be read: the compressed data is corrupt ({e})") from None
        if got != nbytes:
            raise error(path, key, f"ends after {got:,} of {nbytes:,} bytes: the file is truncated")
        if trailing:
            raise error(path, key, f"holds more than the {nbytes:,} bytes its header's shape {shape} claims: the "
                                   "file is corrupt")
    return arr.reshape(shape, order="F" if fortran else "C")


def npz_shapes(path: str | os.PathLike, keys: Iterable[str] | None = None,
               error: Callable[..., Exception] = InputError) -> dict:
    """``{key: shape}`` of an ``.npz``'s members from their headers alone (no data read): for validating a job
    against its inputs before any work. ``keys`` None: every ``.npy`` member. The same ``error`` calls as
    ``read_npz`` for an unreadable file or header; a missing key is simply absent."""
    path = os.fspath(path)
    with open_regular(path, lambda p, f, m: error(p, None, m)) as fh:
        with _open_zip(fh, path, error) as zf:
            out = {}
            for info in zf.infolist():
                name = info.filename
                if not name.endswith(".npy") or (keys is not None and name[:-4] not in keys):
                    continue
                try:
                    member = zf.open(info)
                except (zipfile.BadZipFile, NotImplementedError, RuntimeError, OSError, ValueError, EOFError) as e:
                    raise error(path, name[:-4], f"cannot be opened in the archive ({e})") from None
                with member:
                    out[name[:-4]] = _npy_header(member, path, name[:-4], error)[0]
            return out
