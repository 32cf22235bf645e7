"""The training config (train.json): every setting of the wrong type or range is refused naming it, the file is
read within core.files' limits (a FIFO refused at once), and save/load round-trip."""

import json
import os

import pytest

from backend.train import config as C
from scpainter_blender.core import errors
from scpainter_blender.core import job as J
from tests_support import refusal_beside_fifo

BASE = {"schema": "scpainter.train/1", "checkpoint": "ckpt", "clips": ["clips/a"], "output_dir": "out"}

#: JSON values of every type, for each setting: each either loads or is refused naming that setting.
ODD_VALUES = [None, True, False, 0, -1, 1, 2 ** 40, 0.5, -0.5, 1e300, "", "x", "auto", [], [1], [0.9, 0.999],
              {"a": 1}, {}, [[1]]]


def test_defaults_load_and_round_trip(tmp_path):
    path = tmp_path / "train.json"
    path.write_text(json.dumps(BASE))
    cfg = C.load(str(path))
    assert cfg.clips == ["clips/a"] and cfg.adam_betas == (0.9, 0.999) and cfg.path == str(path)
    C.save(str(tmp_path / "again.json"), cfg)
    back = C.load(str(tmp_path / "again.json"))
    assert back.to_json() == cfg.to_json()
    assert [n for n in os.listdir(tmp_path) if n.endswith(".tmp")] == []


@pytest.mark.parametrize("name", sorted({f for f in C.TrainConfig.__dataclass_fields__} - {"path", "pairs"}))
def test_every_setting_of_the_wrong_type_is_named(tmp_path, name):
    for value in ODD_VALUES:
        data = {**BASE, name: value}
        try:
            C.from_dict(data, str(tmp_path / "train.json"))
        except C.TrainConfigError as e:
            assert e.field == name or e.field.startswith(f"{name}["), (name, value, str(e))
            assert str(e).startswith(f"train.json: {e.field}: ")
            assert isinstance(e, errors.InputError)


@pytest.mark.parametrize("name", sorted(C.PairSettings.__dataclass_fields__))
def test_every_pair_setting_of_the_wrong_type_is_named(tmp_path, name):
    for value in ODD_VALUES:
        try:
            C.from_dict({**BASE, "pairs": {name: value}}, str(tmp_path / "train.json"))
        except C.TrainConfigError as e:
            # point_cleaning is an object: its own fields are named below it (pairs.point_cleaning.outliers)
            assert e.field in (f"pairs.{name}", "pairs") or e.field.startswith(f"pairs.{name}."), (name, value, str(e))


@pytest.mark.parametrize("edit, field, message", [
    ({"adam_betas": 0.9}, "adam_betas", "two numbers"),
    ({"adam_betas": {"a": 1, "b": 2}}, "adam_betas", "two numbers"),
    ({"adam_betas": [0.9, "x"]}, "adam_betas[1]", "in \\[0, 1\\)"),
    ({"adam_betas": [0.9, 1.0]}, "adam_betas[1]", "in \\[0, 1\\)"),
    ({"learning_rate": True}, "learning_rate", "> 0"),
    ({"steps": 2.0}, "steps", "integer"),
    ({"steps": 2 ** 40}, "steps", "integer in \\[1, 2147483647\\]"),
    ({"clips": "a"}, "clips", "non-empty list"),
    ({"clips": ["a", 3]}, "clips[1]", "non-empty string"),
    ({"checkpoint": ["c"]}, "checkpoint", "folder path"),
    ({"optimizer": ["adamw"]}, "optimizer", "adamw or adamw8bit"),
    ({"gradient_checkpointing": "yes"}, "gradient_checkpointing", "true or false"),
    ({"pairs": [576, 320]}, "pairs", "expected an object of pair settings"),
    ({"pairs": {"width": "576"}}, "pairs.width", "integer"),
    ({"pairs": {"width": 100}}, "pairs", "multiples of 64"),
    ({"pairs": {"confidence_percentile": 101}}, "pairs.confidence_percentile", "\\[0, 100\\]"),
    ({"pairs": {"source_prob": 0}}, "pairs.source_prob", "\\(0, 1\\]"),
    ({"schema": "scpainter.train/2"}, "schema", "scpainter.train/1"),
])
def test_named_refusals(tmp_path, edit, field, message):
    with pytest.raises(C.TrainConfigError, match=message) as e:
        C.from_dict({**BASE, **edit}, str(tmp_path / "train.json"))
    assert e.value.field == field


@pytest.mark.parametrize("text, field, message", [
    ('{"schema": "scpainter.train/1", "checkpoint": "c", "clips": ["x"], "output_dir": "o", "learning_rate": NaN}',
     "learning_rate", "NaN is not a JSON number"),
    ('{"schema": "scpainter.train/1", "steps": 1e400}', "steps", "out of range"),
    ('{"schema": "scpainter.train/1", "clips": ' + "[" * 40 + "]" * 40 + "}", "clips" + "[0]" * 31, "nested deeper"),
    ('{"schema": "scpainter.train/1",', "(file)", "not valid JSON"),
    ("[]", "schema", "scpainter.train/1"),
])
def test_file_limits_name_the_field(tmp_path, text, field, message):
    path = tmp_path / "train.json"
    path.write_text(text)
    with pytest.raises(C.TrainConfigError, match=message) as e:
        C.load(str(path))
    assert e.value.field == field and str(e.value).startswith("train.json: ")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_fifo_and_directory_are_refused_at_once(tmp_path):
    os.mkfifo(tmp_path / "train.json")
    e = refusal_beside_fifo(lambda: C.load(str(tmp_path / "train.json")), tmp_path / "train.json",
                            C.TrainConfigError, "loading the config", timeout=5.0)
    assert "train.json: (file): is a FIFO" in str(e)
    with pytest.raises(C.TrainConfigError, match="is a directory"):
        C.load(str(tmp_path))
    with pytest.raises(C.TrainConfigError, match="train.json: \\(file\\): not found"):
        C.load(str(tmp_path / "missing" / "train.json"))


def test_source_window_keeps_its_former_name(tmp_path):
    """pairs.source_window (the source frames t ± N) was pairs.window before issue 15 gave the generation window
    that name alone: a train.json written then still loads."""
    old = C.from_dict({**BASE, "pairs": {"window": 5}}, str(tmp_path / "train.json"))
    new = C.from_dict({**BASE, "pairs": {"source_window": 5}}, str(tmp_path / "train.json"))
    assert old.pairs.source_window == new.pairs.source_window == 5
    assert old.to_json()["pairs"] == new.to_json()["pairs"] and "window" not in old.to_json()["pairs"]


# -- pairs.point_cleaning: the job's scene.point_cleaning, read by the job's own reader -----------------------------

def test_point_cleaning_defaults_are_the_jobs(tmp_path):
    """A config without the field (every config written before it) cleans as a job without it does; absent fields
    take their defaults, null turns one or both off; the file written back holds it resolved and loads the same."""
    path = str(tmp_path / "train.json")
    assert C.from_dict(BASE, path).pairs.point_cleaning.to_dict() == J.POINT_CLEANING
    assert C.PairSettings().point_cleaning.to_dict() == J.POINT_CLEANING       # built in code, too
    for field in ({}, {"outliers": None}, J.POINT_CLEANING):
        assert C.from_dict({**BASE, "pairs": {"point_cleaning": field}}, path).pairs.point_cleaning.to_dict() \
            == J.POINT_CLEANING
    off = C.from_dict({**BASE, "pairs": {"point_cleaning": None}}, path).pairs.point_cleaning
    assert off.depth_edge_ratio is None and off.outliers is None
    cfg = C.from_dict({**BASE, "pairs": {"point_cleaning": {"depth_edge_ratio": 0.1,
                                                             "outliers": {"method": "radius"}}}}, path)
    want = {"depth_edge_ratio": 0.1, "outliers": {"method": "radius", **J.OUTLIER_FIELDS["radius"]}}
    assert cfg.pairs.point_cleaning.to_dict() == want and cfg.to_json()["pairs"]["point_cleaning"] == want
    C.save(str(tmp_path / "again.json"), cfg)
    assert C.load(str(tmp_path / "again.json")).to_json() == cfg.to_json()
    assert C.from_dict(BASE, path).to_json()["pairs"]["point_cleaning"] == J.POINT_CLEANING
    assert C.from_dict(C.from_dict({**BASE, "pairs": {"point_cleaning": None}}, path).to_json(), path) \
        .pairs.point_cleaning.to_dict() == {"depth_edge_ratio": None, "outliers": None}


@pytest.mark.parametrize("value, field", [
    ([], "pairs.point_cleaning"),
    ("on", "pairs.point_cleaning"),
    ({"edge_ratio": 0.1}, "pairs.point_cleaning.edge_ratio"),
    ({"depth_edge_ratio": 0}, "pairs.point_cleaning.depth_edge_ratio"),
    ({"depth_edge_ratio": "0.05"}, "pairs.point_cleaning.depth_edge_ratio"),
    ({"depth_edge_ratio": True}, "pairs.point_cleaning.depth_edge_ratio"),
    ({"outliers": "statistical"}, "pairs.point_cleaning.outliers"),
    ({"outliers": {}}, "pairs.point_cleaning.outliers.method"),
    ({"outliers": {"method": "voxel"}}, "pairs.point_cleaning.outliers.method"),
    ({"outliers": {"method": "radius", "neighbours": 8}}, "pairs.point_cleaning.outliers.neighbours"),
    ({"outliers": {"method": "statistical", "neighbours": 0}}, "pairs.point_cleaning.outliers.neighbours"),
    ({"outliers": {"method": "statistical", "std_ratio": -1}}, "pairs.point_cleaning.outliers.std_ratio"),
    ({"outliers": {"method": "radius", "radius_m": 0}}, "pairs.point_cleaning.outliers.radius_m"),
])
def test_bad_point_cleaning_names_file_and_field_as_the_job_does(tmp_path, value, field):
    """The job's validation, word for word, as this file's error: the file, the field under pairs, the message and
    the hint a job's scene.point_cleaning gets."""
    with pytest.raises(C.TrainConfigError) as e:
        C.from_dict({**BASE, "pairs": {"point_cleaning": value}}, str(tmp_path / "train.json"))
    assert isinstance(e.value, errors.InputError) and e.value.path == str(tmp_path / "train.json")
    assert e.value.field == field and str(e.value).startswith(f"train.json: {field}: ")
    with pytest.raises(J.JobError) as job_error:
        J.PointCleaning.from_dict(value, "job.json", "pairs.point_cleaning")
    assert (job_error.value.field, job_error.value.message, job_error.value.hint) == \
        (e.value.field, e.value.message, e.value.hint)
