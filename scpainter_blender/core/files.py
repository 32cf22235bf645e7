"""Reading and writing files safely, for every command that takes files from users (issue 14).

- ``InputError``: bad input, naming the file and the field, what is wrong and what to do. Every reader's error
  derives from it; the backend turns it into exit code 2 and an ``error`` event with ``file`` and ``field``.
- Inputs are opened with ``open_regular``: a FIFO, a directory or a device is refused before anything blocks on it.
- ``read_json``: size, depth and integer-length limits (validators then name any out-of-range field).
- ``read_npz``: each ``.npy`` member's header is parsed and checked against the member's size before a byte of
  data is allocated; object dtypes (pickles) are refused; every zip/zlib/header failure names the file and key.
- ``atomic_write``: a unique temporary file (``mkstemp``, never a planted link) in the target folder, renamed
  over the target when complete; nothing half-written survives an error.
- ``confined``: a job's paths may not leave the job's folder (``..`` or a symlink) unless the user allows it.
- ``OutputLock``: one run per output folder; a lock whose owner died is taken over.

stdlib and numpy only (no bpy): the add-on and the backend share it.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import socket
import stat
import tempfile
import time
import zipfile
import zlib

import numpy as np


class InputError(ValueError):
    """Bad input: ``path`` (the file), ``field`` (the key, property or header line; ``"(file)"`` for the file as
    a whole), ``message`` (what is wrong), ``hint`` (what to do, optional). ``str()`` is
    ``"<file name>: <field>: <message>"``.

    The one error type for bad input: ``python -m backend`` exits 2 for it (and only for it), the Blender command
    and the operators catch it by name. A plain ``ValueError`` is a bug of ours, never a user's mistake. Input
    that is not a file names its source in parentheses as ``path``: ``COMMAND_LINE`` with the option as field
    (``ArgumentError``), ``"(environment)"`` with the variable, ``"(add-on preferences)"`` with the preference;
    a scene setting names the .blend (``"(unsaved .blend)"``) and the datablock or property.

    It derives from ``ValueError`` only so that callers written before it still catch it; catch it by name."""

    def __init__(self, path, field, message, hint=None):
        self.path, self.field, self.message, self.hint = str(path), field or "(file)", message, hint
        super().__init__(f"{os.path.basename(self.path) or self.path}: {self.field}: {message}")

    def __reduce__(self):
        # pickle (a worker process's error sent back) rebuilds from the state, not by calling __init__ with args:
        # subclasses take other arguments than the one text their args hold
        return _rebuild_error, (self.__class__, self.args, self.__dict__)


def _rebuild_error(cls, args, state):
    e = cls.__new__(cls, *args)
    e.args = args
    e.__dict__.update(state)
    return e


#: The ``path`` of an InputError about a command-line argument.
COMMAND_LINE = "(command line)"


class ArgumentError(InputError):
    """A bad command-line argument (``--device cuda`` without a GPU, no job given): ``path`` is ``COMMAND_LINE``,
    ``field`` the option (``--device``) or a positional argument's name (``jobs``)."""

    def __init__(self, field, message, hint=None):
        super().__init__(COMMAND_LINE, field, message, hint)


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
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)


def check_regular(path, error=InputError) -> int:
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


def open_regular(path, error=InputError):
    """``path`` opened for binary reading if it is a regular file, else ``error(path, "(file)", message)``.

    Opened non-blocking and checked with ``fstat`` on the open descriptor: opening a FIFO this way returns at
    once (a plain open waits for a writer, forever), and the check is about the file actually opened."""
    try:
        fd = os.open(path, os.O_RDONLY | _NONBLOCK | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0))
    except OSError as e:
        raise _os_error(path, e, error) from None
    except ValueError:
        raise _bad_name(path, error) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise error(path, "(file)", f"is {_kind(st.st_mode)}, not a regular file")
        try:  # regular files ignore O_NONBLOCK; clear it anyway so the descriptor behaves as usual
            import fcntl

            fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~_NONBLOCK)
        except (ImportError, OSError):
            pass
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


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


def read_json(path, error=InputError, max_bytes: int = MAX_JSON_BYTES, max_depth: int = MAX_JSON_DEPTH):
    """A JSON file's content, read within limits; ``error(path, field, message)`` otherwise: not found / not a
    regular file / larger than ``max_bytes`` / not UTF-8 / not JSON (with line and column) / NaN or Infinity /
    a float beyond float64 / an integer longer than ``MAX_INT_DIGITS`` digits / nested deeper than ``max_depth`` /
    a lone surrogate escape. Refused values are named by their field (``frames[3].K``)."""
    path = os.fspath(path)
    with open_regular(path, error) as f:
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise error(path, "(file)", f"is larger than {max_bytes // 2 ** 20} MB: not a file this program writes")
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


def read_npz(path, keys, optional=(), error=InputError) -> dict:
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


def npz_shapes(path, keys=None, error=InputError) -> dict:
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


# ------------------------------------------------------------------------------------------- writing outputs

def _umask() -> int:
    """The process's umask, read from /proc where it can be (setting it to read it, the fallback, is
    process-wide: a thread creating a file in that instant would get the temporary mask)."""
    try:
        with open("/proc/self/status", "rb") as f:
            for line in f:
                if line.startswith(b"Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path):
    """Yields a fresh temporary path in ``path``'s folder (created by ``mkstemp``: a unique name, exclusive, so a
    planted file or link is never written through); on success it is renamed over ``path`` (a link at ``path``
    is replaced, not followed), on any error removed. For writers that open by name (PyAV, safetensors)."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    # the name is cut so that prefix + random part + suffix stays within a file system's 255-byte names
    fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)[:100]}.", suffix=".tmp", dir=folder)
    os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the user's usual permissions
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise


@contextlib.contextmanager
def atomic_write(path, mode: str = "wb"):
    """``with atomic_write(path, "w") as f:`` — ``f`` writes a temporary file that replaces ``path`` only when the
    block ends without an error (see ``atomic_path``)."""
    with atomic_path(path) as tmp:
        # O_NOFOLLOW: the fresh name is ours, but a link swapped in for it in a shared folder is not followed
        with open(tmp, mode, **({} if "b" in mode else {"encoding": "utf-8"}),
                  opener=lambda p, flags: os.open(p, flags | getattr(os, "O_NOFOLLOW", 0), 0o600)) as f:
            yield f


def write_json(path, value, indent: int | None = 1) -> None:
    """``value`` as JSON (strict: NaN/inf refused), atomically."""
    text = json.dumps(value, indent=indent, allow_nan=False)
    with atomic_write(path, "w") as f:
        f.write(text + "\n")


def append_text(path, text: str) -> None:
    """Append to a log file, never through a symbolic link (``O_NOFOLLOW``): InputError if ``path`` is one."""
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags | _NONBLOCK, 0o666)  # a FIFO without a reader fails at once (ENXIO), not blocks
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise InputError(path, "(file)", "is a symbolic link: the log is not written through links",
                             hint="remove the link") from None
        if e.errno in (errno.ENXIO, errno.EISDIR):
            raise InputError(path, "(file)", "is not a regular file: the log cannot be appended to it",
                             hint="remove it, or choose another output folder") from None
        raise
    with os.fdopen(fd, "a", encoding="utf-8") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise InputError(path, "(file)", "is not a regular file: the log cannot be appended to it")
        f.write(text)


def remove_listed(folder, names) -> int:
    """Delete the files ``names`` (bare file names, as a record of this program's outputs lists them) from
    ``folder``; names with a path separator or ``..`` are ignored, a link is removed itself, never its target.
    Returns how many were removed."""
    removed = 0
    for name in names:
        if not isinstance(name, str) or not name or name in (".", "..") or os.sep in name or "/" in name or \
                (os.altsep and os.altsep in name) or "\0" in name:  # a NUL makes os.path raise ValueError
            continue
        with contextlib.suppress(FileNotFoundError, IsADirectoryError, PermissionError):
            p = os.path.join(folder, name)
            if os.path.islink(p) or os.path.isfile(p):
                os.remove(p)
                removed += 1
    return removed


# ------------------------------------------------------------------------------------------------ confinement

def inside(path, folder) -> bool:
    """Whether ``path`` lies in ``folder`` (or is it) after resolving symbolic links and ``..``."""
    p, f = os.path.realpath(path), os.path.realpath(folder)
    return p == f or p.startswith(f.rstrip(os.sep) + os.sep)


def confined(base, value, error, field: str, allow_outside: bool = False) -> str:
    """The absolute path of a job's ``value`` (relative to ``base``, the job's folder). Unless ``allow_outside``,
    ``error(field, message)`` when it resolves outside ``base`` (``..``, an absolute path elsewhere, or a symbolic
    link pointing out): a job from someone else must not read or write beyond its own folder."""
    path = os.path.normpath(os.path.join(os.path.abspath(base), os.fspath(value)))
    if not allow_outside and not inside(path, base):
        real = os.path.realpath(path)
        how = "through a symbolic link " if os.path.realpath(os.path.dirname(path)) != os.path.dirname(path) or \
            real != path else ""
        raise error(field, f"{value!r} leads {how}outside the job's folder ({real}); move it into the folder, or "
                           "run with --allow-outside if you trust this job")
    return path


def make_folder(path, field: str = "(folder)") -> str:
    """``os.makedirs(path, exist_ok=True)``, with InputError naming the folder when it cannot be made (a file or a
    FIFO in the way, a name too long, no permission)."""
    try:
        os.makedirs(path, exist_ok=True)
    except FileExistsError:
        raise InputError(path, field, "exists and is not a folder", hint="remove it or choose another output "
                                                                         "folder") from None
    except OSError as e:
        raise InputError(path, field, f"cannot be made: {e.strerror or e}") from None
    if not os.path.isdir(path):
        raise InputError(path, field, "exists and is not a folder")
    return path


def output_folder(parent, name: str, allow_outside: bool = False) -> str:
    """``parent/name`` created if missing; InputError if it is a symbolic link (or lies) outside ``parent``
    unless ``allow_outside``: a link planted in an output folder must not carry writes elsewhere."""
    path = os.path.join(parent, name)
    make_folder(path)
    if not allow_outside and not inside(path, parent):
        raise InputError(path, "(folder)", f"leads outside the output folder ({os.path.realpath(path)})",
                         hint="remove the link, or run with --allow-outside if you made it")
    return path


OUTPUT_FOLDERS = ("conditions", "generated")
LOG_NAME = "backend.log"


def check_output(out, allow_outside: bool = False) -> None:
    """What a run would refuse in an output folder, checked without creating anything (``--check`` and the start
    of every run): ``out`` not a folder; ``conditions/`` or ``generated/`` not a folder or leading outside ``out``
    (unless ``allow_outside``); ``backend.log`` a symbolic link or not a regular file. InputError names it."""
    if not os.path.lexists(out):
        return
    if not os.path.isdir(out):
        raise InputError(out, "output_dir", "exists and is not a folder", hint="remove it or choose another "
                                                                               "output folder")
    for name in OUTPUT_FOLDERS:
        path = os.path.join(out, name)
        if not os.path.lexists(path):
            continue
        if not allow_outside and not inside(path, out):
            raise InputError(path, "(folder)", f"leads outside the output folder ({os.path.realpath(path)})",
                             hint="remove the link, or run with --allow-outside if you made it")
        if not os.path.isdir(path):
            raise InputError(path, "(folder)", "exists and is not a folder")
    check_log(os.path.join(out, LOG_NAME))


def check_log(path) -> None:
    """InputError if the log file ``path`` exists as a symbolic link (never appended through) or as anything but a
    regular file; a missing one is fine (it is created)."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if stat.S_ISLNK(mode):
        raise InputError(path, "(file)", "is a symbolic link: the log is not written through links",
                         hint="remove the link")
    if not stat.S_ISREG(mode):
        raise InputError(path, "(file)", "is not a regular file: the log cannot be appended to it")


def lock_owner(folder):
    """The record of the run holding ``folder``'s lock if that run is alive on this host (or elsewhere: unknown,
    taken as alive), else None: for ``--check`` to say a run would be refused."""
    owner = OutputLock(folder, "check")._owner()
    if not isinstance(owner, dict) or not isinstance(owner.get("pid"), int):
        return None
    if owner.get("host") == socket.gethostname() and not _alive(owner["pid"], owner.get("started")):
        return None
    return owner


def remove_temporaries(folder, names) -> int:
    """Delete what ``atomic_path`` left for the targets ``names`` in ``folder`` when a process was killed
    (``.<name>.<random>.tmp``); only those names' temporaries, for a caller holding the folder's lock."""
    prefixes = tuple(f".{n[:100]}." for n in names)
    removed = 0
    try:
        entries = os.listdir(folder)
    except OSError:
        return 0
    for entry in entries:
        if entry.endswith(".tmp") and entry.startswith(prefixes) and "/" not in entry:
            with contextlib.suppress(OSError):
                p = os.path.join(folder, entry)
                if os.path.islink(p) or os.path.isfile(p):
                    os.remove(p)
                    removed += 1
    return removed


# ---------------------------------------------------------------------------------------------------- locking

LOCK_NAME = ".scpainter.lock"
UNREADABLE_LOCK_S = 60   # a lock file nobody can read is taken over after this (a crash mid-write on old systems)


def _process_start(pid: int):
    """The process's start time in clock ticks (Linux ``/proc``), to tell a live owner from a reused pid; None
    where unknown."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return int(f.read().rsplit(b")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return None


def _process_state(pid: int):
    """The process's state letter (``Z`` zombie) from Linux ``/proc``; None where unknown."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0]
    except (OSError, IndexError, ValueError):
        return None


def _alive(pid: int, started) -> bool:
    if pid <= 0:  # kill(0) and kill(-1) would test our own process group / every process: garbage, not an owner
        return False
    if _process_state(pid) == b"Z":  # a zombie has exited; only its exit status waits for its parent
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except (OverflowError, ValueError):
        return False
    return started is None or _process_start(pid) in (None, started)


class OutputLock:
    """``with OutputLock(folder, command):`` — at most one run writes an output folder at a time.

    The lock file ``<folder>/.scpainter.lock`` (created exclusively, never through a link) holds the owner's pid,
    host, process start time, command and start date, and appears whole (see ``_take``). A second run raises
    ``busy(message, hint, file=, owner=)`` naming the owner; a lock left by a process that no longer runs on this
    host, or unreadable for ``UNREADABLE_LOCK_S``, is taken over (``stale`` is then the old owner's record, for a
    log line). The file is removed when the block ends."""

    def __init__(self, folder, command: str, busy=None):
        self.folder, self.command = os.fspath(folder), command
        self.path = os.path.join(self.folder, LOCK_NAME)
        self.busy = busy or (lambda message, hint, **fields: RuntimeError(f"{message} ({hint})"))
        self.stale = None
        self._held = False

    def _owner(self):
        try:
            with open_regular(self.path) as f:
                return json.loads(f.read(4096).decode("utf-8"))
        except (InputError, ValueError, OSError, RecursionError):
            return None

    def _take(self, me: dict) -> bool:
        """Create the lock file whole or not at all: written to a private temporary file, then hard-linked to its
        name (``link`` fails if the name exists, never follows a planted link), so no reader sees it empty."""
        fd, tmp = tempfile.mkstemp(prefix=".scpainter.lock.", dir=self.folder)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(me, f)
            try:
                os.link(tmp, self.path)
            except FileExistsError:
                return False
            except OSError:  # a file system without hard links: exclusive create, then write
                try:
                    fd2 = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0),
                                  0o644)
                except FileExistsError:
                    return False
                with os.fdopen(fd2, "w", encoding="utf-8") as f:
                    json.dump(me, f)
            return True
        finally:
            with contextlib.suppress(OSError):
                os.remove(tmp)

    def __enter__(self):
        make_folder(self.folder)
        me = {"pid": os.getpid(), "host": socket.gethostname(), "started": _process_start(os.getpid()),
              "command": self.command, "since": time.strftime("%Y-%m-%d %H:%M:%S")}
        for _ in range(3):
            if self._take(me):
                self._held = True
                return self
            owner = self._owner()
            if owner is None:  # unreadable: written by a file system without links this instant, or damaged
                time.sleep(0.05)
                owner = self._owner()
            if isinstance(owner, dict) and owner.get("host") == me["host"] and isinstance(owner.get("pid"), int) \
                    and not _alive(owner["pid"], owner.get("started")):
                self.stale = owner
            elif owner is None and self._age() > UNREADABLE_LOCK_S:
                self.stale = {"unreadable lock file, age s": round(self._age())}
            elif owner is None:
                raise self.busy(f"{self.path}: the output folder is locked and the lock file is unreadable",
                                f"it is taken over when older than {UNREADABLE_LOCK_S} s; delete it if no other "
                                "SCPainter run uses this folder", file=self.path, owner=None)
            else:
                raise self.busy(f"{self.folder} is being written by another run: pid {owner.get('pid')} on "
                                f"{owner.get('host')} ({owner.get('command')}, since {owner.get('since')})",
                                f"wait for it to finish or stop it; if it is gone, delete {self.path}",
                                file=self.path, owner=owner)
            with contextlib.suppress(FileNotFoundError):
                os.remove(self.path)
        raise self.busy(f"{self.path}: could not take the output folder's lock", "try again", file=self.path,
                        owner=None)

    def took_over(self) -> str | None:
        """A log line when the lock was taken over from a run that ended without releasing it, else None."""
        o = self.stale
        if o is None:
            return None
        who = (f"pid {o.get('pid')} on {o.get('host')} ({o.get('command')}, since {o.get('since')})"
               if "pid" in o else "an unreadable lock file")
        return f"took over the output folder's lock from {who}: that run ended without releasing it"

    def _age(self) -> float:
        try:
            return time.time() - os.lstat(self.path).st_mtime
        except OSError:
            return 0.0

    def __exit__(self, *exc):
        if self._held:
            with contextlib.suppress(FileNotFoundError):
                os.remove(self.path)
            self._held = False
        return False
