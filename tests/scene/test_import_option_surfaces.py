"""The import operator's properties and ``blender -c scpainter import``'s options agree with core.import_options (the
installed extension's own modules)."""

import sys

import pytest


def _installed(addon, module):
    return sys.modules[f"{addon}.scpainter_blender.{module}"]


def test_operator_properties_are_the_options(addon):
    import bpy

    options = _installed(addon, "core.import_options")
    rna = bpy.ops.scpainter.import_vggt.get_rna_type().properties
    for name, o in options.OPTIONS.items():
        p = rna[name]
        assert p.name == o.label and p.description == o.description, name
        default = 0.0 if o.default is None else o.default
        if o.items:
            assert p.type == "ENUM" and p.default == default, name
            assert [(i.identifier, i.name, i.description) for i in p.enum_items] == list(o.items), name
        elif isinstance(default, float):
            assert p.type == "FLOAT" and p.default == pytest.approx(default), name
        else:
            assert p.default == default, name
        for bound, attr in (("min", "hard_min"), ("max", "hard_max")):
            if getattr(o, bound) is not None:
                assert getattr(p, attr) == pytest.approx(getattr(o, bound)), (name, bound)
    assert rna["scale_factor"].hard_min == pytest.approx(1e-6) and rna["camera_height"].hard_min == pytest.approx(0.01)
    assert rna["confidence_percentile"].subtype == "PERCENTAGE" and rna["trajectory_path"].subtype == "FILE_PATH"
    assert rna["filter_glob"].default == "*.npz"   # the operator's own property, beside the generated ones


def test_command_line_options_are_the_options(addon):
    options = _installed(addon, "core.import_options")
    cli = _installed(addon, "cli")
    parser = cli._parser()
    args = parser.parse_args(["import", "x.npz"])
    assert options.from_arguments(args) == options.ImportOptions()
    sub = next(a for a in parser._actions if a.dest == "command").choices["import"]
    flags = {a.dest: a for a in sub._actions if a.option_strings}
    for name, o in options.OPTIONS.items():
        if o.flag is None:
            assert name not in flags
            continue
        assert flags[name].option_strings == [o.flag] and o.description in flags[name].help, name
        assert flags[name].default == (None if o.scale_mode else o.default), name
        assert flags[name].choices == (list(o.choices) if o.items else None), name
