"""The format records (core/splats/formats.py) and what is made from them: the texts and lists they replaced come
out as they were, every record's reader resolves, ``detect`` names only records, and the prose that lists formats
outside the table names none it lacks."""

import ast
import inspect
import os
import re

import pytest

from scpainter_blender.core.splats import compressed, formats, gaussians, gltf_splats, ksplat, reader, sog, spz
from scpainter_blender.core.variation import library

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def test_the_texts_and_lists_made_from_the_records_are_those_written_before():
    # the literals these names held before the records (messages and file filters stay byte-identical)
    assert gaussians.ACCEPTED == (
        "binary INRIA 3DGS PLY (float, double or half floats in ushort slots; TRELLIS/Amodal3R included), "
        "SuperSplat compressed PLY (.compressed.ply), antimatter15 .splat, Niantic .spz, GaussianSplats3D .ksplat, "
        "PlayCanvas SOG (.sog or meta.json) and glTF/GLB with KHR_gaussian_splatting")
    assert gaussians.FORMAT_NAMES == {
        "inria": "INRIA 3DGS PLY", "inria_half": "INRIA 3DGS PLY, half floats",
        "supersplat_compressed": "SuperSplat compressed PLY", "splat": "antimatter15 .splat", "spz": "Niantic SPZ",
        "ksplat": "GaussianSplats3D .ksplat", "gltf_splats": "glTF KHR_gaussian_splatting", "sog": "PlayCanvas SOG"}
    assert list(reader.FORMAT_EXTENSIONS.items()) == [
        ("ply", (".ply",)), ("splat", (".splat",)), ("ksplat", (".ksplat",)), ("spz", (".spz",)),
        ("sog", (".sog",)), ("gltf_splats", (".glb", ".gltf"))]
    assert reader.SPLAT_EXTENSIONS == (".ply", ".splat", ".ksplat", ".spz", ".sog")
    assert reader.ASSET_EXTENSIONS == (".ply", ".splat", ".ksplat", ".spz", ".sog", ".glb", ".gltf", ".obj", ".stl",
                                       ".off")
    assert set(reader._NAMED_BY_CONTENT) == {".ksplat", ".spz", ".sog", ".sogs", ".lcc"}
    assert reader.READERS == {"ply": reader.read_ply, "spz": spz.read, "ksplat": ksplat.read,
                              "gltf_splats": gltf_splats.read, "sog": sog.read, "splat": compressed.read_splat}
    assert [f.key for f in formats.FORMATS if f.needs_backend] == ["sog"]  # is_backend_splat_file's old "sog"
    assert [f.key for f in formats.FORMATS if f.by_extension] == ["splat"]  # detect's old `ext == ".splat"`


def test_every_record_is_well_formed():
    keys = [f.key for f in formats.FORMATS]
    assert len(set(keys)) == len(keys) and set(formats.BY_KEY) == set(keys)
    layouts = [layout for f in formats.FORMATS for layout, _ in f.layouts]
    assert len(set(layouts)) == len(layouts), "a GaussianPly.format value belongs to one format"
    exts = [e for f in formats.FORMATS for e in f.extensions]
    assert len(set(exts)) == len(exts) and all(re.fullmatch(r"\.[a-z0-9]+", e) for e in exts)
    for f in formats.FORMATS:
        assert f.name and f.accepted_phrases and f.layouts and f.extensions, f
        assert callable(reader.READERS[f.key]) and reader.READERS[f.key].__name__ == f.read.rsplit(".", 1)[1]
    assert set(formats.ACCEPTED_ORDER) <= set(keys)


def _returned_literals(function) -> set:
    tree = ast.parse(inspect.getsource(function))
    return {n.value.value for n in ast.walk(tree) if isinstance(n, ast.Return) and isinstance(n.value, ast.Constant)
            and isinstance(n.value.value, str)}


def test_detect_names_every_record_and_nothing_else():
    """``detect``'s content sniffing (code, one branch per format) returns record keys only, and every record is
    returned by a branch or, for a headerless format, by its extension."""
    named = set().union(*(_returned_literals(fn) for fn in (reader.detect, reader._json_kind, reader._zip_kind)))
    assert named <= set(formats.BY_KEY), f"detect returns {sorted(named - set(formats.BY_KEY))}, which no record has"
    by_name = {f.key for f in formats.FORMATS if f.by_extension}
    assert named | by_name == set(formats.BY_KEY), \
        f"no branch of detect returns {sorted(set(formats.BY_KEY) - named - by_name)}"


def test_the_library_hint_names_every_asset_extension(tmp_path):
    with pytest.raises(library.VariationError) as e:
        library.library_files(tmp_path / "missing")
    for ext in reader.ASSET_EXTENSIONS:
        assert ext in e.value.hint, f"the library's hint lacks {ext}: {e.value.hint}"


def test_the_import_menu_label_names_only_extensions_the_import_reads():
    """The menu label names a few extensions (then "mesh"): each one must be read (the tooltip names every format
    from the records: tests/scene/test_gaussians.py)."""
    with open(os.path.join(ROOT, "operators", "import_gaussians.py"), encoding="utf-8") as f:
        source = f.read()
    label = re.search(r'text="SCPainter Car Asset \(([^)]*)\)"', source)
    assert label, "the import's menu label was not found in operators/import_gaussians.py"
    named = [s.strip() for s in label.group(1).split(",")]
    assert named[-1] == "mesh" and named[:-1], named
    assert set(named[:-1]) <= set(reader.SPLAT_EXTENSIONS), \
        f"the menu label names {sorted(set(named[:-1]) - set(reader.SPLAT_EXTENSIONS))}, which no format has"
