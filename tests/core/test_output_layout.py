"""The output folder's names live in one module (``core/output_layout.py``): the layout itself, and a scan of the
shipped code for a name spelled anywhere else."""

import ast
import os
import re

import pytest

from scpainter_blender.core import locking, outputs
from scpainter_blender.core.output_layout import (CONDITION_EXR, CONDITION_PREVIEW, FRAME_DIGITS, GENERATED_FRAME,
                                                  FrameFiles, OutputLayout)

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
HOME = "scpainter_blender/core/output_layout.py"


def test_paths(tmp_path):
    lay = OutputLayout(tmp_path)
    root = str(tmp_path)
    assert lay.root == root and repr(lay) == f"OutputLayout({root!r})"
    assert lay.job == os.path.join(root, "job.json")
    assert lay.lock == os.path.join(root, ".scpainter.lock")
    assert lay.log == os.path.join(root, "backend.log")
    assert lay.video == os.path.join(root, "generated.mp4")
    assert lay.state == os.path.join(root, "generate_state.safetensors")
    assert lay.conditions == os.path.join(root, "conditions")
    assert lay.record == os.path.join(root, "conditions", "record.json")
    assert lay.former_record == os.path.join(root, "conditions", "job_key.txt")
    assert lay.generated == os.path.join(root, "generated")
    assert lay.manifest == os.path.join(root, "generated", "manifest.json")
    assert (lay.eval_baseline, lay.eval_sheet) == (os.path.join(root, "baseline.mp4"),
                                                   os.path.join(root, "contact_sheet.png"))
    assert OutputLayout.FOLDERS == ("conditions", "generated")


def test_per_frame_names(tmp_path):
    lay = OutputLayout(str(tmp_path))
    assert FRAME_DIGITS == 6
    assert lay.condition_exr(12) == os.path.join(str(tmp_path), "conditions", "frame_000012.exr")
    assert lay.condition_preview(12) == os.path.join(str(tmp_path), "conditions", "preview_000012.png")
    assert lay.generated_frame(1234567) == os.path.join(str(tmp_path), "generated", "frame_1234567.png")
    assert lay.frame_labels(12) == os.path.join(str(tmp_path), "conditions", "labels_000012.json")
    assert lay.labelled_preview(12) == os.path.join(str(tmp_path), "conditions", "labelled_000012.png")
    assert lay.export("kitti") == os.path.join(str(tmp_path), "export", "kitti")
    assert OutputLayout.condition_names(iter([3, 1])) == [
        "frame_000003.exr", "preview_000003.png", "labels_000003.json", "labelled_000003.png",
        "frame_000001.exr", "preview_000001.png", "labels_000001.json", "labelled_000001.png"]
    assert GENERATED_FRAME.name(0) == "frame_000000.png" and FrameFiles("x_", ".y").name(7) == "x_000007.y"


def test_files_in_a_folder(tmp_path):
    lay = OutputLayout(tmp_path)
    assert CONDITION_EXR.in_folder(lay.conditions) == []  # no folder yet
    os.makedirs(lay.conditions)
    for f in (10, 2):
        for path in (lay.condition_exr(f), lay.condition_preview(f)):
            open(path, "w").close()
    open(lay.record, "w").close()
    assert CONDITION_EXR.in_folder(lay.conditions) == [lay.condition_exr(2), lay.condition_exr(10)]
    assert CONDITION_PREVIEW.in_folder(lay.conditions) == [lay.condition_preview(2), lay.condition_preview(10)]
    assert GENERATED_FRAME.in_folder(lay.conditions) == []  # frame_*.png: none among the EXRs


def test_the_other_core_modules_use_it(tmp_path):
    assert locking.LOCK_NAME == OutputLayout.LOCK
    with locking.OutputLock(str(tmp_path), "test"):
        assert os.path.isfile(OutputLayout(tmp_path).lock)
    os.makedirs(OutputLayout(tmp_path).log)  # a folder where the log goes: check_output names it
    with pytest.raises(outputs.InputError) as e:
        outputs.check_output(str(tmp_path))
    assert e.value.path == OutputLayout(tmp_path).log


# ------------------------------------------------------------------------------------ spelled once, in its home

#: Output file names: no string in the shipped code may contain one, outside ``HOME``.
NAMES = ("generated.mp4", "manifest.json", "backend.log", "generate_state.safetensors", "record.json",
         ".scpainter.lock", "job_key.txt", "preview_", "baseline.mp4", "contact_sheet.png", "variation.json",
         "variants.txt")
#: Folder names: none may be a path component outside ``HOME`` (a dictionary key or an event's ``kind`` may).
FOLDERS = tuple(OutputLayout.FOLDERS)
#: A folder name beside a slash, as a whole component ("scpainter.conditions/1", a schema, is not one).
_BESIDE_SLASH = re.compile(r"(?:^|/)(?:%s)/|/(?:%s)(?:/|$)" % ("|".join(FOLDERS), "|".join(FOLDERS)))


def _docstrings(tree) -> set:
    ids = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                ids.add(id(first.value))
    return ids


def _is_text(node) -> bool:
    return isinstance(node, ast.Constant) and isinstance(node.value, str)


def spelled(source: str, name: str = "<source>") -> list:
    """(line, text) of each string in ``source`` (docstrings aside) that spells an output folder's name: one of
    ``NAMES`` anywhere in it; a folder of ``FOLDERS`` as a path component (a call's positional argument, an operand
    of ``/``, or beside a slash)."""
    tree = ast.parse(source, name)
    docs = _docstrings(tree)
    found = []
    for node in ast.walk(tree):
        if _is_text(node) and id(node) not in docs:
            text = node.value
            if any(n in text for n in NAMES) or _BESIDE_SLASH.search(text):
                found.append((node.lineno, text))
        parts = node.args if isinstance(node, ast.Call) else \
            [node.left, node.right] if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div) else []
        found += [(p.lineno, p.value) for p in parts if _is_text(p) and p.value in FOLDERS]
    return sorted(set(found))


def test_the_scan_sees_each_spelling():
    assert spelled('"""backend.log in a docstring"""\n# generated.mp4 in a comment\nx = {"generated": 1}\n'
                   'artifact(p, kind="conditions")\n') == []
    assert spelled('a = os.path.join(out, "conditions")\nb = out / "generated"\nc = f"{out}/generated/x"\n'
                   'd = "backend.log"\ne = f"preview_{n:06d}.png"\nf = "conditions/x"\n'
                   'g = "scpainter.conditions/1"\n') == \
        [(1, "conditions"), (2, "generated"), (3, "/generated/x"), (4, "backend.log"), (5, "preview_"),
         (6, "conditions/x")]


def test_output_names_are_spelled_only_in_the_layout():
    from tests_support import tracked_sources

    sources = tracked_sources(exclude=(HOME,))
    assert "backend/render/command.py" in sources and os.path.isfile(os.path.join(ROOT, HOME))
    found = {}
    for rel, text in sources.items():
        hits = spelled(text, rel)
        if hits:
            found[rel] = hits
    assert found == {}, "use scpainter_blender.core.output_layout instead of spelling these names"


def test_a_rig_jobs_folders(tmp_path):
    from scpainter_blender.core import rig
    from scpainter_blender.core.output_layout import LIDAR_SWEEP

    lay = OutputLayout(tmp_path)
    cam = lay.camera("CAM_BACK")
    assert isinstance(cam, OutputLayout) and cam.root == os.path.join(str(tmp_path), "CAM_BACK")
    assert cam.condition_exr(3) == os.path.join(str(tmp_path), "CAM_BACK", "conditions", "frame_000003.exr")
    assert OutputLayout.LIDAR == rig.NUSCENES_LIDAR == "LIDAR_TOP"
    assert lay.lidar() == os.path.join(str(tmp_path), "LIDAR_TOP")
    assert lay.lidar_sweep(12) == os.path.join(str(tmp_path), "LIDAR_TOP", "sweep_000012.pcd.bin")
    assert lay.lidar_sweep_info(12) == os.path.join(str(tmp_path), "LIDAR_TOP", "sweep_000012.json")
    assert lay.lidar_sweep(7, "LIDAR_2") == os.path.join(str(tmp_path), "LIDAR_2", "sweep_000007.pcd.bin")
    os.makedirs(lay.lidar())
    for f in (10, 2):
        open(lay.lidar_sweep(f), "w").close()
        open(lay.lidar_sweep_info(f), "w").close()
    assert LIDAR_SWEEP.in_folder(lay.lidar()) == [lay.lidar_sweep(2), lay.lidar_sweep(10)]
