"""core.fields: every numeric field of a job (``core.job``) and of a variation spec (``core.variation.spec``) refuses
a 310-digit integer, -1e308 and NaN by name (issue 42: such integers gave OverflowErrors in ``float()`` and numpy).

The fields are found by walking a valid document that sets every field, so a field added later is covered too."""

import json
import math

import numpy as np
import pytest

from scpainter_blender.core import errors, fields
from scpainter_blender.core import job as J
from scpainter_blender.core.variation import spec as S

HOSTILE = {"310 digits": 10 ** 310, "-310 digits": -10 ** 310, "-1e308": -1e308, "NaN": math.nan, "inf": math.inf}


def full_job() -> dict:
    """A valid job setting every field that holds a number."""
    eye = np.eye(4).tolist()
    return {"schema": J.SCHEMA, "resolution": [64, 32], "fps": 10.0,
            "frames": [{"frame": f, "K": [[50, 0, 32], [0, 50, 16], [0, 0, 1]], "world_to_camera": eye,
                        "source_frames": [0, 1]} for f in (1, 2)],
            "scene": {"predictions": "p.npz", "vggt_to_world": (2 * np.eye(4) - np.diag([0, 0, 0, 1])).tolist(),
                      "confidence_percentile": 50.0, "crop": [1, 2, 3, 4],
                      "removal_boxes": [{"box_to_world": eye, "size": [4.5, 1.9, 1.6]}],
                      "point_cleaning": {"depth_edge_ratio": 0.05,
                                         "outliers": {"method": "statistical", "neighbours": 16, "std_ratio": 2.0}},
                      "recorded_frames": [1, 2],
                      "recorded_objects": [{"id": "a", "size": [1.8, 4.4, 1.5], "boxes": {"1": eye}}]},
            "assets": [{"name": "car", "ply": "car.ply", "object_to_world": {"1": eye, "2": eye},
                        "box": {"box_to_file": eye, "size": [1.9, 4.5, 1.6]}}],
            "output_dir": "out",
            "generate": {"steps": 25, "window": 14, "overlap": 4, "seed": 0, "decode_chunk": 8, "min_guidance": 1.0,
                         "max_guidance": 3.0, "fps": 7.0, "inpaint_radius": 3}}


def full_spec(range_shifts: bool) -> dict:
    spec = S.VariationSpec(resolution=(256, 144), library="cars",
                           shift_range_m=(-2.0, 2.0) if range_shifts else None)
    return S.to_file(spec)


def numeric_leaves(value, where=""):
    """(path, keys) of every number in a JSON document: ``frames[0].K[0][1]``; keys to reach it."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from ((p, (k,) + keys) for p, keys in numeric_leaves(v, f"{where}.{k}" if where else k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from ((p, (i,) + keys) for p, keys in numeric_leaves(v, f"{where}[{i}]"))
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield where, ()


def _normal(name: str) -> str:
    """A field name with object keys written alike: ``boxes['1']`` and ``boxes.1`` → ``boxes.1``."""
    return name.replace("['", ".").replace("']", "")


def _cases(document, read):
    leaves = list(numeric_leaves(document))
    read(json.loads(json.dumps(document)))  # valid as it is
    return [(path, keys, label, bad) for path, keys in leaves for label, bad in HOSTILE.items()]


def _refused_by_name(document, keys, bad, read, path):
    d = json.loads(json.dumps(document))  # no shared lists
    node = d
    for k in keys[:-1]:
        node = node[k]
    node[keys[-1]] = bad
    with pytest.raises(errors.InputError) as e:
        read(d)
    # the field named is the number's own or the matrix / list / object holding it
    assert _normal(path).startswith(_normal(e.value.field)) and e.value.field not in ("(file)", "(top level)"), \
        (path, e.value.field, str(e.value))
    str(e.value)  # its text can be made (an integer of 310 digits is quoted, never a ValueError)


def test_every_numeric_field_of_a_job_refuses_out_of_range_values_by_name():
    document = full_job()
    cases = _cases(document, J.Job.from_dict)
    assert len(cases) > 5 * 100  # every matrix entry, every setting
    for path, keys, _, bad in cases:
        _refused_by_name(document, keys, bad, J.Job.from_dict, path)


@pytest.mark.parametrize("range_shifts", [False, True])
def test_every_numeric_field_of_a_spec_refuses_out_of_range_values_by_name(range_shifts):
    document = full_spec(range_shifts)
    read = lambda d: S.from_dict(d, "spec.json")  # noqa: E731
    cases = _cases(document, read)
    assert len({p for p, *_ in cases}) >= 25
    for path, keys, _, bad in cases:
        _refused_by_name(document, keys, bad, read, path)


def test_the_validators_themselves():
    """``integer`` keeps every value in int64 even without bounds; ``number`` and ``matrix`` refuse integers beyond
    float64; ``short`` quotes an integer too long for Python's ``str``."""
    for bad in (2 ** 63, -2 ** 63 - 1, 10 ** 5000):
        with pytest.raises(errors.InputError, match="expected an integer"):
            fields.integer(bad, "f.json", "n")
    assert fields.integer(2 ** 63 - 1, "f.json", "n") == 2 ** 63 - 1
    with pytest.raises(errors.InputError, match="expected a number"):
        fields.number(10 ** 310, "f.json", "x")
    with pytest.raises(errors.InputError, match="beyond"):
        fields.matrix([[10 ** 310]], "f.json", "m", (1, 1))
    assert "digits" in fields.short(10 ** 5000)
