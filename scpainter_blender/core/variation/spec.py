"""What a variation run varies: the ``scpainter.variation/1`` file (``vary --spec FILE``), its defaults written
once (``VariationSpec``'s signature) and checked field by field (``FIELDS``: each file field, the setting it
gives, how it is read, its bounds).

An example (not the defaults: an absent field takes ``VariationSpec``'s default; the manifest's ``spec`` is the
whole file a run used, every field written)::

    {"schema": "scpainter.variation/1", "variants": 16, "seed": 0, "resolution": [256, 144],
     "camera": {"shifts_m": [-2, 0, 2],                      # choices; or a range: {"min": -3, "max": 3}
                "lane_change": {"probability": 0.25, "shift_m": [-3.5, 3.5], "frames": 8}},   # shift_m: choices
     "cars": {"library": "cars/", "count": [1, 3],           # count: [low, high]
              "moving_probability": 0.5, "size_jitter": 0.05, "hue_jitter_deg": 30,
              "parked_offset_m": [2.0, 12.0], "kerb_gap_m": [0.1, 0.5],           # [low, high]
              "lane_offsets_m": [-3.5, 0.0, 3.5],                                 # choices
              "speed_mps": [3.0, 10.0]},                                          # [low, high]
     "placement": {"tries": 50, "gap_m": 0.5, "ego_size_m": [2.0, 4.8], "ego_margin_m": 0.5, "headway_s": 1.0}}

Every field is optional. Lengths in metres, speeds in metres per second, angles in degrees; a "shift" is to the
left of the direction of travel (``core.geometry.trajectory``). Paths are relative to the spec file. Lists of
choices are drawn from uniformly; [low, high] ranges uniformly within.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from .. import errors, fields, files

if TYPE_CHECKING:
    import argparse

SCHEMA = "scpainter.variation/1"
#: At most this many variants in one run, cars in one variant, placement tries per car.
MAX_VARIANTS = 100_000
MAX_CARS = 64
MAX_TRIES = 10_000


class VariationError(errors.InputError):
    """A variation spec that cannot be used: ``"<spec file>: <field>: <what is wrong>"``."""


@dataclass(frozen=True)
class VariationSpec:
    """Every setting of a variation run, with its default. Ranges are (low, high) inclusive; lists are choices.

    - ``variants``: how many to make; ``seed``: variant i draws from ``numpy.random.default_rng([seed, i])``, so it
      is the same whatever ``variants`` is.
    - ``resolution``: (width, height) of the variants' frames (None: the base job's); K scales with it.
    - ``shifts_m``: camera shifts to choose from, or ``shift_range_m`` (low, high) drawn uniformly instead.
    - ``lane_change_probability``, ``lane_change_m`` (choices), ``lane_change_frames``: a smooth extra shift
      (smoothstep over that many frames, starting at a random frame) on top of the variant's shift.
    - ``library``: a folder of car files (every format the import reads); ``car_count`` (low, high).
    - ``moving_probability``: a car drives (else it is parked); ``size_jitter``: uniform scale in 1 ± it;
      ``hue_jitter_deg``: the DC colour's hue turned by a whole number of degrees within ± it.
    - ``parked_offset_m``: (low, high) metres left or right of the reference path between which a parked car
      stands: at the road's edge found there (``kerb_gap_m`` drawn from it), refused when that edge is nearer
      than low;
      ``lane_offsets_m``: a moving car's lane (left of the path); ``speed_mps`` (low, high).
    - ``tries``: placements drawn per car before the variant is reported unplaced; ``gap_m``: the least gap
      between cars (and to recorded cars); ``ego_size_m`` (width, length) of the ego vehicle around each camera of
      the new path, grown by ``ego_margin_m`` on every side: its swept footprint no parked car may touch, and a
      moving car may not touch it at a frame nor within ``headway_s`` after (``core.variation.placement``).
    """
    variants: int = 16
    seed: int = 0
    resolution: tuple | None = None
    shifts_m: tuple = (0.0,)
    shift_range_m: tuple | None = None
    lane_change_probability: float = 0.0
    lane_change_m: tuple = (-3.5, 3.5)
    lane_change_frames: int = 8
    library: str | None = None
    car_count: tuple = (1, 3)
    moving_probability: float = 0.5
    size_jitter: float = 0.05
    hue_jitter_deg: float = 30.0
    parked_offset_m: tuple = (2.0, 12.0)
    kerb_gap_m: tuple = (0.1, 0.5)
    lane_offsets_m: tuple = (-3.5, 0.0, 3.5)
    speed_mps: tuple = (3.0, 10.0)
    tries: int = 50
    gap_m: float = 0.5
    ego_size_m: tuple = (2.0, 4.8)
    ego_margin_m: float = 0.5
    headway_s: float = 1.0

    def with_overrides(self, **overrides: object) -> "VariationSpec":
        """A copy with the command line's values (None: not given), checked as the file's are."""
        given = {k: v for k, v in overrides.items() if v is not None}
        bounds = {"variants": (1, MAX_VARIANTS), "seed": (0, 2 ** 63 - 1)}
        for name, (lo, hi) in bounds.items():
            if name in given:
                fields.integer(given[name], errors.COMMAND_LINE, f"--{name}", lo, hi,
                               error=lambda p, f, m: errors.ArgumentError(f, m))
        return replace(self, **given)



#: Every field of the file: (its name, the ``VariationSpec`` field, how it is read, low, high bound). Kinds:
#: ``int``, ``number``, ``range`` / ``int_range`` ([low, high] within the bounds), ``choices`` (a non-empty list
#: of numbers), ``pair`` (two numbers), ``shifts`` (choices, or {"min", "max"} for a range), ``folder`` (a path,
#: relative to the spec file).
FIELDS = (
    ("variants", "variants", "int", 1, MAX_VARIANTS),
    ("seed", "seed", "int", 0, 2 ** 63 - 1),
    ("resolution", "resolution", "int_pair", 8, 16384),
    ("camera.shifts_m", "shifts_m", "shifts", -50.0, 50.0),
    ("camera.lane_change.probability", "lane_change_probability", "number", 0.0, 1.0),
    ("camera.lane_change.shift_m", "lane_change_m", "choices", -20.0, 20.0),
    ("camera.lane_change.frames", "lane_change_frames", "int", 1, 100_000),
    ("cars.library", "library", "folder", None, None),
    ("cars.count", "car_count", "int_range", 0, MAX_CARS),
    ("cars.moving_probability", "moving_probability", "number", 0.0, 1.0),
    ("cars.size_jitter", "size_jitter", "number", 0.0, 0.5),
    ("cars.hue_jitter_deg", "hue_jitter_deg", "number", 0.0, 180.0),
    ("cars.parked_offset_m", "parked_offset_m", "range", 0.0, 50.0),
    ("cars.kerb_gap_m", "kerb_gap_m", "range", 0.0, 5.0),
    ("cars.lane_offsets_m", "lane_offsets_m", "choices", -50.0, 50.0),
    ("cars.speed_mps", "speed_mps", "range", 0.0, 70.0),
    ("placement.tries", "tries", "int", 1, MAX_TRIES),
    ("placement.gap_m", "gap_m", "number", 0.0, 10.0),
    ("placement.ego_size_m", "ego_size_m", "pair", 0.1, 30.0),
    ("placement.ego_margin_m", "ego_margin_m", "number", 0.0, 10.0),
    ("placement.headway_s", "headway_s", "number", 0.0, 60.0),
)


def _error(path, field, message, hint=""):
    return VariationError(path, field, message, hint=hint)


def _read(kind, v, field, lo, hi, path):
    """One field's value as ``VariationSpec`` holds it (``FIELDS``' kinds)."""
    num = lambda x, f: fields.number(x, path, f, lo, hi, error=VariationError)  # noqa: E731
    whole = lambda x, f: fields.integer(x, path, f, lo, hi, error=VariationError)  # noqa: E731
    if kind in ("int", "number"):
        return (whole if kind == "int" else num)(v, field)
    if kind in ("pair", "int_pair", "range", "int_range"):
        if not isinstance(v, list) or len(v) != 2:
            raise _error(path, field, f"expected [{'low, high' if 'range' in kind else 'a, b'}], got "
                                      f"{fields.short(v)}")
        a, b = ((whole if kind.startswith("int") else num)(x, f"{field}[{i}]") for i, x in enumerate(v))
        if "range" in kind and a > b:
            raise _error(path, field, f"low {a} is above high {b}")
        return (a, b)
    if kind == "choices" or (kind == "shifts" and not isinstance(v, dict)):
        if not isinstance(v, list) or not v or len(v) > 1000:
            also = ' or {"min": m, "max": m} (a range)' if kind == "shifts" else " to choose from"
            raise _error(path, field, f"expected a non-empty list of numbers (at most 1000){also}, got "
                                      f"{fields.short(v)}")
        return tuple(num(x, f"{field}[{i}]") for i, x in enumerate(v))
    if kind == "shifts":  # {"min": m, "max": m}: drawn uniformly
        if set(v) != {"min", "max"}:
            raise _error(path, field, 'expected a list of shifts or {"min": m, "max": m}')
        low, high = (num(v[k], f"{field}.{k}") for k in ("min", "max"))
        if low > high:
            raise _error(path, field, f"min {low} is above max {high}")
        return (low, high)
    if kind == "folder":
        folder = fields.string(v, path, field, error=VariationError)
        return folder if os.path.isabs(folder) else os.path.join(os.path.dirname(os.path.abspath(path)), folder)
    raise ValueError(f"unknown field kind {kind!r}")


def from_dict(d: dict, path: str | os.PathLike) -> VariationSpec:
    """A ``VariationSpec`` from a spec file's content (``FIELDS``); ``VariationError`` naming the field: an unknown
    one (a typo would otherwise fall back to a default unseen), a value of the wrong kind or out of bounds."""
    if not isinstance(d, dict):
        raise _error(path, "(file)", "expected a JSON object")
    if d.get("schema", SCHEMA) != SCHEMA:
        raise _error(path, "schema", f"expected {SCHEMA!r}, got {fields.short(d.get('schema'))}")
    values = {}

    def walk(obj, prefix):
        known = {name[len(prefix):].split(".")[0] for name, *_ in FIELDS if name.startswith(prefix)}
        known |= {"schema"} if not prefix else set()
        for key, value in obj.items():
            name = prefix + key
            if key not in known:
                raise _error(path, name, f"is not a field{' of ' + prefix[:-1] if prefix else ''} (fields: "
                                         f"{', '.join(sorted(known))})")
            if any(f[0] == name for f in FIELDS):
                values[name] = value
            elif name != "schema":
                if not isinstance(value, dict):
                    raise _error(path, name, "expected an object")
                walk(value, name + ".")

    walk(d, "")
    kw = {attr: _read(kind, values[name], name, lo, hi, path)
          for name, attr, kind, lo, hi in FIELDS if name in values and values[name] is not None}
    if "shifts_m" in kw and isinstance(values["camera.shifts_m"], dict):
        kw["shift_range_m"] = kw.pop("shifts_m")
    return VariationSpec(**kw)


def to_file(spec: VariationSpec) -> dict:
    """The spec file that gives ``spec`` (every field written, in the file's names: ``FIELDS``), as the manifest
    records it; ``from_dict`` reads it back to an equal spec."""
    out = {"schema": SCHEMA}
    for name, attr, kind, _, _ in FIELDS:
        value = getattr(spec, attr)
        if attr == "shifts_m" and spec.shift_range_m is not None:
            value = {"min": spec.shift_range_m[0], "max": spec.shift_range_m[1]}
        if value is None:
            continue
        *parents, leaf = name.split(".")
        node = out
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = list(value) if isinstance(value, tuple) else value
    return out


def load(path: str | os.PathLike) -> VariationSpec:
    """Read and check a spec file (bounded JSON, ``core.files.read_json``)."""
    path = os.fspath(path)
    return from_dict(files.read_json(path, error=VariationError), path)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``vary``, in both CLIs (``python -m backend vary``, ``blender -c scpainter vary``)."""
    parser.add_argument("--out", required=True, help="the folder to write the variants into")
    parser.add_argument("--spec", help=f"a variation spec ({SCHEMA} JSON; default: every default)")
    parser.add_argument("--variants", type=int, help="how many variants (default: the spec's)")
    parser.add_argument("--seed", type=int, help="the run's seed: variant i is the same for one seed (default: the "
                                                 "spec's)")
    parser.add_argument("--library", help="folder of car files to draw from (default: the spec's cars.library)")
    parser.add_argument("--skip-bad", action="store_true",
                        help="leave out library files that cannot be used (unreadable, damaged, not shaped like a "
                             "car), each listed in the manifest with why and warned of; without it the first stops "
                             "the run")


def from_arguments(args: argparse.Namespace) -> VariationSpec:
    """The spec file's settings (or the defaults) with the command line's ``--variants``, ``--seed`` and
    ``--library``, checked (``ArgumentError`` naming the option)."""
    spec = load(args.spec) if args.spec else VariationSpec()
    library = os.path.abspath(args.library) if args.library else None
    return spec.with_overrides(variants=args.variants, seed=args.seed, library=library)
