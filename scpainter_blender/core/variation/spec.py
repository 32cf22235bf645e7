"""What a variation run varies: the ``scpainter.variation/1`` file (``vary --spec FILE``), its defaults written
once (``VariationSpec``'s signature) and checked field by field.

::

    {"schema": "scpainter.variation/1", "variants": 16, "seed": 0, "resolution": [256, 144],
     "camera": {"shifts_m": [-2, 0, 2],                      # or {"min": -3, "max": 3}
                "lane_change": {"probability": 0.25, "shift_m": [-3.5, 3.5], "frames": 8}},
     "cars": {"library": "cars/", "count": [1, 3], "moving_probability": 0.5,
              "size_jitter": 0.05, "hue_jitter_deg": 30,
              "parked_offset_m": [2.0, 12.0], "kerb_gap_m": [0.1, 0.5], "lane_offsets_m": [-3.5, 0.0, 3.5], "speed_mps": [3.0, 10.0]},
     "placement": {"tries": 50, "gap_m": 0.5, "ego_size_m": [2.0, 4.8], "ego_margin_m": 0.5, "headway_s": 1.0}}

Every field is optional. Lengths in metres, speeds in metres per second, angles in degrees; a "shift" is to the
left of the direction of travel (``core.geometry.trajectory``). Paths are relative to the spec file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

from .. import errors, fields, files

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

    def with_overrides(self, **overrides) -> "VariationSpec":
        """A copy with the command line's values (None: not given), checked as the file's are."""
        given = {k: v for k, v in overrides.items() if v is not None}
        bounds = {"variants": (1, MAX_VARIANTS), "seed": (0, 2 ** 63 - 1)}
        for name, (lo, hi) in bounds.items():
            if name in given:
                fields.integer(given[name], errors.COMMAND_LINE, f"--{name}", lo, hi,
                               error=lambda p, f, m: errors.ArgumentError(f, m))
        return replace(self, **given)

    def to_dict(self) -> dict:
        """The resolved settings, as the manifest records them."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


def _error(path, field, message, hint=""):
    return VariationError(path, field, message, hint=hint)


def _int(v, field, lo, hi, path):
    return fields.integer(v, path, field, lo, hi, error=VariationError)


def _num(v, field, lo, hi, path):
    return fields.number(v, path, field, lo, hi, error=VariationError)


def _range(v, field, lo, hi, path, integer=False) -> tuple:
    """[low, high] with lo <= low <= high <= hi."""
    if not isinstance(v, list) or len(v) != 2:
        raise _error(path, field, f"expected [low, high], got {fields.short(v)}")
    check = _int if integer else _num
    a, b = (check(x, f"{field}[{i}]", lo, hi, path) for i, x in enumerate(v))
    if a > b:
        raise _error(path, field, f"low {a} is above high {b}")
    return (a, b)


def _choices(v, field, lo, hi, path) -> tuple:
    if not isinstance(v, list) or not v or len(v) > 1000:
        raise _error(path, field, f"expected a non-empty list of numbers (at most 1000), got {fields.short(v)}")
    return tuple(_num(x, f"{field}[{i}]", lo, hi, path) for i, x in enumerate(v))


def _section(d, key, known, path) -> dict:
    s = d.get(key, {})
    if not isinstance(s, dict):
        raise _error(path, key, "expected an object")
    for k in s:
        if k not in known:
            raise _error(path, f"{key}.{k}", f"is not a field of {key} (fields: {', '.join(known)})")
    return s


def from_dict(d, path) -> VariationSpec:
    """A ``VariationSpec`` from a spec file's content; ``VariationError`` naming the field."""
    if not isinstance(d, dict):
        raise _error(path, "(file)", "expected a JSON object")
    top = ("schema", "variants", "seed", "resolution", "camera", "cars", "placement")
    for k in d:
        if k not in top:
            raise _error(path, k, f"is not a field of a variation spec (fields: {', '.join(top)})")
    if d.get("schema", SCHEMA) != SCHEMA:
        raise _error(path, "schema", f"expected {SCHEMA!r}, got {fields.short(d.get('schema'))}")
    kw = {}
    if "variants" in d:
        kw["variants"] = _int(d["variants"], "variants", 1, MAX_VARIANTS, path)
    if "seed" in d:
        kw["seed"] = _int(d["seed"], "seed", 0, 2 ** 63 - 1, path)
    if d.get("resolution") is not None:
        kw["resolution"] = tuple(_int(x, f"resolution[{i}]", 8, 16384, path)
                                 for i, x in enumerate(_pair(d["resolution"], "resolution", path)))
    cam = _section(d, "camera", ("shifts_m", "lane_change"), path)
    if "shifts_m" in cam:
        s = cam["shifts_m"]
        if isinstance(s, dict):
            if set(s) != {"min", "max"}:
                raise _error(path, "camera.shifts_m", "expected a list of shifts or {\"min\": m, \"max\": m}")
            kw["shift_range_m"] = _range([s["min"], s["max"]], "camera.shifts_m", -50.0, 50.0, path)
        else:
            kw["shifts_m"] = _choices(s, "camera.shifts_m", -50.0, 50.0, path)
    lc = cam.get("lane_change")
    if lc is not None:
        if not isinstance(lc, dict):
            raise _error(path, "camera.lane_change", "expected an object")
        for k in lc:
            if k not in ("probability", "shift_m", "frames"):
                raise _error(path, f"camera.lane_change.{k}", "is not a field (probability, shift_m, frames)")
        if "probability" in lc:
            kw["lane_change_probability"] = _num(lc["probability"], "camera.lane_change.probability", 0.0, 1.0, path)
        if "shift_m" in lc:
            kw["lane_change_m"] = _choices(lc["shift_m"], "camera.lane_change.shift_m", -20.0, 20.0, path)
        if "frames" in lc:
            kw["lane_change_frames"] = _int(lc["frames"], "camera.lane_change.frames", 1, 100_000, path)
    cars = _section(d, "cars", ("library", "count", "moving_probability", "size_jitter", "hue_jitter_deg",
                                "parked_offset_m", "kerb_gap_m", "lane_offsets_m", "speed_mps"), path)
    if "library" in cars:
        lib = fields.string(cars["library"], path, "cars.library", error=VariationError)
        kw["library"] = lib if os.path.isabs(lib) else os.path.join(os.path.dirname(os.path.abspath(path)), lib)
    if "count" in cars:
        kw["car_count"] = _range(cars["count"], "cars.count", 0, MAX_CARS, path, integer=True)
    if "moving_probability" in cars:
        kw["moving_probability"] = _num(cars["moving_probability"], "cars.moving_probability", 0.0, 1.0, path)
    if "size_jitter" in cars:
        kw["size_jitter"] = _num(cars["size_jitter"], "cars.size_jitter", 0.0, 0.5, path)
    if "hue_jitter_deg" in cars:
        kw["hue_jitter_deg"] = _num(cars["hue_jitter_deg"], "cars.hue_jitter_deg", 0.0, 180.0, path)
    if "parked_offset_m" in cars:
        kw["parked_offset_m"] = _range(cars["parked_offset_m"], "cars.parked_offset_m", 0.0, 50.0, path)
    if "kerb_gap_m" in cars:
        kw["kerb_gap_m"] = _range(cars["kerb_gap_m"], "cars.kerb_gap_m", 0.0, 5.0, path)
    if "lane_offsets_m" in cars:
        kw["lane_offsets_m"] = _choices(cars["lane_offsets_m"], "cars.lane_offsets_m", -50.0, 50.0, path)
    if "speed_mps" in cars:
        kw["speed_mps"] = _range(cars["speed_mps"], "cars.speed_mps", 0.0, 70.0, path)
    pl = _section(d, "placement", ("tries", "gap_m", "ego_size_m", "ego_margin_m", "headway_s"), path)
    if "tries" in pl:
        kw["tries"] = _int(pl["tries"], "placement.tries", 1, MAX_TRIES, path)
    if "gap_m" in pl:
        kw["gap_m"] = _num(pl["gap_m"], "placement.gap_m", 0.0, 10.0, path)
    if "ego_size_m" in pl:
        kw["ego_size_m"] = tuple(_num(x, f"placement.ego_size_m[{i}]", 0.1, 30.0, path)
                                 for i, x in enumerate(_pair(pl["ego_size_m"], "placement.ego_size_m", path)))
    if "ego_margin_m" in pl:
        kw["ego_margin_m"] = _num(pl["ego_margin_m"], "placement.ego_margin_m", 0.0, 10.0, path)
    if "headway_s" in pl:
        kw["headway_s"] = _num(pl["headway_s"], "placement.headway_s", 0.0, 60.0, path)
    return VariationSpec(**kw)


def _pair(v, field, path) -> list:
    if not isinstance(v, list) or len(v) != 2:
        raise _error(path, field, f"expected two numbers, got {fields.short(v)}")
    return v


def load(path) -> VariationSpec:
    """Read and check a spec file (bounded JSON, ``core.files.read_json``)."""
    path = os.fspath(path)
    return from_dict(files.read_json(path, error=VariationError), path)


def add_arguments(parser) -> None:
    """The options of ``vary``, in both CLIs (``python -m backend vary``, ``blender -c scpainter vary``)."""
    parser.add_argument("--out", required=True, help="the folder to write the variants into")
    parser.add_argument("--spec", help=f"a variation spec ({SCHEMA} JSON; default: every default)")
    parser.add_argument("--variants", type=int, help="how many variants (default: the spec's)")
    parser.add_argument("--seed", type=int, help="the run's seed: variant i is the same for one seed (default: the "
                                                 "spec's)")
    parser.add_argument("--library", help="folder of car files to draw from (default: the spec's cars.library)")


def from_arguments(args) -> VariationSpec:
    """The spec file's settings (or the defaults) with the command line's ``--variants``, ``--seed`` and
    ``--library``, checked (``ArgumentError`` naming the option)."""
    spec = load(args.spec) if args.spec else VariationSpec()
    library = os.path.abspath(args.library) if args.library else None
    return spec.with_overrides(variants=args.variants, seed=args.seed, library=library)
