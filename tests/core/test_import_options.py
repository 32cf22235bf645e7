"""core.import_options: the import options' one home (defaults, choices, bounds, texts, checks), the command-line
options and the Blender property keywords made from it; the facts it shares written once in shipped code."""

import argparse
import ast
import dataclasses

import pytest

from scpainter_blender.core import errors
from scpainter_blender.core import import_options as IO
from scpainter_blender.core import job as J
from scpainter_blender.core.geometry import point_cloud
from scpainter_blender.core.vggt import predictions as vggt

#: The caller's fields of ImportOptions, not options a user sets.
CALLERS = {"frame_start", "set_scene_camera"}


def _parser():
    p = argparse.ArgumentParser()
    IO.add_arguments(p)
    return p


def test_defaults_are_the_options():
    names = {f.name for f in dataclasses.fields(IO.ImportOptions)}
    assert names - CALLERS == set(IO.OPTIONS)
    opts = IO.ImportOptions()
    assert {n: getattr(opts, n) for n in IO.OPTIONS} == {n: o.default for n, o in IO.OPTIONS.items()}
    assert opts.confidence_percentile == point_cloud.CONFIDENCE_PERCENTILE == J.Scene("p", None).confidence_percentile
    assert opts.depth_edge_ratio == IO.DEPTH_EDGE_RATIO == J.POINT_CLEANING["depth_edge_ratio"]
    assert IO.OPTIONS["extrinsic_convention"].choices == ("auto",) + vggt.EXTRINSIC_CONVENTIONS
    assert IO.SCALE_MODES == ("FACTOR", "TRAJECTORY", "CAMERA_HEIGHT")
    assert IO.SCALE_VALUE == {"FACTOR": "scale_factor", "TRAJECTORY": "trajectory_path",
                              "CAMERA_HEIGHT": "camera_height"}
    for o in IO.OPTIONS.values():
        assert o.description and o.label, o.name
        assert not o.items or o.default in o.choices, o.name
    assert opts.check() is opts


@pytest.mark.parametrize("name, value, message", [
    ("confidence_percentile", 150.0, "expected a percentile in [0, 100]"),
    ("confidence_percentile", float("nan"), "percentile"),
    ("point_source", "lidar", "expected one of ['depth', 'world_points']"),
    ("scale_mode", "GUESS", "expected one of ['FACTOR', 'TRAJECTORY', 'CAMERA_HEIGHT']"),
    ("extrinsic_convention", "sideways", "expected one of ['auto', 'world_to_camera', 'camera_to_world']"),
    ("scale_factor", 0.0, "expected metres per VGGT unit > 0"),
    ("point_radius", -1.0, "expected metres >= 0"),
    ("frame_window", -1, "expected a number of frames >= 0"),
    ("frame_window", True, "expected a number of frames >= 0"),
    ("depth_edge_ratio", 1e-5, "expected a fraction of the pixel's depth"),
])
def test_check_names_the_option(name, value, message):
    with pytest.raises(errors.InputError) as e:
        IO.ImportOptions(**{name: value}).check()
    assert (e.value.path, e.value.field) == ("(import options)", name) and message in e.value.message


def test_command_line_options_are_made_from_the_options():
    p = _parser()
    assert IO.from_arguments(p.parse_args([])) == IO.ImportOptions()   # nothing given: the defaults
    flags = {a.dest: a for a in p._actions if a.option_strings}
    on_line = {n: o for n, o in IO.OPTIONS.items() if o.flag}
    assert set(flags) - {"help"} == set(on_line)
    for name, o in on_line.items():
        a = flags[name]
        assert a.option_strings == [o.flag] and o.description in a.help
        assert a.default == (None if o.scale_mode else o.default), name   # a scale value given chooses the mode
        assert a.choices == (list(o.choices) if o.items else None), name
    for flag, value, mode, name in (("--scale-factor", "3", "FACTOR", "scale_factor"),
                                    ("--trajectory", "t.txt", "TRAJECTORY", "trajectory_path"),
                                    ("--camera-height", "2", "CAMERA_HEIGHT", "camera_height")):
        opts = IO.from_arguments(p.parse_args([flag, value]))
        assert opts.scale_mode == mode and str(getattr(opts, name)) in (value, value + ".0")
    assert IO.from_arguments(p.parse_args(["--depth-edge-ratio", "off"])).edge_ratio is None
    with pytest.raises(SystemExit):   # argparse: one scale at a time
        p.parse_args(["--scale-factor", "2", "--camera-height", "1.6"])
    for args, flag in ((["--scale-factor", "0"], "--scale-factor"),
                       (["--confidence-percentile", "150"], "--confidence-percentile"),
                       (["--depth-edge-ratio", "200"], "--depth-edge-ratio")):
        with pytest.raises(errors.ArgumentError) as e:
            IO.from_arguments(p.parse_args(args))
        assert (e.value.path, e.value.field) == (errors.COMMAND_LINE, flag)


def test_the_recorded_objects_options_follow_the_readers():
    """``objects_format``'s choices are auto plus the formats core.recording reads; ``--objects`` and its companions
    reach ``ImportOptions``; an unknown format is refused naming the option."""
    from scpainter_blender.core.recording import reader

    assert IO.OPTIONS["objects_format"].choices == (reader.AUTO, *reader.FORMATS)
    opts = IO.from_arguments(_parser().parse_args(["--objects", "o.json", "--objects-format", "kitti",
                                                   "--objects-scene", "scene-0001", "--objects-camera", "image_03"]))
    assert (opts.objects, opts.objects_format, opts.objects_scene, opts.objects_camera) == \
        ("o.json", "kitti", "scene-0001", "image_03")
    with pytest.raises(errors.InputError) as e:
        IO.ImportOptions(objects_format="csv").check()
    assert e.value.field == "objects_format" and "expected one of" in e.value.message


def test_blender_property_keywords_are_made_from_the_options():
    props = IO.blender_properties()
    assert list(props) == list(IO.OPTIONS)   # the order the operator draws them
    kinds = {bool: "BoolProperty", int: "IntProperty", float: "FloatProperty", str: "StringProperty"}
    for name, (kind, kw) in props.items():
        o = IO.OPTIONS[name]
        assert kind == ("EnumProperty" if o.items else kinds[type(o.default)]), name
        assert kw["default"] == (0.0 if o.default is None else o.default) and kw["description"] == o.description
        assert [i[0] for i in kw.get("items", [])] == list(o.choices)
        for bound in ("min", "max"):
            if getattr(o, bound) is not None:
                assert kw[bound] == getattr(o, bound), (name, bound)


def test_shared_facts_are_written_once():
    """The default confidence percentile lives in core.geometry.point_cloud and the extrinsic conventions in
    core.vggt.predictions: no other shipped module spells them (a 50 on a line about a percentile; a tuple or list
    holding both convention names)."""
    homes = {"percentile": "scpainter_blender/core/geometry/point_cloud.py",
             "conventions": "scpainter_blender/core/vggt/predictions.py"}
    found = []
    from tests_support import tracked_sources

    for path, text in tracked_sources(shipped_only=True).items():
        lines = text.splitlines()
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.Constant) and type(node.value) in (int, float) and node.value == 50 \
                    and "percentile" in lines[node.lineno - 1].lower() and path != homes["percentile"]:
                found.append(f"{path}:{node.lineno}: {lines[node.lineno - 1].strip()}")
            names = {e.value for e in getattr(node, "elts", ()) if isinstance(e, ast.Constant)}
            if isinstance(node, (ast.Tuple, ast.List)) and path != homes["conventions"] and \
                    {"world_to_camera", "camera_to_world"} <= names:
                found.append(f"{path}:{node.lineno}: {lines[node.lineno - 1].strip()}")
    assert not found, "written again outside its home:\n" + "\n".join(found)
    assert point_cloud.CONFIDENCE_PERCENTILE == 50.0 and vggt.EXTRINSIC_CONVENTIONS == ("world_to_camera",
                                                                                      "camera_to_world")
    assert J.EXTRINSIC_CONVENTIONS is vggt.EXTRINSIC_CONVENTIONS
