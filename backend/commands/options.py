"""What several commands of ``python -m backend`` share, declared once: the ``--device`` option and its resolution,
the option groups (where a job's paths may lead, ``--check``, Ray), their help texts and the bounded argument
types. Not a command (no ``NAME``).

Imports only the standard library and ``core`` (numpy at most) when a parser is built; torch is imported by
``resolve_device`` alone, when a command runs.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

#: ``--precision`` of generate and evaluate: auto, then the dtypes ``backend.generate.command.PRECISIONS`` maps
#: (not imported here: it needs torch; a test holds the two together).
PRECISION_CHOICES = ("auto", "fp32", "bf16", "fp16")

DEVICE_HELP = "auto: CUDA when torch sees a GPU, else the CPU"
ALLOW_OUTSIDE_HELP = ("let the job's paths (output_dir, predictions, assets, checkpoint) lead anywhere; without it "
                      "they must stay inside the job file's folder or a --data-root (a job from someone else then "
                      "cannot read or write elsewhere)")
DATA_ROOT_HELP = ("a trusted folder (repeatable) the job's paths (output_dir, predictions, assets, checkpoint) may "
                  "lead into besides the job file's folder, e.g. the recording and asset library many variant "
                  "jobs share; symbolic links and .. are followed, so nothing outside it or the job's folder is "
                  "reached")
HALF_FLOAT_HELP = ("store the image I and the masks M, M_a of the condition EXRs as half floats (Z stays float32): "
                   "files ~40%% smaller than the lossless float32 default, error <= 2.4e-4; a change re-renders "
                   "finished frames")


def resolve_device(name: str) -> str:
    """cpu, cuda or auto; CUDA is touched only when asked for (auto or cuda), never at start-up."""
    if name == "cpu":
        return "cpu"
    import torch

    if torch.cuda.is_available():
        return "cuda"
    if name == "cuda":
        from scpainter_blender.core.errors import ArgumentError

        raise ArgumentError("--device", "cuda: torch sees no CUDA GPU on this machine",
                            hint="use --device cpu or auto")
    return "cpu"


def device_option(p: argparse.ArgumentParser, help_text: str | None = DEVICE_HELP) -> None:
    """``--device`` (``core.backend_protocol.DEVICE_NAMES``, default ``DEFAULT_DEVICE``); ``help_text``: what the
    device is for in this command (None: no help line)."""
    from scpainter_blender.core.backend_protocol import DEFAULT_DEVICE, DEVICE_NAMES

    p.add_argument("--device", choices=DEVICE_NAMES, default=DEFAULT_DEVICE, help=help_text)


def bounded_int(lo: int, hi: int) -> Callable[[str], int]:
    """An argparse ``type``: an integer in [lo, hi], else argparse's error naming the option."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"expected an integer in [{lo}, {hi}], got {value}")
        return value
    return parse


def non_negative(text: str) -> float:
    """An argparse ``type``: a finite number of seconds >= 0."""
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return value


def confinement_options(p: argparse.ArgumentParser) -> None:
    """``--allow-outside`` and ``--data-root`` (render, generate, export, batch): where a job's paths may lead
    (``job_inputs.job_paths``)."""
    from scpainter_blender.core import outputs

    p.add_argument(outputs.ALLOW_OUTSIDE_OPTION, action="store_true", help=ALLOW_OUTSIDE_HELP)
    p.add_argument(outputs.DATA_ROOT_OPTION, action="append", metavar="DIR", help=DATA_ROOT_HELP)


def proposals_option(p: argparse.ArgumentParser) -> None:
    """``--proposals accept|ignore|off`` (render, generate, export, batch): what the labels make of the reconstruction's
    objects that nothing labels (``backend/render/proposals.py``)."""
    from scpainter_blender.core.variation.proposals import DEFAULT_MODE, MODES

    p.add_argument("--proposals", choices=MODES, default=DEFAULT_MODE,
                   help="objects of the reconstruction above the road that no recorded object, removal box or car "
                        "covers (found from the points): accept labels each as a recorded object of the class its "
                        "size suggests; ignore (default) makes each an ignore region in every export, with a "
                        "warning naming it; off leaves them unlabelled. Label-only: the layers are kept")


def input_options(p: argparse.ArgumentParser) -> None:
    """``confinement_options`` and ``--check`` (render, generate)."""
    confinement_options(p)
    p.add_argument("--check", action="store_true",
                   help="validate and stop, rendering and loading nothing: the job, its paths, its input files "
                        "from their headers (data corruption shows only when read), the output folder"
                        + (" and the checkpoint" if p.prog.endswith("generate") else ""))


def ray_options(p: argparse.ArgumentParser, what: str) -> None:
    """``--ray [ADDRESS]``, ``--retries`` and ``--cpus-per-job``, the same for ``batch`` and ``evaluate``
    (``backend/batch/ray_pool.py``); ``what``: what runs on the cluster."""
    from scpainter_blender.core.batch_items import DEFAULT_CPUS_PER_JOB, DEFAULT_RETRIES, MAX_RETRIES

    p.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                   help=f"run {what} on a Ray cluster (one task per job: one GPU each, or --cpus-per-job CPUs on "
                        "a cluster without GPUs; retried when a worker dies): the cluster at ADDRESS (HOST:PORT of "
                        "its head, ray://HOST:PORT, auto or local; not the dashboard's http:// URL), else RAY_ADDRESS or the one `ray start` started here, else a new local one; "
                        "files on a shared file system (README)")
    p.add_argument("--retries", type=bounded_int(0, MAX_RETRIES), default=None,
                   help="--ray: run a job again at most this often when its worker dies or it fails unexpectedly "
                        f"(bad input is never retried; default {DEFAULT_RETRIES})")
    p.add_argument("--cpus-per-job", type=float, default=None,
                   help=f"--ray on a cluster without GPUs: CPUs each job asks for (default {DEFAULT_CPUS_PER_JOB:g})")


def check_names(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``ArgumentError`` naming the option (or positional argument) whose value is not UTF-8: a file name's bytes
    that are not (Python holds them as surrogates, ``\\udcff``) could not be written into the jobs, records,
    lists, events and logs that name it as text, nor read back from them (``core.files.read_json`` refuses such
    strings), so such a path is refused before any work rather than half-used. Likewise a value holding a NUL
    byte, which no file name can hold (the OS calls raise ValueError on it): the one check for every command's
    options."""
    from scpainter_blender.core.errors import ArgumentError

    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]  # noqa: SLF001
    command = subs[0].choices.get(getattr(args, "command", None)) if subs else None
    for action in (command or parser)._actions:  # noqa: SLF001
        value = getattr(args, action.dest, None)
        for v in value if isinstance(value, list) else [value]:
            if not isinstance(v, str):
                continue
            name = next((o for o in action.option_strings if o.startswith("--")), action.dest)
            if not _is_text(v):
                raise ArgumentError(name, f"{v!r} is not UTF-8 text (a file name's bytes that are not are never "
                                          "written into jobs, records or events)",
                                    hint="rename the file or folder to a UTF-8 name")
            if "\0" in v:
                raise ArgumentError(name, f"{v!r} holds a NUL byte, which no file name can hold",
                                    hint="give the path without it")


def _is_text(value: str) -> bool:
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True
