"""core/backend_protocol.py is the one home of the device names, the exit codes and the event kinds; and
runs.client.Invocation.argv() is a command line the backend's own parser reads back."""

import ast
import os
import re

import pytest

from scpainter_blender.runs.client import Invocation
from scpainter_blender.core import backend_protocol as protocol

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
HOME = os.path.join("scpainter_blender", "core", "backend_protocol.py")


def test_device_names_and_exit_codes_are_spelled_only_in_their_home():
    device_list = re.compile(r"""[\[(]\s*(["'](auto|cpu|cuda)["']\s*,\s*){2}["'](auto|cpu|cuda)["']""")
    exit_def = re.compile(r"^\s*EXIT_\w+(\s*,\s*EXIT_\w+)*\s*=", re.M)
    found = []
    from tests_support import tracked_sources

    # every tracked .py outside tests/ (the tests spell the codes they assert) and the home
    for path, text in tracked_sources(exclude=(HOME.replace(os.sep, "/"),)).items():
        found += [f"{path}: device list" for _ in device_list.finditer(text)]
        found += [f"{path}: exit code defined" for _ in exit_def.finditer(text)]
        for node in ast.walk(ast.parse(text, path)):
            # a comparison with an exit code's number (exit_code == 2, returncode == 130), or returning one
            if isinstance(node, ast.Compare) and any(
                    isinstance(c, ast.Constant) and c.value in (2, 130) for c in node.comparators):
                left = ast.unparse(node.left)
                if re.search(r"exit_code|returncode", left):
                    found.append(f"{path}:{node.lineno}: {ast.unparse(node)}")
    assert not found, found


def test_device_names_match_the_preferences_enum_order():
    assert protocol.DEVICE_NAMES == ("auto", "cuda", "cpu") and protocol.DEFAULT_DEVICE in protocol.DEVICE_NAMES
    assert (protocol.EXIT_OK, protocol.EXIT_FAILED, protocol.EXIT_BAD_INPUT, protocol.EXIT_INTERRUPTED) == \
        (0, 1, 2, 130)


@pytest.mark.parametrize("run", [
    Invocation("render", jobs=("/x/job.json",), device="cpu", allow_outside=True, force=True, point_radius=2),
    Invocation("render", jobs=("/x/job.json",), data_roots=("/data",)),
    Invocation("render", jobs=("/x/job.json",), proposals="accept"),
    Invocation("generate", jobs=("/x/job.json",), data_roots=("/data", "/assets")),
    Invocation("generate", jobs=("job.json",), device="cuda", checkpoint="/ck", model="baseline", steps=3, seed=7,
               inpaint="telea"),
    Invocation("batch", batch_command="generate", lists=("a.txt", "b.txt"), trusted_lists=("t.txt",), device="auto",
               checkpoint="/ck", inpaint="navier-stokes", allow_outside=True, shard="0/1"),
    Invocation("batch", jobs=("a.json",), batch_command="render", ray="", retries=3, cpus_per_job=2.5,
               data_roots=("/data",)),
    Invocation("batch", jobs=("a.json",), ray="head:6379"),
    Invocation("doctor", checkpoint="/ck"),
    Invocation("export", jobs=("/x/job.json",), export_format="openlabel", out="/x/dataset", device="cpu",
               allow_outside=True),
    Invocation("export", jobs=("job.json",), export_format="kitti", data_roots=("/data",)),
    Invocation("export", jobs=("job.json",), export_format="coco", proposals="off"),
    Invocation("generate", jobs=("job.json",), proposals="accept"),
    Invocation("batch", jobs=("a.json", "b.json"), batch_command="render", proposals="off"),
    Invocation("mesh-asset", asset="/x/car.glb", out="/x/car.ply", count=5000),
    Invocation("splat-asset", asset="/x/car.sog", out="/x/car.ply"),
    Invocation("serve", idle_timeout=600.0, device="cpu"),
    Invocation("serve", idle_timeout=0.5),
])
def test_invocation_argv_round_trips_through_the_backend_parser(run):
    from backend.__main__ import build_parser

    args = vars(build_parser().parse_args(run.argv()))
    expected = {"command": run.command, "device": run.device, "checkpoint": run.checkpoint, "model": run.model,
                "steps": run.steps, "seed": run.seed, "inpaint": run.inpaint, "point_radius": run.point_radius,
                "force": run.force, "allow_outside": run.allow_outside, "data_root": list(run.data_roots) or None,
                "shard": run.shard, "ray": run.ray,
                "retries": run.retries, "cpus_per_job": run.cpus_per_job, "command_name": run.batch_command,
                "list": list(run.lists) or None, "trusted_list": list(run.trusted_lists) or None,
                "format": run.export_format, "out": run.out, "count": run.count, "idle_timeout": run.idle_timeout,
                "proposals": run.proposals}
    if run.command in ("render", "generate"):
        expected["job"] = run.jobs[0]
    elif run.command in ("batch", "export"):   # export: one job, or several as one dataset
        expected["jobs"] = list(run.jobs)
    elif run.command in ("mesh-asset", "splat-asset"):
        expected["mesh" if run.command == "mesh-asset" else "splats"] = run.asset
    for name, value in expected.items():
        if value is None or value is False:  # not given: the parser's default (the backend's), or no such option
            continue
        assert args[name] == value, (name, args)


def test_invocation_spells_the_asset_and_serve_command_lines_as_before():
    """The command lines the add-on started by hand before ``Invocation`` wrote them (scene/gaussians.py,
    scene/variations.py, the warm backend's ``serve``), argument for argument."""
    assert Invocation("mesh-asset", asset="/x/car.glb", out="/x/car.ply", count=5000).argv() == \
        ["mesh-asset", "/x/car.glb", "--out", "/x/car.ply", "--count", "5000"]
    assert Invocation("splat-asset", asset="/x/car.sog", out="/x/car.ply").argv() == \
        ["splat-asset", "/x/car.sog", "--out", "/x/car.ply"]
    assert Invocation(protocol.SERVE, idle_timeout=600.0, device="cpu").argv() == \
        ["serve", "--idle-timeout", "600", "--device", "cpu"]
    assert Invocation(protocol.SERVE, idle_timeout=0).argv() == ["serve", "--idle-timeout", "0"]


def test_invocation_refuses_a_device_nobody_knows():
    with pytest.raises(ValueError):
        Invocation("render", device="gpu")
    with pytest.raises(ValueError):
        Invocation("export", export_format="yolo")


def test_blender_cli_never_writes_a_command_line_value_into_the_preferences():
    package = os.path.join(ROOT, "scpainter_blender", "cli")
    names = sorted(n for n in os.listdir(package) if n.endswith(".py"))
    assert "__init__.py" in names and "common.py" in names
    for name in names:
        source = open(os.path.join(package, name), encoding="utf-8").read()
        assert not re.search(r"prefs\.\w+\s*=(?!=)", source), name
