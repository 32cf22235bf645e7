"""The documents' lists checked against the code, so that they cannot go stale: docs/design.md §2's module table
against the tracked sources, the command lists of docs/design.md and the README against the two argparse parsers
(which also build ``--help``), the options and choices the documents spell against those parsers, and the README's
format tables against the readers' own tables.

At the top of tests/ (as test_packaging.py and test_demo.py): it checks documents, which mirror no package.

The conventions read here are stated in the documents themselves (design.md §2 above the table, §4.4 above the
command lists). A failure lists exactly what to add or remove, and where.
"""

import ast
import os
import re

import pytest

from tests_support import SHIPPED, tracked_sources

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BACKEND_PROG = "python -m backend"
BLENDER_PROG = "blender -c scpainter"


def _read(rel):
    with open(os.path.join(ROOT, rel), encoding="utf-8") as f:
        return f.read()


def _section(text, heading, next_heading):
    start = text.index(heading)
    return text[start:text.index(next_heading, start)]


_FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def _spans(text):
    """Every inline code span of a markdown text (it may run over a line break), newlines as spaces; fenced code
    blocks are no spans."""
    return [" ".join(s.split()) for s in re.findall(r"`([^`]+)`", _FENCE.sub("", text))]


def _command_lines(text, prog):
    """What a document shows of ``prog``'s command lines: its code spans that start with ``prog``, and the lines of
    its fenced code blocks from ``prog`` on (``.venv/bin/python -m backend …`` included), comments cut."""
    out = [s for s in _spans(text) if s.startswith(prog + " ")]
    for block in _FENCE.findall(text):
        for line in block.splitlines()[1:-1]:
            line = line.split("  #")[0]
            if prog + " " in line:
                out.append(" ".join(line[line.index(prog):].split()))
    return out


def _cells(line):
    """The cells of a markdown table row; a "|" inside a code span is not a separator."""
    cells, cell, code = [], "", False
    for ch in line.strip().strip("|"):
        if ch == "`":
            code = not code
        if ch == "|" and not code:
            cells.append(cell.strip())
            cell = ""
        else:
            cell += ch
    return cells + [cell.strip()]


def _table(text, header):
    """The rows (lists of cells) of the markdown table whose header row starts with ``header``."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header))
    rows = []
    for line in lines[start + 2:]:  # after the header and its |---| line
        if not line.startswith("|"):
            break
        rows.append(_cells(line))
    return rows


# -- the commands: one small function per parser, so a move of either parser changes only it ----------------------

def _sub_commands(parser):
    import argparse

    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def backend_parsers():
    """{command: its argparse parser} of ``python -m backend`` (the parser ``--help`` prints)."""
    from backend.__main__ import build_parser

    return _sub_commands(build_parser())


def blender_parsers():
    """{command: its argparse parser} of ``blender -c scpainter`` (needs the bpy module: skips without it)."""
    pytest.importorskip("bpy")
    from scpainter_blender.cli import _parser

    return _sub_commands(_parser())


PARSERS = {BACKEND_PROG: backend_parsers, BLENDER_PROG: blender_parsers}


# -- design.md §2: the module table ----------------------------------------------------------------------------------

def _tracked_py():
    return set(tracked_sources())


def _holds_nothing(text):
    """A package ``__init__.py`` with nothing but (at most) a docstring: exempt from the table by rule."""
    body = ast.parse(text).body
    return not body or (len(body) == 1 and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant))


def _resolve(name, tracked):
    """A name of the table's first column, as the convention above the table says: from the repository root when
    something tracked is there, else from ``scpainter_blender/``."""
    def exists(path):
        return path in tracked or any(t.startswith(path) for t in tracked) if path.endswith("/") else \
            os.path.exists(os.path.join(ROOT, path))

    return name if exists(name) else "scpainter_blender/" + name


def module_table():
    """[(row's place as written, resolved folder or file, its folder, {module paths the row names})] of design.md
    §2."""
    tracked = _tracked_py()
    rows = _table(_section(_read("docs/design.md"), "## 2.", "## 3."), "| where | what | may import |")
    out = []
    for cells in rows:
        where, what = cells[0], cells[1]
        places = [s for s in re.findall(r"`([^`]+)`", where) if s.endswith("/") or s.endswith(".py")]
        if not places:
            continue  # pyproject.toml: no module
        assert len(places) == 1, f"design.md §2: a row names one folder or file in its first column: {where!r}"
        place = _resolve(places[0], tracked)
        folder = place if place.endswith("/") else os.path.dirname(place) + "/"
        named = {place} if place.endswith(".py") else set()
        named |= {folder + s for s in re.findall(r"`([\w/]+\.py)`", what)}
        out.append((places[0], place, folder, named))
    return out


def test_design_module_table_names_every_shipped_module_and_nothing_else():
    sources = tracked_sources(shipped_only=True)
    tracked = _tracked_py()
    rows = module_table()
    named = set().union(*(n for _, _, _, n in rows))
    required = {p for p, text in sources.items() if not (p.endswith("/__init__.py") and _holds_nothing(text))}
    problems = []
    for path in sorted(required - named):
        folder = os.path.dirname(path) + "/"
        owners = [written for written, place, _, _ in rows if place == folder]
        if owners:  # the first row of its folder (`core/` has two)
            problems.append(f"missing: `{os.path.basename(path)}` in the row `{owners[0]}` ({path})")
        else:  # as the convention spells a folder: short when nothing at the root has its name
            short = folder[len("scpainter_blender/"):] if folder.startswith("scpainter_blender/") and \
                _resolve(folder[len("scpainter_blender/"):], tracked) == folder else folder
            problems.append(f"missing: {path}: no row for its folder; add a row `{short}` naming "
                            f"`{os.path.basename(path)}`")
    for written, place, folder, names in rows:
        if place.endswith("/") and not any(t.startswith(place) for t in tracked):
            problems.append(f"stale: the row `{written}`: no folder {place}")
        for path in sorted(names - tracked):
            problems.append(f"stale: `{path[len(folder):]}` in the row `{written}` ({path} is not a tracked file)")
    assert not problems, "docs/design.md §2's module table (convention above it):\n  " + "\n  ".join(problems)
    assert {p.split("/")[0] for p in required} <= set(SHIPPED)


def test_design_layout_names_every_package():
    """§2's layout block (the tree above the rules) names every folder of shipped modules (as `name/`)."""
    section = _section(_read("docs/design.md"), "## 2.", "## 3.")
    block = _FENCE.search(section).group(0)
    named = set(re.findall(r"([\w.-]+)/", block))
    folders = {os.path.dirname(p) for p in tracked_sources(shipped_only=True)} - {""}
    missing = sorted(f for f in folders if os.path.basename(f) not in named)
    assert not missing, f"docs/design.md §2's layout block misses the folders {missing} (add each as `name/` with " \
                        f"what it holds, indented under its parent)"
    assert {"core", "splats", "render"} <= named


def test_module_table_sees_the_rows_it_should():
    """The parser of the table is not blind: known rows resolve where the convention says."""
    rows = {written: (place, names) for written, place, _, names in module_table()}
    assert rows["core/splats/"][0] == "scpainter_blender/core/splats/"
    assert "scpainter_blender/core/splats/reader.py" in rows["core/splats/"][1]
    assert rows["backend/render/"][0] == "backend/render/"
    assert "backend/render/command.py" in rows["backend/render/"][1]
    assert rows["__init__.py"][1] == {"__init__.py"}
    assert _holds_nothing('"""A docstring."""\n') and _holds_nothing("")
    assert not _holds_nothing('"""A docstring."""\nfrom . import main\n')


# -- the command lists ----------------------------------------------------------------------------------------------

def _command_list(text, prog, where):
    """The commands of the one code span ``PROG cmd ARGS | cmd ARGS | ...`` (commands separated by " | ")."""
    lists = [s for s in _spans(text) if s.startswith(prog + " ") and " | " in s]
    assert len(lists) == 1, f"{where}: one command list `{prog} cmd ARGS | cmd ARGS | ...` expected, found {lists}"
    return [piece.split()[0] for piece in lists[0][len(prog):].split(" | ")]


@pytest.mark.parametrize("doc", ["docs/design.md", "README.md"])
@pytest.mark.parametrize("prog", [BACKEND_PROG, BLENDER_PROG])
def test_command_lists_are_the_parsers(doc, prog):
    parsers = PARSERS[prog]()
    listed = _command_list(_read(doc), prog, doc)
    missing = [c for c in parsers if c not in listed]
    stale = [c for c in listed if c not in parsers]
    assert not missing and not stale and len(listed) == len(set(listed)), \
        f"{doc}'s command list of `{prog}`: missing {missing}, no longer commands {stale}, listed {listed}"


# -- options and choices the documents spell in a command's code span -----------------------------------------------

def _option_claims(text, prog, commands):
    """(span, [commands], --option, [choices or None]) for every ``--option`` of every code span that starts with
    ``prog cmd`` (or ``prog a|b|c``), the span's commands being parser commands; ``--opt a|b|c`` (or ``a,b,c``)
    gives choices."""
    claims = []
    for span in _command_lines(text, prog):
        if " | " in span:
            continue
        names = span[len(prog) + 1:].split()[0].split("|")
        if not all(n in commands for n in names):
            continue  # not a command (checked by the command lists)
        for opt, value in re.findall(r"(--[a-z][\w-]*)(?:[ =]([^\s\]\[]+))?", span):
            # a|b|c: the choices; a,b,c: the names an option taking several separated by commas lists
            # (export --format)
            choices = re.split(r"[|,]", value) if value and re.search(r"[|,]", value) else None
            claims.append((span, names, opt, choices))
    return claims


@pytest.mark.parametrize("doc", ["docs/design.md", "README.md"])
@pytest.mark.parametrize("prog", [BACKEND_PROG, BLENDER_PROG])
def test_documented_options_exist(doc, prog):
    """Every ``--option`` a document shows in a command's code span is that command's, and every ``a|b|c`` it
    lists for it is one of the option's choices (no name that no longer exists)."""
    parsers = PARSERS[prog]()
    problems, seen = [], 0
    for span, names, opt, choices in _option_claims(_read(doc), prog, parsers):
        for name in names:
            actions = {s: a for a in parsers[name]._actions for s in a.option_strings}
            seen += 1
            if opt not in actions:
                problems.append(f"`{prog} {name}` has no {opt} (in `{span}`)")
            elif choices and actions[opt].choices is not None:
                unknown = [c for c in choices if c not in actions[opt].choices]
                if unknown:
                    problems.append(f"`{prog} {name} {opt}` has no choice {unknown} (choices "
                                    f"{list(actions[opt].choices)}; in `{span}`)")
    assert not problems, f"{doc}:\n  " + "\n  ".join(problems)
    assert seen, f"{doc}: no option of `{prog}` found (the span parser is blind)"


# -- the README's format tables -------------------------------------------------------------------------------------

def _extensions(cell):
    return {s for s in re.findall(r"`([^`]+)`", cell) if re.fullmatch(r"\.[a-z0-9]+", s)}


def test_readme_splat_and_mesh_formats_are_the_readers():
    """The README's "Formats accepted" table: its first column names each format's extensions (`.ply`); the Gaussian
    rows together are ``core.splats.reader.FORMAT_EXTENSIONS`` (every reader has a row), the mesh row is the mesh
    loader's ``UP_BY_EXTENSION``."""
    from backend.mesh.load import UP_BY_EXTENSION
    from scpainter_blender.core.splats import reader

    assert set(reader.READERS) == set(reader.FORMAT_EXTENSIONS), \
        "every Gaussian format (core/splats/reader.py READERS) has its extensions in FORMAT_EXTENSIONS"
    rows = _table(_read("README.md"), "| input | what it is | notes |")
    mesh = [r[0] for r in rows if r[0].startswith("mesh")]
    assert len(mesh) == 1, f"README: one row of mesh cars expected, found {mesh}"
    splat_rows = [r[0] for r in rows if not r[0].startswith("mesh") and "predictions.npz" not in r[0]]
    problems = []
    if _extensions(mesh[0]) != set(UP_BY_EXTENSION):
        problems.append(f"the mesh row names {sorted(_extensions(mesh[0]))}, the mesh loader reads "
                        f"{sorted(UP_BY_EXTENSION)} (backend/mesh/load.py UP_BY_EXTENSION)")
    named = set().union(*map(_extensions, splat_rows))
    known = {e for exts in reader.FORMAT_EXTENSIONS.values() for e in exts}
    if named != known:
        problems.append(f"the Gaussian rows name {sorted(named)}, the readers take {sorted(known)} "
                        f"(core/splats/reader.py FORMAT_EXTENSIONS): missing {sorted(known - named)}, "
                        f"stale {sorted(named - known)}")
    for row in splat_rows:
        if not _extensions(row):
            problems.append(f"the row {row!r} names no extension in its first column")
    for fmt, exts in reader.FORMAT_EXTENSIONS.items():
        if not any(_extensions(row) & set(exts) for row in splat_rows):
            problems.append(f"no row for the format {fmt!r} ({', '.join(exts)})")
    assert not problems, "README.md, Formats accepted:\n  " + "\n  ".join(problems)


@pytest.mark.parametrize("doc", ["docs/design.md", "README.md"])
def test_export_formats_are_the_protocols(doc):
    """Every ``--format a|b|c`` of ``export`` in the document lists exactly ``EXPORT_FORMAT_NAMES``."""
    from scpainter_blender.core.backend_protocol import EXPORT_FORMAT_NAMES

    lists = [c for span, names, opt, c in _option_claims(_read(doc), BACKEND_PROG, {"export"}) if opt == "--format"]
    assert lists, f"{doc}: no `{BACKEND_PROG} export … --format a|b|c` found"
    for listed in lists:
        assert listed == list(EXPORT_FORMAT_NAMES), f"{doc}: export --format lists {listed}, the code " \
                                                    f"{list(EXPORT_FORMAT_NAMES)} (core/backend_protocol.py)"


def test_design_names_every_gaussian_layout():
    """design.md §8's list of ``GaussianPly.format`` values is ``FORMAT_NAMES`` (the layouts of core/splats/formats.py's
    records), none missing, none stale."""
    from scpainter_blender.core.splats import formats

    text = _section(_read("docs/design.md"), "## 8. Gaussian assets", "\n## 9.")
    claim = re.search(r"with `format` = .*?((?:`\w+`\s*/\s*)+`\w+`)\)", text, re.S)
    assert claim, "docs/design.md §8: the list of `format` values (`with `format` = `a` / `b`)`) was not found"
    listed = re.findall(r"`(\w+)`", claim.group(1))
    assert set(listed) == set(formats.FORMAT_NAMES) and len(listed) == len(set(listed)), \
        f"docs/design.md §8 lists the layouts {listed}; core/splats/formats.py has {sorted(formats.FORMAT_NAMES)}"


def test_the_readmes_sidecar_and_rig_file_examples_are_read_by_their_readers():
    """The README shows a sensors sidecar and a rig file: both are what their readers accept."""
    import json

    from scpainter_blender.core import rig
    from scpainter_blender.core.vggt import sensors

    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    block = text[text.index('{"schema": "scpainter.sensors/1"'):]
    sidecar, rig_file = (json.loads(part) for part in block[:block.index("```")].strip().split("\n\n"))
    assert sensors.from_dict(sidecar, "README.md").sensor == ["CAM_FRONT", "CAM_BACK"]
    assert rig_file.pop("schema") == rig.RIG_SCHEMA
    assert rig.Rig.from_dict(rig_file, "README.md").lidar.model == "nuscenes-32"


# -- generation defaults --------------------------------------------------------------------------------------------

def test_the_readmes_generate_defaults_are_the_code():
    """The README's "defaults (N steps, overlap N, seed N" and the speed settings' "default X" are
    ``job.GENERATE_DEFAULTS`` (they said 25 steps after the default became 18); the documents' stock-sampler command
    line parses (the backend's own parser) to ``job.STOCK_SAMPLING``."""
    from scpainter_blender.core import job as J

    text = _read("README.md")
    m = re.search(r"from the defaults \((\d+) steps, overlap (\d+), seed (\d+)", text)
    assert m, "README.md: the generate defaults sentence ('from the defaults (N steps, overlap N, seed N') is gone"
    assert [int(v) for v in m.groups()] == [J.GENERATE_DEFAULTS[k] for k in ("steps", "overlap", "seed")], m.group(0)
    for name in ("sampler", "feature-reuse", "compile", "gpu-tuning"):
        said = re.search(rf"`--{name}[^`]*` \([^`]*?default (\w+)", text)
        assert said and said.group(1) == str(J.GENERATE_DEFAULTS[name.replace("-", "_")]), (name, said)
    gen = backend_parsers()["generate"]
    for doc in ("README.md", "docs/design.md"):
        m = re.search(r"`(--sampler euler\s+--steps[^`]*)`", _read(doc))
        assert m, f"{doc}: stock SVD's sampler as a command line is gone"
        args = vars(gen.parse_args(["job.json", *m.group(1).split()]))
        got = {k: args[k] if args[k] is not None else J.GENERATE_DEFAULTS[k] for k in J.STOCK_SAMPLING}
        assert got == J.STOCK_SAMPLING, (doc, m.group(1))
