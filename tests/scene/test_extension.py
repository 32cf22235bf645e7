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
    assert len(_our_menu_entries()) == 3   # VGGT, Gaussian asset, recorded objects
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
    assert len(_our_menu_entries()) == before_menu == 3
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
    for rel in _py_files("scpainter_blender/core", "backend", "scpainter_blender/runs/client.py"):
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


# -- the command line's package (scpainter_blender/cli/: one module per command) -----------------------------------

CLI = "scpainter_blender/cli"
# what the command line may use of the add-on: the bpy-free core, the scene layer, the runs of the backend
CLI_MAY_IMPORT = ("scpainter_blender.core", "scpainter_blender.scene", "scpainter_blender.runs",
                  "scpainter_blender.cli")


def _resolved_imports(rel):
    """The modules (or names in them) that file ``rel`` imports, relative imports made absolute: (name, relative)."""
    package = rel[:-len(".py")].split("/")[:-1]
    out = []
    for node in ast.walk(ast.parse(open(os.path.join(ROOT, rel)).read(), rel)):
        if isinstance(node, ast.Import):
            out += [(a.name, False) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level:
            base = package[:len(package) - node.level + 1] + (node.module.split(".") if node.module else [])
            out += [(".".join(base + [a.name]), True) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            out.append((node.module, False))
    return out


def test_cli_imports_only_core_scene_and_runs():
    """``scpainter_blender/cli/`` is the top of the Blender side: of the add-on it uses core, scene and runs
    (relative); otherwise the standard library and bpy."""
    import sys

    files = list(_py_files(CLI))
    assert f"{CLI}/__init__.py" in files and f"{CLI}/common.py" in files
    assert ("scpainter_blender.runs.client", True) in _resolved_imports(f"{CLI}/batch.py")  # relative, resolved
    for rel in files:
        for name, relative in _resolved_imports(rel):
            if relative:
                assert name.startswith(CLI_MAY_IMPORT), (rel, name)
            else:
                assert name.split(".")[0] in sys.stdlib_module_names or name.split(".")[0] == "bpy", (rel, name)


def test_only_the_addon_root_imports_the_cli():
    """Nothing below the command line imports it (scene, core, operators, panels); the root registers it."""
    for rel in _py_files("operators", "panels", "scpainter_blender"):
        if rel.startswith(CLI + "/"):
            continue
        assert not [n for n, relative in _resolved_imports(rel)
                    if relative and (n == "scpainter_blender.cli" or n.startswith("scpainter_blender.cli."))], rel
    assert ("scpainter_blender.cli", True) in _resolved_imports("__init__.py")


def _unannotated_functions(tree):
    """The functions of ``tree`` that leave a parameter or the return without an annotation (their names)."""
    bare = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            a = node.args
            params = [p for p in a.posonlyargs + a.args + a.kwonlyargs if p.arg not in ("self", "cls")]
            params += [p for p in (a.vararg, a.kwarg) if p is not None]
            if node.returns is None or any(p.annotation is None for p in params):
                bare.append(node.name)
    return bare


def test_cli_command_modules_have_the_command_shape():
    """Every module of ``scpainter_blender/cli/`` but the package and ``common.py`` is one command: ``NAME``,
    ``ORDER`` (unique), ``add_parser(sub)`` and ``run(args)``; every function of the package fully annotated."""
    orders = {}
    for rel in _py_files(CLI):
        tree = ast.parse(open(os.path.join(ROOT, rel)).read(), rel)
        assert _unannotated_functions(tree) == [], rel
        if os.path.basename(rel) in ("__init__.py", "common.py"):
            continue
        top = {t.id: n.value for n in tree.body if isinstance(n, ast.Assign) for t in n.targets
               if isinstance(t, ast.Name)}
        functions = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
        assert isinstance(top.get("NAME"), ast.Constant) and isinstance(top["NAME"].value, str), rel
        assert isinstance(top.get("ORDER"), ast.Constant) and isinstance(top["ORDER"].value, int), rel
        assert [a.arg for a in functions["add_parser"].args.args] == ["sub"], rel
        assert [a.arg for a in functions["run"].args.args] == ["args"], rel
        assert top["ORDER"].value not in orders, (rel, orders)
        orders[top["ORDER"].value] = top["NAME"].value
    assert len(orders) >= 6 and len(set(orders.values())) == len(orders), orders


def test_cli_finds_its_commands_in_the_installed_extension(addon):
    """Installed, the package is ``bl_ext.<repo>.scpainter.scpainter_blender.cli``: its commands are found there,
    in ``--help``'s order (the commands of the old parser keep theirs), each the installed module."""
    import sys

    cli = sys.modules[addon + ".scpainter_blender.cli"]
    names = [c.NAME for c in cli.COMMANDS]
    old = ["import", "render", "generate", "batch", "vary", "export"]   # --help's order before the split: kept
    assert [n for n in names if n in old] == old and len(set(names)) == len(names)  # a new command joins by ORDER
    assert all(c.__name__.startswith(addon + ".scpainter_blender.cli.") for c in cli.COMMANDS)
    sub = next(a for a in cli._parser()._actions if a.dest == "command")
    assert list(sub.choices) == [c.NAME for c in cli.COMMANDS]


# -- the import graph: no cycle; runs/ and scene/ one way (docs/design.md §2) ------------------------------------

def _module_name(rel):
    """``scpainter_blender/runs/client.py`` -> ``scpainter_blender.runs.client``; a package is its ``__init__``."""
    parts = rel[:-3].split("/")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _runtime_imports(source, rel):
    """The (module or None, level, names) imported when module ``rel`` runs: an ``if TYPE_CHECKING:`` block (an
    annotation's import, never executed) is left out."""
    out = []

    def visit(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and ast.unparse(child.test).endswith("TYPE_CHECKING"):
                for sub in child.orelse:
                    visit_one(sub)
                continue
            visit_one(child)

    def visit_one(child):
        if isinstance(child, ast.Import):
            out.extend((a.name, 0, ()) for a in child.names)
        elif isinstance(child, ast.ImportFrom):
            out.append((child.module, child.level, tuple(a.name for a in child.names)))
        visit(child)

    visit(ast.parse(source, rel))
    return out


def _import_graph(sources):
    """{module: the add-on modules it imports} over ``sources`` ({path: text}); an import of a package's member
    that is a module counts as that module, of a name in a package's ``__init__`` as the package."""
    modules = {_module_name(rel): rel for rel in sources}
    graph = {}
    for name, rel in modules.items():
        parts = name.split(".") if name else []   # "" is the extension's own __init__.py
        package = parts if rel.endswith("__init__.py") else parts[:-1]
        deps = set()
        for module, level, names in _runtime_imports(sources[rel], rel):
            base = package[:len(package) - level + 1] if level else []
            base = ".".join(base + (module.split(".") if module else []))
            for member in names or (None,):
                full = f"{base}.{member}" if member and base else (member or base)
                target = full if full in modules else base if base in modules else None
                if target and target != name:
                    deps.add(target)
        graph[name] = deps
    return graph


def _cycles(graph):
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def connect(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while not component or component[-1] != v:
                component.append(stack.pop())
                on_stack.discard(component[-1])
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return found


def _addon_graph():
    rels = list(_py_files("__init__.py", "operators", "panels", "scpainter_blender"))
    return _import_graph({rel.replace(os.sep, "/"): open(os.path.join(ROOT, rel), encoding="utf-8").read()
                          for rel in rels})


def test_the_cycle_check_sees_a_cycle():
    sources = {"p/__init__.py": "", "p/a.py": "from . import b\n", "p/b.py": "from .c import X\n",
               "p/c.py": "from .a import Y\nfrom typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from . import d\n",
               "p/d.py": "from . import c\n"}
    graph = _import_graph(sources)
    assert graph["p.a"] == {"p.b"} and graph["p.c"] == {"p.a"} and graph["p.d"] == {"p.c"}
    assert _cycles(graph) == [["p.a", "p.b", "p.c"]]


def test_no_import_cycle_among_the_addon_modules():
    """Each fact lives in the module that owns it, so no two modules need each other (an import inside a function
    does not hide one: every import is read)."""
    graph = _addon_graph()
    assert "scpainter_blender.runs.camera_run" in graph and "operators.backend_run" in graph
    assert {"operators", "scpainter_blender.runs.warm_session"} <= graph[""]   # the root __init__.py's, resolved
    assert _cycles(graph) == []


#: What runs/ takes from scene/ (the arrow goes runs -> scene): the job it exports, the output folders and
#: SceneError, the results it loads into Blender.
RUNS_USES_OF_SCENE = {"scpainter_blender.scene.job_export", "scpainter_blender.scene.props",
                      "scpainter_blender.scene.results"}
#: The bpy-free part of runs/ (the backend's command line and processes, the session's warm backend): stdlib and
#: core, so scene/ may start a one-shot conversion with ``client.Invocation`` and nothing comes back around.
RUNS_WITHOUT_BPY = ("scpainter_blender/runs/client.py", "scpainter_blender/runs/warm_process.py",
                    "scpainter_blender/runs/warm_session.py")


def test_runs_and_scene_import_each_other_one_way():
    """runs/ may import bpy, core and of scene/ only ``RUNS_USES_OF_SCENE``; scene/ never imports runs/ but its
    bpy-free ``runs.client`` (the command line, ``scpainter_blender/cli/``, is a front end, like operators/: it uses
    both)."""
    graph = _addon_graph()
    wrong = []
    for name, deps in graph.items():
        if name.startswith("scpainter_blender.runs"):
            wrong += [(name, d) for d in deps if d.startswith("scpainter_blender.scene")
                      and d not in RUNS_USES_OF_SCENE]
            wrong += [(name, d) for d in deps if d.split(".")[0] in ("operators", "panels")]
        elif name.startswith("scpainter_blender.scene"):
            wrong += [(name, d) for d in deps if d.startswith("scpainter_blender.runs")
                      and d != "scpainter_blender.runs.client"]
    assert wrong == []
    for rel in RUNS_WITHOUT_BPY:
        for name, level in _imports(rel):
            assert level or name.split(".")[0] not in ("bpy", "bpy_extras", "mathutils", "addon_utils"), (rel, name)
        assert not [d for d in graph[_module_name(rel)] if not d.startswith(("scpainter_blender.core",
                                                                              "scpainter_blender.runs"))], rel
        assert not [d for d in graph[_module_name(rel)]
                    if d.startswith("scpainter_blender.runs") and d.replace(".", "/") + ".py" not in RUNS_WITHOUT_BPY]
