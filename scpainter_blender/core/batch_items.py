"""What the batch commands share (``python -m backend batch`` and ``blender -c scpainter batch``): the ``--list``
file of job or scene paths (its format, and the ``data-root:`` line of the backend's lists: ``read_job_list``),
which items one rank of a multi-process run takes (``--shard`` or the environment), the ``--ray`` options, which
items name one job (``first_items``), which would write another job's output folder (``shared_output_items``) and
the summary's counts. No bpy, no torch.

Just over 400 lines, as one module: the list file is written (``write_job_list``, by ``vary``) and read here with one
rule for what a line may hold, and both batch command lines (the backend's and Blender's) take their options and
shards from here; split, the writer and the reader of one format would drift."""

from __future__ import annotations

import dataclasses
import math
import os
import unicodedata

from . import backend_protocol, errors, files, outputs

#: ``--ray``: a job is run again at most this many times after its worker died or it failed unexpectedly (default,
#: and the most ``--retries`` accepts).
DEFAULT_RETRIES = 2
MAX_RETRIES = 100
#: ``--cpus-per-job``: what each job asks of a Ray cluster without GPUs (a GPU cluster's jobs take 1 GPU, 1 CPU).
DEFAULT_CPUS_PER_JOB = 1.0
#: The cluster addresses ``--ray ADDRESS`` and ``RAY_ADDRESS`` take (what ``ray.init(address=)`` joins): ``auto``
#: (the cluster ``ray start`` started on this machine), ``local`` (a new one here), ``HOST:PORT`` (the head's GCS,
#: port 6379 unless ``ray start --port`` said otherwise) and ``ray://HOST:PORT`` (Ray Client, port 10001).
RAY_ADDRESS_FORMS = ("auto", "local", "HOST:PORT", "ray://HOST:PORT")
#: What to give instead of another address; the dashboard's URL (http://HEAD:8265) is what ``ray job submit`` and
#: the web page take, and is the address people copy.
RAY_ADDRESS_HINT = ("give the cluster's address: ray://HEAD:10001 (Ray Client) or HEAD:6379 (its GCS, as `ray start "
                    "--head` prints it), auto or local; the dashboard's URL http://HEAD:8265 is for `ray job submit`, "
                    "not for joining the cluster")


def check_ray_options(retries: int | None, cpus_per_job: float | None) -> None:
    """The ``--ray`` options both batch commands take, checked before any work: ``--retries`` an integer in
    [0, ``MAX_RETRIES``], ``--cpus-per-job`` a finite number above 0 (whether a node has that many CPUs is the
    cluster's to say: ``backend.batch.ray_pool``). ``ArgumentError`` naming the option."""
    if isinstance(retries, bool) or not isinstance(retries, int) or not 0 <= retries <= MAX_RETRIES:
        raise errors.ArgumentError("--retries", f"expected an integer in [0, {MAX_RETRIES}], got {retries!r}")
    if isinstance(cpus_per_job, bool) or not isinstance(cpus_per_job, (int, float)) \
            or not math.isfinite(cpus_per_job) or not cpus_per_job > 0:
        raise errors.ArgumentError("--cpus-per-job", f"expected a finite number of CPUs above 0, got {cpus_per_job!r}",
                                  hint="e.g. --cpus-per-job 4 for jobs that use 4 threads each")


def ray_address_problem(address: str) -> str | None:
    """Why ``address`` is none of the ``RAY_ADDRESS_FORMS``, or None: a web URL (http/https: the dashboard's),
    another scheme, a HOST:PORT without a host or with a port outside 1-65535. Whether a head answers there is
    ``backend.batch.ray_pool``'s to find out."""
    given = address.strip()
    if given in ("auto", "local"):
        return None
    scheme, sep, rest = given.partition("://")
    if sep and scheme.lower() in ("http", "https"):
        return (f"{given!r} is a web address (the Ray dashboard's, where Ray Jobs are submitted), not the address "
                "of a Ray cluster")
    if sep and scheme != "ray":
        return f"{given!r}: {scheme}:// is not a Ray cluster address (expected {', '.join(RAY_ADDRESS_FORMS)})"
    host, colon, port = (rest if sep else given).rpartition(":")
    if not colon or not host or "/" in host or not port.isdigit() or not 0 < int(port) < 65536:
        return f"{given!r}: expected {', '.join(RAY_ADDRESS_FORMS)}, e.g. 10.0.0.5:6379"
    return None


def check_ray_address(address: str | None) -> None:
    """``--ray``'s ADDRESS, or where none is given ("" or None) ``RAY_ADDRESS`` if set, in one of the
    ``RAY_ADDRESS_FORMS``: ``ArgumentError`` naming ``--ray``, or ``InputError`` "(environment)" naming
    ``RAY_ADDRESS``, with ``RAY_ADDRESS_HINT`` (before any cluster is started or joined: Ray itself fails on a
    dashboard URL with an error that read as an internal one)."""
    if address:
        problem = ray_address_problem(address)
        if problem is not None:
            raise errors.ArgumentError("--ray", problem, hint=RAY_ADDRESS_HINT)
        return
    given = os.environ.get("RAY_ADDRESS", "")
    problem = ray_address_problem(given) if given.strip() else None
    if problem is not None:
        raise errors.InputError("(environment)", "RAY_ADDRESS", problem, hint=RAY_ADDRESS_HINT + " (or unset "
                                                                                                "RAY_ADDRESS)")


def ray_options(ray: str | None, retries: int | None = None, cpus_per_job: float | None = None) -> tuple[int, float]:
    """``(retries, cpus_per_job)`` of a batch from its ``--ray``, ``--retries`` and ``--cpus-per-job`` (None: not
    given, the default), checked with ``check_ray_options``, and its address with ``check_ray_address``. Without
    ``--ray`` (``ray`` None) either option would be ignored: ``ArgumentError`` naming it."""
    if ray is None:
        for option, value in (("--retries", retries), ("--cpus-per-job", cpus_per_job)):
            if value is not None:
                raise errors.ArgumentError(option, "applies to --ray only: without it the option would be ignored",
                                          hint="add --ray [ADDRESS], or leave the option out")
    retries = DEFAULT_RETRIES if retries is None else retries
    cpus_per_job = DEFAULT_CPUS_PER_JOB if cpus_per_job is None else cpus_per_job
    if ray is not None:
        check_ray_address(ray)
        check_ray_options(retries, cpus_per_job)
    return retries, cpus_per_job


#: A list file's directive: ``data-root: DIR`` (before its first path, repeatable), a folder its jobs' paths may
#: lead into (``outputs.confined``), relative to the list file's folder.
DATA_ROOT_DIRECTIVE = "data-root:"


@dataclasses.dataclass(frozen=True)
class JobList:
    """A list file as ``read_job_list`` reads it: ``path`` (the file), ``paths`` (its items, absolute where the
    file's were relative) and ``data_roots`` (its ``data-root:`` lines' folders, absolute and checked)."""

    path: str
    paths: list
    data_roots: tuple = ()


def _parse(path) -> tuple[list, list]:
    """A list file's paths (absolute where the file's were relative) and its ``data-root:`` lines, ``(field, DIR
    as written)`` with field ``line N``; blank and ``#`` lines skipped. InputError names the file when it is not a
    regular UTF-8 text file of at most ``files.MAX_JSON_BYTES``, and the line of a ``data-root:`` after a path."""
    base = os.path.dirname(os.path.abspath(path))
    with files.open_regular(path) as f:
        data = f.read(files.MAX_JSON_BYTES + 1)
    if len(data) > files.MAX_JSON_BYTES:
        raise errors.InputError(path, "(file)", "is too large for a list of job paths")
    try:
        # lines end at "\n" alone (and "\r\n"): str.splitlines would also split at other control characters
        lines = [line.removesuffix("\r") for line in data.decode("utf-8-sig").split("\n")]
    except UnicodeDecodeError as e:
        raise errors.InputError(path, "(file)", f"is not UTF-8 text (byte {e.start})") from None
    paths, directives = [], []
    for n, text in enumerate(lines, 1):
        bad = control_character(text)
        if bad is not None:
            # a NUL byte: no path holds one (the system refuses it), a damaged or forged list
            what = "a NUL byte" if bad == "\0" else f"the control character {bad!r}"
            raise errors.InputError(path, f"line {n}", f"holds {what}: a list line is one "
                                                       "path, and a control character in it would change the list's "
                                                       "meaning", hint="rename the file or folder it names")
        text = text.strip()
        if not text or text.startswith("#"):
            continue
        if not text.startswith(DATA_ROOT_DIRECTIVE):
            paths.append(text if os.path.isabs(text) else os.path.join(base, text))
        elif paths:
            raise errors.InputError(path, f"line {n}", f"{DATA_ROOT_DIRECTIVE} after the first path (it applies "
                                                       "to every job of the file)", hint="move it above the paths")
        else:
            directives.append((f"line {n}", text[len(DATA_ROOT_DIRECTIVE):].strip()))
    return paths, directives


def control_character(text: str) -> str | None:
    """The first control character of ``text`` (Unicode category Cc: newlines, NUL, escapes; and the line and
    paragraph separators), None when it has none: what a list file's line and a manifest's name may not hold."""
    for ch in text:
        if unicodedata.category(ch) == "Cc" or ch in "\u2028\u2029":
            return ch
    return None


def list_line(value: str, path: str | os.PathLike, field: str) -> str:
    """``value`` (a path a list file names) as one line of a list file, unchanged in meaning when read back
    (``read_job_list``): no control character (a newline would start a line of its own: another job, or a
    ``data-root:``), no space at either end, not starting with ``#`` or ``DATA_ROOT_DIRECTIVE``. InputError naming
    ``path`` (what the value came from) and ``field`` otherwise."""
    bad = control_character(value)
    problem = (f"holds the control character {bad!r}" if bad is not None else
               "begins or ends with a space" if value != value.strip() else
               f"begins with '#' or '{DATA_ROOT_DIRECTIVE}'" if value.startswith(("#", DATA_ROOT_DIRECTIVE)) else None)
    if problem:
        raise errors.InputError(path, field, f"{value!r} {problem}: written into a list file it would change the "
                                             "list's meaning (another job, or a trusted folder)",
                                hint="rename the file or folder")
    return value


def write_job_list(path: str | os.PathLike, roots: list, items: list, comment: str = "") -> None:
    """Write a list file (``read_job_list``'s format), atomically: ``comment`` (a ``#`` line), a ``data-root:`` line
    per root, then the items; every value checked by ``list_line`` first (InputError naming ``path``)."""
    for field, values in (("data-root", roots), ("(jobs)", items)):
        for v in values:
            list_line(v, path, field)
    with outputs.atomic_write(path, "w") as f:
        if comment:
            f.write(f"# {comment}\n")
        f.writelines(f"{DATA_ROOT_DIRECTIVE} {r}\n" for r in roots)
        f.writelines(f"{p}\n" for p in items)


def read_job_list(path: str | os.PathLike) -> JobList:
    """A ``--list`` file of ``python -m backend batch``. The format: one path a line, relative ones taken from the
    file's folder; blank lines and lines starting with ``#`` are skipped; before the first path, any number of
    ``data-root: DIR`` lines (``DATA_ROOT_DIRECTIVE``; DIR relative to the file's folder): folders the paths of
    the jobs this file lists may lead into besides their own folders (the recording and asset library many
    variant jobs share), as ``--data-root`` allows for every job of a run. Lines end at a newline alone. InputError
    naming the file and the line: a control character in a line (``control_character``), a ``data-root:`` line
    after a path, without a folder, or naming something that is not a folder."""
    path = os.fspath(path)
    base = os.path.dirname(os.path.abspath(path))
    paths, directives = _parse(path)
    roots = []
    for field, value in directives:
        def error(message, field=field):
            return errors.InputError(path, field, f"{DATA_ROOT_DIRECTIVE} {message}",
                                     hint=f"{DATA_ROOT_DIRECTIVE} DIR names an existing folder, relative to the "
                                          "list file's folder")
        if not value:
            raise error("names no folder")
        roots.append(outputs.data_root(os.path.join(base, value), error))
    return JobList(path, paths, tuple(dict.fromkeys(roots)))


def read_list(path: str | os.PathLike) -> list:
    """The paths of a list file that declares nothing (``read_job_list``'s format without ``data-root:`` lines):
    the clip lists of training. A ``data-root:`` line there is an InputError naming the file and the line: it
    would trust nothing, silently."""
    path = os.fspath(path)
    paths, directives = _parse(path)
    if directives:
        raise errors.InputError(path, directives[0][0], f"{DATA_ROOT_DIRECTIVE} applies to the lists of batch jobs "
                                                        "only",
                                hint=f"give the folder on the command line ({outputs.DATA_ROOT_OPTION} DIR) and "
                                     "leave the line out")
    return paths


def bad_input_fields(e: errors.InputError, item: str | None = None) -> dict:
    """A batch item failed by bad input: its ``error`` (the message), ``hint``, ``file`` and ``field`` (either
    batch command's items; the error event's names, ``core.backend_protocol.ERROR_FIELDS``). ``hint`` is the
    error's own, else one saying what to do: for the item's own path (``item``) that names no job file (missing,
    a folder, unreadable), to list job files; for another file, to check that file."""
    hint = e.hint
    if not hint and e.field == "(file)" and item is not None \
            and os.path.abspath(os.fspath(e.path)) == os.path.abspath(os.fspath(item)):
        hint = ("each batch item names a job file (job.json), readable by this user; relative paths in a --list "
                "file are taken from the list file's folder")
    elif not hint:
        hint = f"check {e.path} ({e.field}), then run the batch again: the jobs already finished are skipped"
    return {"error": str(e), "hint": hint, "file": e.path, "field": e.field}


def status_counts(results: list) -> dict:
    """How many batch items ended each way (``ok``, ``failed``, ``stopped``, ``not run (SIGTERM)``:
    ``backend_protocol.ITEM_*``), in the order first met: the ``counts`` of every batch's ``done`` event (the
    backend's and the add-on's)."""
    counts: dict = {}
    for r in results:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    return counts


def summary(results: list) -> dict:
    """The counts of a batch's summary (``backend_protocol.BATCH_SUMMARY_FIELDS``, all but ``command`` and
    ``items``): ``jobs``, then the items that ended ``ok``, ``failed``, ``stopped`` and ``not_run`` (never started:
    SIGTERM or Ctrl-C came first), and ``counts`` (``status_counts``). A run is good only when ``ok`` == ``jobs``."""
    counts = status_counts(results)
    p = backend_protocol
    return {"jobs": len(results), "ok": counts.get(p.ITEM_OK, 0), "failed": counts.get(p.ITEM_FAILED, 0),
            "stopped": counts.get(p.ITEM_STOPPED, 0), "not_run": counts.get(p.ITEM_NOT_RUN, 0), "counts": counts}


def job_identity(path: str | os.PathLike) -> tuple:
    """What makes two spellings of a job path the same job: the job file's identity (``st_dev``, ``st_ino``: a hard
    link, a symbolic link, ``a/./job.json``) and its folder's, where the listed path puts it (the job's relative
    paths, its output folder among them, are taken from the folder of the path as given, not of the file it links
    to: a link in another folder is another job). A path that cannot be looked at (missing, unreadable) is its own
    identity, its absolute spelling: the job reports the error itself."""
    path = os.path.abspath(os.fspath(path))
    try:
        st, folder = os.stat(path), os.stat(os.path.dirname(path))
    except OSError:
        return ("path", os.path.normpath(path))
    return ("file", st.st_dev, st.st_ino, folder.st_dev, folder.st_ino)


def first_items(items: list) -> list:
    """For each item, the index of the first item naming the same job (``job_identity``): its own index for the
    first, an earlier one for a copy (listed again, through a link, or spelled another way)."""
    first: dict = {}
    return [first.setdefault(job_identity(p), i) for i, p in enumerate(items)]


def job_shard(first: list, rank: int, world: int) -> list:
    """The indices of the items one rank of a batch takes (``shard`` of the items by their job): item k goes to the
    rank of its job's first item (``first_items``: ``first[k] % world``), so a job listed twice is run once, by
    one rank, which gives each copy its result. Without copies, ``shard``'s items exactly."""
    if not 0 <= rank < world:
        raise ValueError(f"rank {rank} is not in [0, {world})")
    return [k for k, i in enumerate(first) if i % world == rank]


def folder_identity(path: str | os.PathLike) -> tuple:
    """What makes two spellings of a folder, existing or not, the same folder: ``path`` with its symbolic links
    and ``..`` followed (``os.path.realpath``), known by the ``st_dev``/``st_ino`` of its nearest existing folder
    plus the names below it that do not exist yet (a folder the first job will make is already the second's). A
    path that cannot be looked at (no permission) is its resolved spelling."""
    head, rest = os.path.realpath(os.fspath(path)), []
    while True:
        try:
            st = os.stat(head)
        except (FileNotFoundError, NotADirectoryError):
            head, name = os.path.split(head)
            if not name:
                break
            rest.append(name)
            continue
        except OSError:
            break
        return ("folder", st.st_dev, st.st_ino, tuple(reversed(rest)))
    return ("path", os.path.realpath(os.fspath(path)))


def job_output_dir(path: str | os.PathLike) -> str | None:
    """The output folder the job file at ``path`` names, absolute: its ``output_dir`` taken from the folder of the
    path as given, as the job takes it (``job.resolve``), read from the file's JSON alone. None when the file cannot
    be read or names none: the job then reports its own error when it runs."""
    from . import job as job_mod

    try:
        content = files.read_json(path)
    except (errors.InputError, OSError, ValueError):
        return None
    value = content.get("output_dir") if isinstance(content, dict) else None
    return job_mod.resolve(path, value) if isinstance(value, str) and value.strip() else None


#: What to do when two jobs of a batch write one output folder.
SHARED_OUTPUT_HINT = ("give each job its own output_dir (e.g. a copy with a shorter frame range: out_short), then run "
                      "the batch again")


def shared_output_items(items: list, first: list | None = None) -> dict:
    """``{item index: its failed result's fields}`` for the items a batch refuses before running anything: a job
    that is not an earlier item's job (``first_items``; ``first`` when already known) but names the same output
    folder (``folder_identity`` of ``job_output_dir``, existing or not). Run after the other, it would replace its
    outputs or remove them (a shorter frame range removes the recorded frames the job no longer has), so the later
    item fails as bad input (``bad_input_fields``: the job file, ``output_dir``, the other job,
    ``SHARED_OUTPUT_HINT``). Every process of a sharded batch computes the same from the whole list."""
    first = first_items(items) if first is None else first
    owner: dict = {}
    refused: dict = {}
    for k, i in enumerate(first):
        out = job_output_dir(items[k]) if k == i else None   # a copy shares its job's outcome
        if out is None:
            continue
        j, theirs = owner.setdefault(folder_identity(out), (k, out))
        if j != k:
            same = "" if theirs == out else f" (as {theirs})"
            refused[k] = bad_input_fields(errors.InputError(
                items[k], "output_dir", f"{out} is also the output folder of {items[j]}{same}, another job earlier "
                                        "in this batch: run after it, this job would replace its outputs or remove "
                                        "the frames it does not have", hint=SHARED_OUTPUT_HINT), items[k])
    return refused


def parse_shard(text: str) -> tuple[int, int]:
    """(K, N) from ``--shard K/N`` (either batch command's): ArgumentError unless two integers with 0 <= K < N."""
    try:
        k, n = (int(x) for x in text.split("/"))
    except ValueError:  # (int() of the user's text, or not two parts)
        raise errors.ArgumentError("--shard", f"{text!r}: expected K/N, e.g. 0/4") from None
    if not 0 <= k < n:
        raise errors.ArgumentError("--shard", f"{k}/{n}: K must be in [0, N)")
    return k, n


def shard_option(text: str | None, ray: str | None) -> tuple[int, int] | None:
    """``--shard`` of a batch with its ``--ray`` (None: not given): (K, N), or None when not given; ArgumentError
    when it is bad (``parse_shard``) or given with ``--ray`` (Ray schedules every item itself)."""
    if not text:
        return None
    if ray is not None:
        raise errors.ArgumentError("--shard", "not with --ray: Ray schedules every item",
                                   hint="give each Ray batch its whole list; --shard splits a list over processes")
    return parse_shard(text)


def shard(items: list, rank: int, world: int) -> list:
    """The items of one rank of a batch: every ``world``-th, starting at ``rank`` (deterministic, order kept)."""
    if not 0 <= rank < world:
        raise ValueError(f"rank {rank} is not in [0, {world})")
    return items[rank::world]


def ranks_from_env() -> tuple[int, int, int]:
    """(rank, world size, local rank) from torchrun/accelerate's environment (``RANK``, ``WORLD_SIZE``,
    ``LOCAL_RANK``); (0, 1, 0) without it. A value that is not a non-negative integer (a world size below 1, a
    rank outside it, or a world size above 1 without a rank) is an InputError naming the variable."""
    def get(name, default, lo):
        value = os.environ.get(name, "").strip()
        if not value:
            return default
        try:
            n = int(value)
        except ValueError:
            n = None
        if n is None or n < lo:
            raise errors.InputError("(environment)", name, f"expected an integer >= {lo}, got {value!r}",
                                   hint="torchrun and accelerate set it; unset it to run one process")
        return n

    rank, world, local = get("RANK", 0, 0), get("WORLD_SIZE", 1, 1), get("LOCAL_RANK", 0, 0)
    if world > 1 and not os.environ.get("RANK", "").strip():  # every process would take rank 0's share
        raise errors.InputError("(environment)", "RANK", f"not set, with WORLD_SIZE={world}",
                               hint="start the processes with torchrun or accelerate launch, which set both")
    if rank >= world:
        raise errors.InputError("(environment)", "RANK", f"{rank} is not below WORLD_SIZE ({world})")
    return rank, world, local
