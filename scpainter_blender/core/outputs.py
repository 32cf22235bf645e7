"""Writing outputs safely (issue 14): whole files or none, never through a planted link, never outside the folder.

- ``atomic_write`` / ``atomic_path``: a unique temporary file (``O_EXCL | O_NOFOLLOW``, never a planted link) in the
  target folder, renamed over the target when complete; nothing half-written survives an error. Both work relative
  to the folder opened once (``open_folder``): a folder of the output tree swapped for a link after it was checked
  receives nothing. ``atomic_folder`` the same for a folder built whole (a checkpoint, a clip, a cached street);
  with ``replace`` and a ``record`` (an export) it replaces only a folder holding nothing but the files its record
  lists (``foreign_files``: a command never deletes or replaces what it did not create). ``write_json`` is the one
  JSON writer (strict: NaN/inf refused). ``remove_temporaries`` removes the temporary files a killed run left.
- Log files: ``append_text`` never appends through a symbolic or hard link; ``check_log`` refuses one beforehand.
- Confinement: ``confined``, a job's paths may not leave the job's folder (``..`` or a symlink) except into a data
  root the user trusts (``--data-root``: ``data_root``, ``data_roots_option``), unless the user allows everything
  (``--allow-outside``); ``inside`` is the test.
- Output folders: ``make_folder``, ``output_folder`` (``conditions/``, ``generated/`` may not lead elsewhere),
  ``own_folder`` (a command's own folder in an output tree, never through a link: ``vNNNN/``, ``export/``),
  ``check_output`` (what a run would refuse, checked without creating anything), ``remove_listed`` (the files a
  record of this program's outputs lists, and nothing else).

Bad outputs (a file in the way, a link) raise ``errors.InputError`` naming the path. One run per output folder is
``core.locking``; the names in an output folder are ``core.output_layout``.

Why one module over 400 lines: every write of the project goes through it, and its parts share one state and one
rule: the folders of an output tree this process checked (``_FOLDERS``), opened once by ``open_folder`` for every
write, rename and deletion (atomic files and folders, clean-up, own folders). Split, that registry would be shared
across modules and a new writer could bypass it. stdlib only (no bpy): the add-on and
the backend share it.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import secrets
import shutil
import stat
import tempfile
from typing import TYPE_CHECKING

from .errors import DISK_FULL_ERRNOS, ArgumentError, InputError
from .user_cache import user_cache_dir  # noqa: F401  (outputs.user_cache_dir: its callers' name for it)
from . import files
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
    """Yields a fresh temporary path in ``path``'s folder (created exclusively with ``O_NOFOLLOW``: a unique name,
    so a planted file or link is never written through); on success it is renamed over ``path`` (a link at
    ``path`` is replaced, not followed), on any error removed; a folder at ``path`` is an InputError naming it. For
    writers that open by name (PyAV, safetensors).

    The folder is opened once (``open_folder``: a folder this process made with ``output_folder`` /
    ``own_folder`` must still be that folder, not a link swapped in for it) and the rename happens relative to that
    descriptor; for such a folder the path yielded is ``/proc/self/fd/N/<temporary>`` (Linux), so a folder swapped
    for a link after the check still receives nothing."""
    with _temporary(path) as (dfd, folder, tmp):
        checked = dfd is not None and _registered_above(os.path.abspath(folder)) is not None
        yield _fd_path(dfd, folder, tmp) if checked else os.path.join(folder, tmp)


@contextlib.contextmanager
def _temporary(path: str | os.PathLike) -> Iterator[tuple]:
    """``atomic_path``'s work: yields (descriptor of the folder, the folder, the temporary's name in it)."""
    path = os.fspath(path)
    folder, name = os.path.split(os.path.abspath(path))
    dfd = open_folder(folder)
    try:
        tmp = _create_temporary(dfd, folder, name)
        try:
            yield dfd, folder, tmp
            try:
                if dfd is None:
                    os.replace(os.path.join(folder, tmp), os.path.join(folder, name))
                else:
                    os.replace(tmp, name, src_dir_fd=dfd, dst_dir_fd=dfd)
            except IsADirectoryError:  # a file is never renamed over a folder
                raise InputError(path, "(file)", "is a folder where this output file goes",
                                 hint="move or remove the folder, then run again") from None
        except BaseException as e:
            with contextlib.suppress(OSError):
                where, at = _at(dfd, folder, tmp)
                os.remove(where, **at)
            if isinstance(e, OSError):
                _name_output(e, path, dfd)
            raise
    finally:
        _close(dfd)


def _at(dfd: int | None, folder: str, name: str) -> tuple:
    """The arguments naming ``name`` in a folder opened by ``open_folder``: ``(name,)`` and its descriptor, or the
    joined path where the system has no ``*at`` calls (``dfd`` None)."""
    return (name, {"dir_fd": dfd}) if dfd is not None else (os.path.join(folder, name), {})


def _close(dfd: int | None) -> None:
    if dfd is not None:
        os.close(dfd)


def _create_temporary(dfd: int | None, folder: str, name: str) -> str:
    """A new empty file ``.<name>.<random>.tmp`` in the folder ``dfd`` (``O_CREAT | O_EXCL | O_NOFOLLOW``; the
    user's usual permissions, 0666 less the umask), closed; returns its name."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    for _ in range(100):
        tmp = f"{_temporary_prefix(name)}{secrets.token_hex(4)}{_TEMPORARY_SUFFIX}"
        try:
            where, at = _at(dfd, folder, tmp)
            os.close(os.open(where, flags, 0o666, **at))
            return tmp
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", name)


def _name_output(e: OSError, path: str, dfd: int | None) -> None:
    """Make the error of a write into ``path``'s temporary name ``path``: a write's error (a full disk) names no
    file, and a copy's (``shutil``: ``filename2``) or a writer's opened by name names the folder's descriptor alias
    (``/proc/self/fd/N/...``, ``_fd_path``), a path the user never gave."""
    alias = f"/proc/self/fd/{dfd}/" if dfd is not None else None
    if e.filename is None:
        e.filename = path
    for attr in ("filename", "filename2"):
        value = getattr(e, attr)
        if alias and isinstance(value, (str, bytes)) and os.fsdecode(value).startswith(alias):
            setattr(e, attr, path)


def _fd_path(dfd: int, folder: str, name: str) -> str:
    """A path naming ``name`` in the folder open as ``dfd`` itself (``/proc/self/fd/N/name`` where the system has
    it), else in ``folder`` by name."""
    proc = f"/proc/self/fd/{dfd}"
    return os.path.join(proc if os.path.isdir(proc) else folder, name)


#: The folders this process made or checked in an output tree (``output_folder``, ``own_folder``): absolute path
#: -> (st_dev, st_ino). ``open_folder`` refuses one that is no longer that folder (swapped for a link meanwhile).
_FOLDERS: dict = {}


def _register(path: str, st: os.stat_result) -> None:
    path = os.path.abspath(path)
    if _FOLDERS.get(path) != (st.st_dev, st.st_ino):
        _forget(path, itself=False)   # a new folder at this name: what was known below the old one no longer holds
    _FOLDERS[path] = (st.st_dev, st.st_ino)


def _forget(path: str, itself: bool = True) -> None:
    """Drop ``path`` (with ``itself``) and every folder registered below it from ``_FOLDERS``."""
    below = path.rstrip(os.sep) + os.sep
    for known in [k for k in _FOLDERS if k.startswith(below) or (itself and k == path)]:
        del _FOLDERS[known]


def _registered_above(folder: str) -> str | None:
    """The nearest folder of ``_FOLDERS`` that is ``folder`` (absolute) or holds it, or None: where a checked
    walk to ``folder`` starts."""
    p = folder
    while p not in _FOLDERS:
        up = os.path.dirname(p)
        if up == p:
            return None
        p = up
    return p


def _replaced(folder: str) -> InputError:
    return InputError(folder, "(folder)", "was replaced while this command ran (a link or another folder put in "
                                          f"its place, now leading to {os.path.realpath(folder)}): nothing is "
                                          "written through it", hint="remove what was put there, then run again")


_DIR_FLAGS = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0)


def _open_walk(folder: str, create: bool = False, allow_outside: bool = False) -> int:
    """A descriptor of the folder ``folder`` (absolute; ``_AT`` systems), reached from the nearest folder this
    process registered (``_registered_above``) one name at a time, never through a link swapped in: that folder is
    opened and must still be the one registered, each name below it is opened relative to its parent with
    ``O_NOFOLLOW`` (``create``: made first, ``mkdir`` relative to the parent, and registered), and a folder
    registered on the way must still be that folder (InputError naming it). A link the user put inside the tree
    is followed only when it leads inside the registered folder (or ``allow_outside``), as ``output_folder``
    allows. Without a registered folder above, ``folder`` is opened by path (``create``: ``os.makedirs``).

    ``create`` (making folders, ``make_folder``) accepts a registered folder that is now another real folder (not
    a link): removed and made again by the user between two runs of one process (the add-on, tests); nothing is
    written through a link either way."""
    top = _registered_above(folder)
    if top is None:
        if create:
            os.makedirs(folder, exist_ok=True)
        return os.open(folder, _DIR_FLAGS)
    try:
        fd = os.open(top, _DIR_FLAGS)
    except FileNotFoundError:
        if not create or os.path.lexists(top):
            raise
        _forget(top)   # removed since it was registered: made anew
        return _open_walk(folder, create, allow_outside)
    except NotADirectoryError:
        raise InputError(top, "(folder)", "exists and is not a folder") from None
    st = os.fstat(fd)
    if (st.st_dev, st.st_ino) != _FOLDERS[top]:
        if not create or os.path.islink(top):
            os.close(fd)
            raise _replaced(top)
        _register(top, st)
    here = top
    try:
        for name in ([] if folder == top else os.path.relpath(folder, top).split(os.sep)):
            here = os.path.join(here, name)
            made = False
            if create:
                with contextlib.suppress(FileExistsError):
                    os.mkdir(name, 0o777, dir_fd=fd)
                    made = True
            try:
                sub = os.open(name, _DIR_FLAGS | getattr(os, "O_NOFOLLOW", 0), dir_fd=fd)
            except OSError:
                try:
                    os.readlink(name, dir_fd=fd)
                except OSError:
                    raise   # not a link: missing, or not a folder
                if not allow_outside and not inside(here, top):
                    raise _leads_outside(here) from None
                sub = os.open(here, _DIR_FLAGS)   # a link inside the tree, as output_folder allows
            os.close(fd)
            fd = sub
            st, expected = os.fstat(fd), _FOLDERS.get(here)
            if made or (create and expected != (st.st_dev, st.st_ino)):
                _register(here, st)
            elif expected is not None and expected != (st.st_dev, st.st_ino):
                raise _replaced(here)
    except BaseException:
        os.close(fd)
        raise
    return fd


#: Whether this system works relative to a folder's descriptor (``openat``, ``renameat``, ...: POSIX); elsewhere
#: (Windows, which has no symbolic links a user makes without privileges) by path, the folder's identity checked.
_AT = hasattr(os, "O_DIRECTORY") and {os.open, os.rename, os.unlink, os.mkdir, os.stat} <= os.supports_dir_fd


def open_folder(folder: str | os.PathLike) -> int | None:
    """A descriptor of the folder ``folder`` (``O_DIRECTORY``), for work relative to it. When this process made
    or checked it as part of an output tree (``output_folder``, ``own_folder``), the folder opened must be that
    very folder (device and inode): one swapped for a symbolic link, or another folder, since is an InputError
    naming it, and nothing is written there. A folder below a registered one (``make_folder``'s subfolders, a
    writer's folders in ``atomic_folder``'s staging folder) is reached from it name by name (``_open_walk``):
    swapping any folder on the way for a link is found too. None where the system has no ``*at`` calls (``_AT``): the identity
    is then checked by path."""
    folder = os.path.abspath(os.fspath(folder))
    if not _AT:
        st = os.stat(folder)
        if _FOLDERS.get(folder, (st.st_dev, st.st_ino)) != (st.st_dev, st.st_ino) or not stat.S_ISDIR(st.st_mode):
            raise InputError(folder, "(folder)", "was replaced while this command ran: nothing is written through it",
                             hint="remove what was put there, then run again")
        return None
    try:
        return _open_walk(folder)
    except NotADirectoryError:
        raise InputError(folder, "(folder)", "exists and is not a folder") from None


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike, keep_existing: bool = False, replace: bool = False,
                  usual_mode: bool = False, record: str | None = None) -> Iterator[str]:
    """Yields a fresh empty folder beside ``path`` (``mkdtemp``: ``.<name>.<random>.tmp``, a unique name, mode 0700
    as mkdtemp makes it); when the block ends without an error it is renamed to ``path``, on any error removed with
    everything in it, so ``path`` appears whole or not at all. The parent folder must exist. ``keep_existing``:
    when ``path`` appeared meanwhile (another process finished first), ours is removed and theirs kept; otherwise
    the rename's OSError is raised (``path`` a folder that is not empty). ``usual_mode``: the folder gets the
    permissions a new folder would (0777 less the umask) before it is renamed.

    ``replace`` (with ``record``, the name of the JSON object the caller writes into the folder: an export's
    ``export.json``): the folder is a command's own, replaced whole by its next run, and nothing of anyone else's is
    ever deleted or replaced. ``record`` gets a ``CREATED_KEY`` list of every file the folder holds (what this
    command created); an existing ``path`` is replaced only when it holds nothing else (``foreign_files``: checked
    again just before the rename, so a file a user put there while the command ran is found), moved aside and then
    only its recorded files deleted; an existing folder without a record that holds nothing (one the user made) is
    filled, never replaced; anything else is an InputError naming ``path`` and a foreign file, and ``path`` is left
    as it was."""
    path = os.path.abspath(os.fspath(path))
    parent, name = os.path.dirname(path), os.path.basename(path)
    tmp = _staging_folder(parent, name)
    aside = None
    try:
        yield tmp
        if usual_mode:
            os.chmod(tmp, 0o777 & ~_umask())
        if record is not None:
            _record_created(tmp, record)
        if replace and os.path.lexists(path):
            foreign = foreign_files(path, record)
            if foreign:
                raise InputError(path, "(folder)", f"holds files this command did not write ({foreign[0]!r}"
                                 f"{f' and {len(foreign) - 1} more' if len(foreign) > 1 else ''}): it is never "
                                 "replaced", hint="give a new or empty folder, or move those files away")
            if record is None or not os.path.lexists(os.path.join(path, record)):
                _move_into(tmp, path, record)   # a folder the user made, empty: filled, never replaced
                return
            aside = tempfile.mkdtemp(prefix=_temporary_prefix(name), suffix=".old" + _TEMPORARY_SUFFIX, dir=parent)
            os.rename(path, os.path.join(aside, name))
        try:
            _close(open_folder(tmp))   # still the staging folder made (not a link swapped in): else InputError
            os.rename(tmp, path)
            _forget(tmp)
            _forget(path)   # a new folder now has the name: a record of an earlier one no longer holds
        except OSError:
            if aside is not None and not os.path.lexists(path):
                os.rename(os.path.join(aside, name), path)
                aside = None
            if not (keep_existing and os.path.isdir(path)):
                raise
    finally:  # after an error, or when theirs was kept (renamed, it is gone); the replaced folder once it is
        if os.path.isdir(tmp) and not os.path.islink(tmp):
            shutil.rmtree(tmp, ignore_errors=True)
        _forget(tmp)
        if aside is not None:
            _remove_recorded(os.path.join(aside, name), record)
            with contextlib.suppress(OSError):
                os.rmdir(aside)   # kept (with what a user put there at the last instant) unless it is empty


def _staging_folder(parent: str, name: str) -> str:
    """A new folder ``.<name>.<random>.tmp`` (mode 0700, as ``mkdtemp`` makes it) in ``parent``, made relative to
    ``parent`` opened by ``open_folder`` (a registered parent swapped for a link is an InputError) and registered:
    the folders and files a writer makes in it are checked (``make_folder``, ``atomic_write``), so a staging folder
    swapped for a link after it was made receives nothing. Returns its path."""
    if not _AT:
        return tempfile.mkdtemp(prefix=_temporary_prefix(name), suffix=_TEMPORARY_SUFFIX, dir=parent)
    pfd = open_folder(parent)
    try:
        for _ in range(100):
            tmp = f"{_temporary_prefix(name)}{secrets.token_hex(4)}{_TEMPORARY_SUFFIX}"
            try:
                os.mkdir(tmp, 0o700, dir_fd=pfd)
                break
            except FileExistsError:
                continue
        else:
            raise FileExistsError(errno.EEXIST, "no free temporary name", os.path.join(parent, name))
        try:
            fd = os.open(tmp, _DIR_FLAGS | getattr(os, "O_NOFOLLOW", 0), dir_fd=pfd)
        except OSError:   # swapped for a link (or a file) the instant after it was made: nothing goes there
            raise _replaced(os.path.join(parent, tmp)) from None
        try:
            _register(os.path.join(parent, tmp), os.fstat(fd))
        finally:
            os.close(fd)
    finally:
        _close(pfd)
    return os.path.join(parent, tmp)


#: The key of a folder's record (``atomic_folder``'s ``record``) listing the files the command created in it.
CREATED_KEY = "files"


def tree_files(folder: str) -> list:
    """Every file, link or other non-folder below ``folder``, as relative paths with ``/``; links are not
    followed (a link to a folder is a file here)."""
    out = []
    for root, dirs, names in os.walk(folder, followlinks=False):
        rel = os.path.relpath(root, folder)
        links = [d for d in dirs if os.path.islink(os.path.join(root, d))]
        dirs[:] = [d for d in dirs if d not in links]
        out += [n if rel == "." else f"{rel}/{n}".replace(os.sep, "/") for n in names + links]
    return sorted(out)


def _record_created(folder: str, record: str) -> None:
    """Add ``CREATED_KEY`` (every file of ``folder`` but the record) to the record the caller wrote there."""
    rec_path = os.path.join(folder, record)
    with files.confined_reads(None):   # the command's own file, wherever its destination is
        content = files.read_json(rec_path)
    content[CREATED_KEY] = [f for f in tree_files(folder) if f != record]
    write_json(rec_path, content)


def created_files(folder: str | os.PathLike, record: str | None) -> set | None:
    """The files ``folder``'s ``record`` says its command created (``CREATED_KEY``), None without a readable one."""
    if record is None:
        return None
    try:
        with files.confined_reads(None):   # a destination's record: read wherever the destination is
            content = files.read_json(os.path.join(folder, record))
    except InputError:
        return None
    listed = content.get(CREATED_KEY) if isinstance(content, dict) else None
    if not isinstance(listed, list) or not all(isinstance(f, str) for f in listed):
        return None
    return set(listed)


def foreign_files(folder: str | os.PathLike, record: str | None) -> list:
    """The files of an existing ``folder`` that its ``record`` does not list as created by this program (all but the
    record itself when it lists none, or there is none: a record planted in a user's folder protects nothing);
    ``[]``: the folder may be replaced. A link or a file at ``folder`` itself is ``[folder]``."""
    folder = os.fspath(folder)
    if os.path.islink(folder) or not os.path.isdir(folder):
        return [folder]
    mine = created_files(folder, record) or set()
    return [f for f in tree_files(folder) if f not in mine and f != record]


def _move_into(src: str, dst: str, record: str | None) -> None:
    """Every entry of the folder ``src`` into the existing folder ``dst`` without replacing anything there (a new
    file is a hard link made exclusively, a new folder ``mkdir``): what appears meanwhile in ``dst`` is never
    overwritten (an InputError naming it). The record last, so the folder is marked as this command's only once
    it holds everything."""
    names = sorted(os.listdir(src), key=lambda n: n == record)
    for n in names:
        s, d = os.path.join(src, n), os.path.join(dst, n)
        try:
            if os.path.isdir(s) and not os.path.islink(s):
                os.mkdir(d)
                _move_into(s, d, None)
            else:
                os.link(s, d, follow_symlinks=False)
        except FileExistsError:
            raise InputError(d, "(file)", "appeared while this command ran: it is never replaced",
                             hint="move it away and run again") from None


def _remove_recorded(folder: str, record: str | None) -> None:
    """Delete the files ``folder``'s record lists (and the record), then the folders left empty; anything else
    stays (the folder too, then)."""
    mine = (created_files(folder, record) or set()) | ({record} if record else set())
    for f in tree_files(folder):
        if f in mine:
            with contextlib.suppress(OSError):
                os.remove(os.path.join(folder, *f.split("/")))
    for root, _, _ in sorted(os.walk(folder, followlinks=False), key=lambda w: -len(w[0])):
        with contextlib.suppress(OSError):
            os.rmdir(root)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO]:
    """``with atomic_write(path, "w") as f:`` — ``f`` writes a temporary file that replaces ``path`` only when the
    block ends without an error (see ``atomic_path``)."""
    with _temporary(path) as (dfd, folder, tmp):
        # opened in the folder's descriptor; O_NOFOLLOW: the fresh name is ours, but a link swapped in for it in a
        # shared folder is not followed
        where, at = _at(dfd, folder, tmp)
        with open(where, mode, **({} if "b" in mode else {"encoding": "utf-8"}),
                  opener=lambda p, flags: os.open(p, flags | getattr(os, "O_NOFOLLOW", 0), 0o600, **at)) as f:
            yield f


def json_text(value: object, indent: int | None = 1) -> str:
    """The text ``write_json`` writes for ``value`` (strict: NaN/inf refused), final newline included."""
    return json.dumps(value, indent=indent, allow_nan=False) + "\n"


def write_json(path: str | os.PathLike, value: object, indent: int | None = 1) -> None:
    """``value`` as JSON (strict: NaN/inf refused), atomically."""
    text = json_text(value, indent)
    with atomic_write(path, "w") as f:
        f.write(text)


def remove_temporaries(folder: str | os.PathLike, names: Iterable[str], folders: bool = False) -> int:
    """Delete what ``atomic_path`` left for the targets ``names`` in ``folder`` when a process was killed
    (``.<name>.<random>.tmp``); only those names' temporaries, for a caller holding the folder's lock. Relative to
    the folder opened once (``open_folder``): a folder swapped for a link meanwhile loses nothing. ``folders``:
    also the temporary folders ``atomic_folder`` left for them (removed with what they hold; a link never
    followed)."""
    prefixes = tuple(_temporary_prefix(n) for n in names)
    removed = 0
    try:
        dfd = open_folder(folder)
    except (OSError, InputError):
        return 0
    try:
        for entry in os.listdir(folder if dfd is None else dfd):
            if entry.endswith(_TEMPORARY_SUFFIX) and entry.startswith(prefixes) and "/" not in entry:
                with contextlib.suppress(OSError):
                    where, at = _at(dfd, os.fspath(folder), entry)
                    if stat.S_ISLNK(mode := os.lstat(where, **at).st_mode) or stat.S_ISREG(mode):
                        os.remove(where, **at)
                        removed += 1
                    elif folders and stat.S_ISDIR(mode) and dfd is not None:
                        shutil.rmtree(entry, dir_fd=dfd)   # never follows a link inside it
                        removed += 1
                    elif folders and stat.S_ISDIR(mode):
                        shutil.rmtree(where)
                        removed += 1
    finally:
        _close(dfd)
    return removed


def link_or_copy(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """``dst`` as a hard link to ``src`` where the file system allows (multi-GB model weights cost nothing), a
    copy with its metadata otherwise (another device, a file system without links)."""
    folder, name = os.path.split(os.path.abspath(os.fspath(dst)))
    dfd = open_folder(folder)   # a folder of an output tree swapped for a link: InputError, nothing linked there
    try:
        where, at = _at(dfd, folder, name)
        os.link(src, where, **({"dst_dir_fd": dfd} if at else {}))
        return
    except OSError:
        pass
    finally:
        _close(dfd)
    with atomic_path(dst) as tmp:   # a copy, written as every output is
        shutil.copy2(src, tmp)


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
_HARD_LINKED_LOG = ("has other hard links (another name of the same file, maybe outside the output folder): the log "
                    "is not written through links")


def append_text(path: str | os.PathLike, text: str) -> None:
    """Append to a log file, never through a link: InputError if ``path`` is a symbolic link (``O_NOFOLLOW``) or a
    file with more than one hard link (checked on the open descriptor: another name of a user's file)."""
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    folder, name = os.path.split(os.path.abspath(os.fspath(path)))
    try:
        dfd = open_folder(folder)   # the output folder swapped for a link since it was made: InputError
        try:
            where, at = _at(dfd, folder, name)
            fd = os.open(where, flags | NONBLOCK, 0o666, **at)  # a FIFO without a reader fails at once (ENXIO)
        finally:
            _close(dfd)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise InputError(path, "(file)", _LINKED_LOG, hint="remove the link") from None
        if e.errno in (errno.ENXIO, errno.EISDIR):
            raise InputError(path, "(file)", _IRREGULAR_LOG, hint="remove it, or choose another output folder") \
                from None
        raise
    # a file name that is not UTF-8 (its bytes kept as surrogates) is written as \udcff: the log stays UTF-8 text
    with os.fdopen(fd, "a", encoding="utf-8", errors="backslashreplace") as f:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise InputError(path, "(file)", _IRREGULAR_LOG)
        if st.st_nlink > 1:
            raise InputError(path, "(file)", _HARD_LINKED_LOG, hint="remove it (the other name keeps the file)")
        f.write(text)


def check_log(path: str | os.PathLike) -> None:
    """InputError if the log file ``path`` exists as a symbolic link or a file with other hard links (never appended
    through) or as anything but a regular file; a missing one is fine (it is created)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    mode = st.st_mode
    if stat.S_ISLNK(mode):
        raise InputError(path, "(file)", _LINKED_LOG, hint="remove the link")
    if not stat.S_ISREG(mode):
        raise InputError(path, "(file)", _IRREGULAR_LOG)
    if st.st_nlink > 1:
        raise InputError(path, "(file)", _HARD_LINKED_LOG, hint="remove it (the other name keeps the file)")


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

def make_folder(path: str | os.PathLike, field: str = "(folder)", root: bool = False,
                allow_outside: bool = False) -> str:
    """``os.makedirs(path, exist_ok=True)``, with InputError naming the folder when it cannot be made (a file or a
    FIFO in the way, a name too long, no permission). Below a folder of an output tree (registered: ``root``,
    ``output_folder``, ``own_folder``, ``atomic_folder``'s staging folder) the folders are made and opened name by
    name relative to it (``_open_walk``) and registered in turn: a folder on the way swapped for a link (or a
    link there leading outside the tree, unless ``allow_outside``) is an InputError naming it, and nothing is
    made through it. ``root``: ``path`` is the root of a command's output tree (``output_dir``, ``vary --out``),
    registered so that every later write in it is checked the same way."""
    path = os.fspath(path)
    full = os.path.abspath(path)
    if not _AT:
        _make_by_path(path, field)
        if root:
            _register(full, os.stat(full))
        return path
    try:
        fd = _open_walk(full, create=True, allow_outside=allow_outside)
    except (FileExistsError, NotADirectoryError):
        raise InputError(path, field, "exists and is not a folder", hint="remove it or choose another output "
                                                                         "folder") from None
    except OSError as e:
        if e.errno in DISK_FULL_ERRNOS:  # not the folder's fault: the backend names the full disk
            raise
        raise InputError(path, field, f"cannot be made: {e.strerror or e}") from None
    try:
        if root:
            _register(full, os.fstat(fd))
    finally:
        os.close(fd)
    return path


def _make_by_path(path: str, field: str) -> None:
    """``make_folder`` where the system has no ``*at`` calls."""
    try:
        os.makedirs(path, exist_ok=True)
    except FileExistsError:
        raise InputError(path, field, "exists and is not a folder", hint="remove it or choose another output "
                                                                         "folder") from None
    except OSError as e:
        if e.errno in DISK_FULL_ERRNOS:
            raise
        raise InputError(path, field, f"cannot be made: {e.strerror or e}") from None
    if not os.path.isdir(path):
        raise InputError(path, field, "exists and is not a folder")


def output_folder(parent: str | os.PathLike, name: str, allow_outside: bool = False) -> str:
    """``parent/name`` created if missing; InputError if it is a symbolic link (or lies) outside ``parent``
    unless ``allow_outside``: a link planted in an output folder must not carry writes elsewhere. The folder found
    is remembered (``open_folder``): swapped for a link later in the run, it receives nothing; made below a
    registered ``parent`` (``make_folder``), a ``parent`` swapped meanwhile is found too."""
    path = os.path.join(parent, name)
    make_folder(path, allow_outside=allow_outside)
    if not allow_outside and not inside(path, parent):
        raise _leads_outside(path)
    _register(path, os.stat(path))
    return path


def remove_own_folder(parent: str | os.PathLike, name: str) -> None:
    """Delete ``parent/name``, a folder of a command's own output tree, with everything in it: opened first as
    ``own_folder`` opens it (a link there is an InputError, never followed), forgotten by ``open_folder`` after."""
    path = own_folder(parent, name)
    shutil.rmtree(path, ignore_errors=True)
    _FOLDERS.pop(path, None)


def own_folder(parent: str | os.PathLike, name: str, field: str = "(folder)") -> str:
    """``parent/name``, a folder of a command's own output tree (``vary``'s variant folders and ``library/``,
    ``export``'s ``export/``), made if missing (``mkdir`` relative to ``parent``, never through a link) and
    otherwise opened without following a link at ``name``: a symbolic link there (planted, wherever it leads) or a
    file is an InputError naming it. Remembered like ``output_folder``'s. Returns the path."""
    path = os.path.join(os.path.abspath(os.fspath(parent)), name)
    pfd = open_folder(parent)
    try:
        where, at = _at(pfd, os.path.dirname(path), name)
        with contextlib.suppress(FileExistsError):
            os.mkdir(where, 0o777, **at)
        if pfd is None:   # by path (no *at calls): what is there must be a folder, not a link
            if os.path.islink(path) or not os.path.isdir(path):
                what = "a symbolic link" if os.path.islink(path) else "not a folder"
                raise InputError(path, field, f"is {what}: an output folder is never written through a link",
                                 hint="remove it, then run again")
            _register(path, os.stat(path))
            return path
        try:
            fd = os.open(name, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_NOFOLLOW", 0)
                         | getattr(os, "O_CLOEXEC", 0), dir_fd=pfd)
        except OSError as e:
            if os.path.islink(path):
                raise InputError(path, field, f"is a symbolic link (to {os.readlink(path)}): an output folder is "
                                              "never written through a link",
                                 hint="remove the link, then run again") from None
            raise InputError(path, field, f"cannot be used as a folder: {e.strerror or e}",
                             hint="remove or move it, then run again") from None
        try:
            _register(path, os.fstat(fd))
        finally:
            os.close(fd)
    finally:
        _close(pfd)
    return path


def _leads_outside(path) -> InputError:
    return InputError(path, "(folder)", f"leads outside the output folder ({os.path.realpath(path)})",
                      hint=f"remove the link, or run with {ALLOW_OUTSIDE_OPTION} if you made it")


def name_too_long(path: str | os.PathLike) -> str | None:
    """Which part of ``path`` (absolute) is longer than the file system allows, said in words, or None: a name
    beyond ``NAME_MAX`` bytes of the nearest existing folder's file system (``os.pathconf``; 255 where it cannot be
    asked), or the whole path beyond its ``PATH_MAX``. So ``--check`` refuses what the run would fail on
    (``ENAMETOOLONG``) without making anything."""
    path = os.path.abspath(os.fspath(path))
    existing = path
    while not os.path.isdir(existing) and os.path.dirname(existing) != existing:
        existing = os.path.dirname(existing)
    limits = {}
    for key, default in (("PC_NAME_MAX", 255), ("PC_PATH_MAX", 4096)):
        try:
            limits[key] = os.pathconf(existing, key)
        except (OSError, ValueError, AttributeError):
            limits[key] = default
    for part in path.split(os.sep):
        if len(os.fsencode(part)) > limits["PC_NAME_MAX"]:
            return f"{part[:20]}… is {len(os.fsencode(part))} bytes, at most {limits['PC_NAME_MAX']}"
    if len(os.fsencode(path)) >= limits["PC_PATH_MAX"]:
        return f"the path is {len(os.fsencode(path))} bytes, at most {limits['PC_PATH_MAX'] - 1}"
    return None


def check_output(out: str | os.PathLike, allow_outside: bool = False) -> None:
    """What a run would refuse in an output folder, checked without creating anything (``--check`` and the start
    of every run): ``out`` not a folder; ``conditions/`` or ``generated/`` not a folder or leading outside ``out``
    (unless ``allow_outside``); ``backend.log`` a symbolic link or not a regular file; a folder still to be made
    whose name is longer than its file system allows (``name_too_long``). InputError names it."""
    if not os.path.lexists(out):
        if (long := name_too_long(out)) is not None:
            raise InputError(out, "output_dir", f"has a name longer than its file system allows ({long})",
                             hint="choose a shorter output folder name")
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
    Relative to the folder opened once (``open_folder``: one this process made, swapped for a link since, is an
    InputError). Returns how many were removed."""
    removed = 0
    try:
        dfd = open_folder(folder)
    except FileNotFoundError:
        return 0
    try:
        for name in names:
            if not isinstance(name, str) or not name or name in (".", "..") or os.sep in name or "/" in name or \
                    (os.altsep and os.altsep in name) or "\0" in name:  # a NUL makes os calls raise ValueError
                continue
            with contextlib.suppress(FileNotFoundError, IsADirectoryError, PermissionError):
                where, at = _at(dfd, os.fspath(folder), name)
                mode = os.lstat(where, **at).st_mode
                if stat.S_ISLNK(mode) or stat.S_ISREG(mode):
                    os.remove(where, **at)
                    removed += 1
    finally:
        _close(dfd)
    return removed
