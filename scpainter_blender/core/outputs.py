"""Writing outputs safely (issue 14): whole files or none, never through a planted link, never outside the folder.

- ``atomic_write`` / ``atomic_path``: a unique temporary file (``mkstemp``, never a planted link) in the target
  folder, renamed over the target when complete; nothing half-written survives an error. ``atomic_folder`` the
  same for a folder built whole (a checkpoint, a clip, a cached street). ``write_json`` is the one JSON writer
  (strict: NaN/inf refused). ``remove_temporaries`` removes the temporary files a killed run left.
- Log files: ``append_text`` never appends through a symbolic link; ``check_log`` refuses one beforehand.
- Confinement: ``confined``, a job's paths may not leave the job's folder (``..`` or a symlink) except into a data
  root the user trusts (``--data-root``: ``data_root``, ``data_roots_option``), unless the user allows everything
  (``--allow-outside``); ``inside`` is the test.
- Output folders: ``make_folder``, ``output_folder`` (``conditions/``, ``generated/`` may not lead elsewhere),
  ``check_output`` (what a run would refuse, checked without creating anything), ``remove_listed`` (the files a
  record of this program's outputs lists, and nothing else).

Bad outputs (a file in the way, a link) raise ``errors.InputError`` naming the path. One run per output folder is
``core.locking``; the names in an output folder are ``core.output_layout``. stdlib only (no bpy): the add-on and
the backend share it.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import stat
import tempfile
from typing import TYPE_CHECKING

from .errors import DISK_FULL_ERRNOS, ArgumentError, InputError
from .user_cache import user_cache_dir  # noqa: F401  (outputs.user_cache_dir: its callers' name for it)
from .files import NONBLOCK
from .output_layout import OutputLayout

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator, Sequence
    from typing import IO

# -------------------------------------------------------------------------------------- writing a file whole

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


#: A temporary output is ``.<target's name>.<random>.tmp`` (``atomic_path``), found again by ``remove_temporaries``.
_TEMPORARY_SUFFIX = ".tmp"


def _temporary_prefix(name: str) -> str:
    """``.<name>.``, the name cut so that prefix + random part + suffix stays within a file system's 255-byte
    names."""
    return f".{name[:100]}."


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[str]:
    """Yields a fresh temporary path in ``path``'s folder (created by ``mkstemp``: a unique name, exclusive, so a
    planted file or link is never written through); on success it is renamed over ``path`` (a link at ``path``
    is replaced, not followed), on any error removed; a folder at ``path`` is an InputError naming it. For writers
    that open by name (PyAV, safetensors)."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=_temporary_prefix(os.path.basename(path)), suffix=_TEMPORARY_SUFFIX,
                               dir=folder)
    os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the user's usual permissions
        try:
            os.replace(tmp, path)
        except IsADirectoryError:  # a file is never renamed over a folder
            raise InputError(path, "(file)", "is a folder where this output file goes",
                             hint="move or remove the folder, then run again") from None
    except BaseException as e:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        if isinstance(e, OSError) and e.filename is None:  # a write's error (a full disk) names no file: this one
            e.filename = path
        raise


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike, keep_existing: bool = False, replace: bool = False,
                  usual_mode: bool = False) -> Iterator[str]:
    """Yields a fresh empty folder beside ``path`` (``mkdtemp``: ``.<name>.<random>.tmp``, a unique name, mode 0700
    as mkdtemp makes it); when the block ends without an error it is renamed to ``path``, on any error removed with
    everything in it, so ``path`` appears whole or not at all. The parent folder must exist. ``keep_existing``:
    when ``path`` appeared meanwhile (another process finished first), ours is removed and theirs kept; otherwise
    the rename's OSError is raised (``path`` a folder that is not empty). ``replace``: an existing ``path`` (the
    caller decided it may go) is moved aside just before ours takes its name, deleted once it has, and put back
    if the rename fails. ``usual_mode``: the folder gets the permissions a new folder would (0777 less the umask)
    before it is renamed."""
    path = os.path.abspath(os.fspath(path))
    parent, name = os.path.dirname(path), os.path.basename(path)
    tmp = tempfile.mkdtemp(prefix=_temporary_prefix(name), suffix=_TEMPORARY_SUFFIX, dir=parent)
    aside = None
    try:
        yield tmp
        if usual_mode:
            os.chmod(tmp, 0o777 & ~_umask())
        if replace and os.path.lexists(path):
            aside = tempfile.mkdtemp(prefix=_temporary_prefix(name), suffix=".old" + _TEMPORARY_SUFFIX, dir=parent)
            os.rename(path, os.path.join(aside, name))
        try:
            os.rename(tmp, path)
        except OSError:
            if aside is not None and not os.path.lexists(path):
                os.rename(os.path.join(aside, name), path)
            if not (keep_existing and os.path.isdir(path)):
                raise
    finally:  # after an error, or when theirs was kept (renamed, it is gone); the replaced folder once it is
        if os.path.isdir(tmp) and not os.path.islink(tmp):
            shutil.rmtree(tmp, ignore_errors=True)
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO]:
    """``with atomic_write(path, "w") as f:`` — ``f`` writes a temporary file that replaces ``path`` only when the
    block ends without an error (see ``atomic_path``)."""
    with atomic_path(path) as tmp:
        # O_NOFOLLOW: the fresh name is ours, but a link swapped in for it in a shared folder is not followed
        with open(tmp, mode, **({} if "b" in mode else {"encoding": "utf-8"}),
                  opener=lambda p, flags: os.open(p, flags | getattr(os, "O_NOFOLLOW", 0), 0o600)) as f:
            yield f


def write_json(path: str | os.PathLike, value: object, indent: int | None = 1) -> None:
    """``value`` as JSON (strict: NaN/inf refused), atomically."""
    text = json.dumps(value, indent=indent, allow_nan=False)
    with atomic_write(path, "w") as f:
        f.write(text + "\n")


def remove_temporaries(folder: str | os.PathLike, names: Iterable[str]) -> int:
    """Delete what ``atomic_path`` left for the targets ``names`` in ``folder`` when a process was killed
    (``.<name>.<random>.tmp``); only those names' temporaries, for a caller holding the folder's lock."""
    prefixes = tuple(_temporary_prefix(n) for n in names)
    removed = 0
    try:
        entries = os.listdir(folder)
    except OSError:
        return 0
    for entry in entries:
        if entry.endswith(_TEMPORARY_SUFFIX) and entry.startswith(prefixes) and "/" not in entry:
            with contextlib.suppress(OSError):
                p = os.path.join(folder, entry)
                if os.path.islink(p) or os.path.isfile(p):
                    os.remove(p)
                    removed += 1
    return removed


def link_or_copy(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """``dst`` as a hard link to ``src`` where the file system allows (multi-GB model weights cost nothing), a
    copy with its metadata otherwise (another device, a file system without links)."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def link_or_copy_tree(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Every file under the folder ``src`` into ``dst`` (created), by ``link_or_copy``."""
    for root, _, names in os.walk(src):
        rel = os.path.relpath(root, src)
        os.makedirs(os.path.join(dst, rel), exist_ok=True)
        for f in names:
            link_or_copy(os.path.join(root, f), os.path.join(dst, rel, f))


# ------------------------------------------------------------------------------------------------- log files

_LINKED_LOG = "is a symbolic link: the log is not written through links"
_IRREGULAR_LOG = "is not a regular file: the log cannot be appended to it"


def append_text(path: str | os.PathLike, text: str) -> None:
    """Append to a log file, never through a symbolic link (``O_NOFOLLOW``): InputError if ``path`` is one."""
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags | NONBLOCK, 0o666)  # a FIFO without a reader fails at once (ENXIO), not blocks
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise InputError(path, "(file)", _LINKED_LOG, hint="remove the link") from None
        if e.errno in (errno.ENXIO, errno.EISDIR):
            raise InputError(path, "(file)", _IRREGULAR_LOG, hint="remove it, or choose another output folder") \
                from None
        raise
    # a file name that is not UTF-8 (its bytes kept as surrogates) is written as \udcff: the log stays UTF-8 text
    with os.fdopen(fd, "a", encoding="utf-8", errors="backslashreplace") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise InputError(path, "(file)", _IRREGULAR_LOG)
        f.write(text)


def check_log(path: str | os.PathLike) -> None:
    """InputError if the log file ``path`` exists as a symbolic link (never appended through) or as anything but a
    regular file; a missing one is fine (it is created)."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if stat.S_ISLNK(mode):
        raise InputError(path, "(file)", _LINKED_LOG, hint="remove the link")
    if not stat.S_ISREG(mode):
        raise InputError(path, "(file)", _IRREGULAR_LOG)


# ----------------------------------------------------------------------------------------------- confinement

#: The option naming a data root (``python -m backend render|generate|export|batch``, ``blender -c scpainter
#: batch``), repeatable; in a batch list file the same is a ``data-root: DIR`` line (``core.batch_items``).
DATA_ROOT_OPTION = "--data-root"
#: The option that lifts confinement for every path of a job.
ALLOW_OUTSIDE_OPTION = "--allow-outside"
#: What to do about a job path that leads outside its job's folder and every data root.
CONFINED_HINT = (f"move it into the job's folder; or name the folder that holds it with {DATA_ROOT_OPTION} DIR (a "
                 "trusted root of shared recordings and assets; a batch list file may declare it with a "
                 f"'data-root: DIR' line); or run with {ALLOW_OUTSIDE_OPTION} if you trust this job")


def inside(path: str | os.PathLike, folder: str | os.PathLike) -> bool:
    """Whether ``path`` lies in ``folder`` (or is it) after resolving symbolic links and ``..``."""
    p, f = os.path.realpath(path), os.path.realpath(folder)
    return p == f or p.startswith(f.rstrip(os.sep) + os.sep)


def data_root(path: str | os.PathLike, error: Callable[[str], Exception]) -> str:
    """The absolute path of a data root the user named (``--data-root DIR``; a list file's ``data-root:`` line,
    given already joined to the list's folder), checked: ``error(message)`` (the InputError to raise, naming
    where it was given) unless it is an existing folder. A root that is itself a symbolic link is followed: the
    user named it."""
    p = os.path.abspath(os.fspath(path))
    if not os.path.isdir(p):
        raise error(f"{p} {'is not a folder' if os.path.exists(p) else 'does not exist'}")
    return p


def data_roots_option(values: Iterable[str] | None) -> tuple:
    """The ``--data-root`` values of a command line (None: not given), each checked by ``data_root``: an
    ``ArgumentError`` naming the option otherwise. Returns a tuple of absolute folders."""
    def error(message):
        return ArgumentError(DATA_ROOT_OPTION, message, hint="name an existing folder (a trusted root of shared "
                                                             "recordings and assets)")

    return tuple(data_root(v, error) for v in values or ())


def confined(base: str | os.PathLike, value: str, error: Callable[..., Exception], field: str,
             allow_outside: bool = False, data_roots: Sequence[str] = ()) -> str:
    """The absolute path of a job's ``value`` (relative to ``base``, the job's folder). It must resolve (symbolic
    links and ``..`` followed) inside ``base`` or inside one of ``data_roots`` (folders the user trusts, absolute:
    ``data_root``), unless ``allow_outside``; otherwise ``error(field, message, hint)`` (``..``, an absolute path
    elsewhere, or a symbolic link pointing out, also one inside a data root): a job from someone else must not
    read or write beyond its own folder and the roots the user named. The output folder follows the same rule:
    it may lie in a data root too (variant jobs writing into a shared tree of renders)."""
    path = os.path.normpath(os.path.join(os.path.abspath(base), os.fspath(value)))
    if allow_outside or inside(path, base) or any(inside(path, root) for root in data_roots):
        return path
    real = os.path.realpath(path)
    how = "through a symbolic link " if real != path else ""
    where = f"the job's folder ({os.path.abspath(base)})"
    if data_roots:
        where += f" and the data root{'s' if len(data_roots) > 1 else ''} ({', '.join(data_roots)})"
    raise error(field, f"{value!r} leads {how}outside {where}: it resolves to {real}", CONFINED_HINT)


# -------------------------------------------------------------------------------------------- output folders

def make_folder(path: str | os.PathLike, field: str = "(folder)") -> str:
    """``os.makedirs(path, exist_ok=True)``, with InputError naming the folder when it cannot be made (a file or a
    FIFO in the way, a name too long, no permission)."""
    try:
        os.makedirs(path, exist_ok=True)
    except FileExistsError:
        raise InputError(path, field, "exists and is not a folder", hint="remove it or choose another output "
                                                                         "folder") from None
    except OSError as e:
        if e.errno in DISK_FULL_ERRNOS:  # not the folder's fault: the backend names the full disk
            raise
        raise InputError(path, field, f"cannot be made: {e.strerror or e}") from None
    if not os.path.isdir(path):
        raise InputError(path, field, "exists and is not a folder")
    return path


def output_folder(parent: str | os.PathLike, name: str, allow_outside: bool = False) -> str:
    """``parent/name`` created if missing; InputError if it is a symbolic link (or lies) outside ``parent``
    unless ``allow_outside``: a link planted in an output folder must not carry writes elsewhere."""
    path = os.path.join(parent, name)
    make_folder(path)
    if not allow_outside and not inside(path, parent):
        raise _leads_outside(path)
    return path


def _leads_outside(path) -> InputError:
    return InputError(path, "(folder)", f"leads outside the output folder ({os.path.realpath(path)})",
                      hint=f"remove the link, or run with {ALLOW_OUTSIDE_OPTION} if you made it")


def check_output(out: str | os.PathLike, allow_outside: bool = False) -> None:
    """What a run would refuse in an output folder, checked without creating anything (``--check`` and the start
    of every run): ``out`` not a folder; ``conditions/`` or ``generated/`` not a folder or leading outside ``out``
    (unless ``allow_outside``); ``backend.log`` a symbolic link or not a regular file. InputError names it."""
    if not os.path.lexists(out):
        return
    if not os.path.isdir(out):
        raise InputError(out, "output_dir", "exists and is not a folder", hint="remove it or choose another "
                                                                               "output folder")
    layout = OutputLayout(out)
    for name in OutputLayout.FOLDERS:
        path = os.path.join(out, name)
        if not os.path.lexists(path):
            continue
        if not allow_outside and not inside(path, out):
            raise _leads_outside(path)
        if not os.path.isdir(path):
            raise InputError(path, "(folder)", "exists and is not a folder")
    check_log(layout.log)


def remove_listed(folder: str | os.PathLike, names: Iterable[str]) -> int:
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


