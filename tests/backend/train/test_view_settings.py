"""One home for the view settings training and evaluation share (backend/train/view_settings.py): the
command line takes its defaults from the dataclasses, and the values are written nowhere else."""

import dataclasses
import re

from backend.__main__ import build_parser
from backend.evaluate import protocol
from backend.train import pairs
from backend.train.view_settings import ViewSettings

VIEW = {f.name for f in dataclasses.fields(ViewSettings)}


def _parse(*options):
    return build_parser().parse_args(["evaluate", "clip", "--output-dir", "out", *options])


def test_evaluate_without_options_gets_the_dataclass_defaults():
    s = protocol.EvalSettings.from_args(_parse())
    assert s == protocol.EvalSettings(clips=["clip"], output_dir="out")
    assert {k: getattr(s, k) for k in VIEW} == dataclasses.asdict(ViewSettings())
    assert {k: getattr(pairs.PairSettings(), k) for k in VIEW} == dataclasses.asdict(ViewSettings())


def test_editing_a_dataclass_default_is_what_the_command_line_sees():
    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Edited(protocol.EvalSettings):
        width: int = 64
        frames: int = 7
        shifts: tuple = (1.5,)
        crop_min_px: int = 3

    s = Edited.from_args(_parse())
    assert (s.width, s.height, s.frames, s.shifts, s.crop_min_px) == (64, ViewSettings().height, 7, (1.5,), 3)
    given = Edited.from_args(_parse("--resolution", "128", "64", "--frames", "3", "--shifts", "--no-insertion"))
    assert (given.width, given.height, given.frames, given.shifts, given.insertion) == (128, 64, 3, (), False)


def test_evaluate_options_leave_their_defaults_to_the_dataclass():
    evaluate = build_parser()._subparsers._group_actions[0].choices["evaluate"]
    settings = {f.name for f in dataclasses.fields(protocol.EvalSettings)} | {"resolution"}
    options = [a for a in evaluate._actions if a.dest in settings and a.option_strings]
    assert {a.dest for a in options} >= {"resolution", "frames", "shifts", "source_window", "steps", "seed",
                                         "crop_min_px", "precision", "checkpoint", "inpaint", "inception"}
    assert [(a.dest, a.default) for a in options if a.default is not None] == []


def test_the_settings_classes_do_not_declare_the_view_fields_again():
    for cls in (pairs.PairSettings, protocol.EvalSettings):
        assert not VIEW & set(vars(cls).get("__annotations__", {})), cls


# a default of the view written again: "576, 320" or "576 x 320", or a field / option given 576, 320 or 14
SPELLED = [re.compile(r"\b576\s*(?:,|x|×|\*)\s*320\b"),
           re.compile(r"\b(?:width|height|frames|source_window)\b\s*(?::\s*[\w |]+)?=\s*(?:576|320|14)\b"),
           re.compile(r"default\s*=\s*\[?\s*(?:576|320|14)\b")]


def test_the_view_defaults_are_written_only_in_their_home():
    from tests_support import tracked_sources

    shipped = tracked_sources(exclude=("backend/train/view_settings.py",), shipped_only=True)
    assert len(shipped) > 50
    hits = []
    for f, text in shipped.items():
        for i, line in enumerate(text.splitlines(), 1):
            if any(p.search(line) for p in SPELLED):
                hits.append(f"{f}:{i}: {line.strip()}")
    assert hits == []
