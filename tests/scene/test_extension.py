"""The extension as Blender sees it: built and validated by Blender's tool, installed, registered, import rules."""

import ast
import os
import zipfile

import addon_utils
import bpy
import pytest

from tools import blender_env

ROOT = blender_env.ROOT


def test_zip_contents(extension_zip):
    names = zipfile.ZipFile(extension_zip).namelist()
    assert "blender_manifest.toml" in names and "__init__.py" in names
    assert "scpainter_blender/core/vggt/predictions.py" in names and "backend/__main__.py" in names
    assert "operators/import_vggt.py" in names and "panels/main.py" in names
    for excluded in ("tests/", "bench/", "docs/", "tools/", ".ci/", "Makefile", "requirements.txt", ".venv/",
                     ".venv-bpy42/", ".venv-bpy45/", "requirements-backend.txt", ".venv-backend/",
                     "scpainter_blender/street/"):
        assert not [n for n in names if n.startswith(excluded)], excluded
    assert not [n for n in names if "__pycache__" in n]


def _street_imports(name, source):
    """The imports of module ``name`` (its path in the zip) that reach the street package, absolute or relative."""
    package = name.split("/")[:-1]
    found = []
    for node in ast.walk(ast.parse(source, name)):
        if isinstance(node, ast.Import):
            targets = [a.name.split(".") for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            base = base + (node.module.split(".") if node.module else [])
            targets = [base + [a.name] for a in node.names]
        else:
            continue
        found += [".".join(t) for t in targets if "street" in t[:-1] or t[-1] == "street"]
    return found


def test_shipped_code_never_imports_the_street(extension_zip):
    """The procedural street is left out of the zip: no shipped module may import it (the add-on registers from
    this very zip in test_installed_and_enabled)."""
    with zipfile.ZipFile(extension_zip) as z:
        sources = {n: z.read(n).decode() for n in z.namelist() if n.endswith(".py")}
    assert "scpainter_blender/core/vggt/npz.py" in sources and "backend/train/street_clip.py" in sources
    assert _street_imports("tests/x.py", "from scpainter_blender.street import build\nfrom .street import a") == \
        ["scpainter_blender.street.build", "tests.street.a"]  # the check sees both kinds
    assert _street_imports("scpainter_blender/scene/x.py", "from ..street.dataset import view_name") == \
        ["scpainter_blender.street.dataset.view_name"]
    assert {n: _street_imports(n, src) for n, src in sources.items() if _street_imports(n, src)} == {}


def _our_classes():
    return sorted(n for n in dir(bpy.types) if n.startswith("SCPAINTER_"))


def _our_menu_entries():
    funcs = getattr(bpy.types.TOPBAR_MT_file_import.draw, "_draw_funcs", [])
    return [f for f in funcs if "scpainter" in getattr(f, "__module__", "")]


def test_installed_and_enabled(addon):
    assert addon in bpy.context.preferences.addons
    prefs = bpy.context.preferences.addons[addon].preferences
    assert prefs.backend_python == "" and prefs.device == "AUTO" and hasattr(prefs, "checkpoint_dir")
    assert hasattr(bpy.ops.scpainter, "import_vggt")
    assert {"SCPAINTER_OT_import_vggt", "SCPAINTER_OT_import_gaussians", "SCPAINTER_PT_main",
            "SCPAINTER_FH_vggt", "SCPAINTER_FH_gaussians"} <= set(_our_classes())
    assert bpy.types.SCPAINTER_PT_main.bl_category == "SCPainter"
    assert len(_our_menu_entries()) == 2
    mod = __import__(addon, fromlist=["register"])
    assert os.path.realpath(mod.__file__).startswith(os.path.realpath(os.environ["BLENDER_USER_RESOURCES"]))


def test_register_unregister_register_leaves_nothing_behind(addon):
    before_classes, before_menu = _our_classes(), len(_our_menu_entries())
    addon_utils.disable(addon, default_set=True)
    assert _our_classes() == []
    assert _our_menu_entries() == []
    assert not hasattr(bpy.types.Scene, "scpainter_output_dir")
    with pytest.raises((AttributeError, RuntimeError, KeyError)):
        bpy.ops.scpainter.import_vggt.get_rna_type()
    addon_utils.enable(addon, default_set=True)
    assert _our_classes() == before_classes
    assert len(_our_menu_entries()) == before_menu == 2
    assert hasattr(bpy.ops.scpainter, "import_vggt")


# -- import rules (docs/design.md §2) ---------------------------------------------------------------------

def _py_files(*dirs):
    for d in dirs:
        base = os.path.join(ROOT, d)
        if os.path.isfile(base):
            yield d
            continue
        for dirpath, _, files in os.walk(base):
            for f in files:
                if f.endswith(".py"):
                    yield os.path.relpath(os.path.join(dirpath, f), ROOT)


def _imports(rel):
    tree = ast.parse(open(os.path.join(ROOT, rel)).read(), rel)
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, 0) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            out.append((node.module or "", node.level))
    return out


def test_core_and_backend_never_import_bpy():
    for rel in _py_files("scpainter_blender/core", "backend", "scpainter_blender/backend_client.py"):
        for name, level in _imports(rel):
            assert level or name.split(".")[0] not in ("bpy", "bpy_extras", "mathutils", "addon_utils"), (rel, name)


def test_heavy_packages_only_in_backend():
    shipped = [f for f in _py_files("__init__.py", "operators", "panels", "scpainter_blender")]
    for rel in shipped:
        for name, level in _imports(rel):
            assert level or name.split(".")[0] not in ("torch", "diffusers", "transformers", "open3d", "trimesh"), \
                (rel, name)


def test_scpainter_blender_init_imports_nothing():
    for pkg in ("scpainter_blender/__init__.py", "scpainter_blender/core/__init__.py"):
        assert _imports(pkg) == [], pkg


def test_imports_inside_the_extension_are_relative():
    """Blender installs the extension as bl_ext.<repo>.scpainter: absolute imports of our own modules break."""
    ours = {"scpainter_blender", "operators", "panels", "backend", "tools"}
    for rel in _py_files("__init__.py", "operators", "panels", "scpainter_blender"):
        for name, level in _imports(rel):
            assert level or name.split(".")[0] not in ours, (rel, name)


def test_backend_uses_only_the_core_of_the_addon():
    """The backend runs outside Blender: of the add-on it may use core and nothing that needs bpy."""
    for rel in _py_files("backend"):
        for name, level in _imports(rel):
            if name.startswith("scpainter_blender"):
                assert name.startswith("scpainter_blender.core"), (rel, name)
