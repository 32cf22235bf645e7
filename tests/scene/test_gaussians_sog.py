"""Importing a SOG (PlayCanvas/SuperSplat) car in Blender (real bpy): Blender's Python has no WebP decoder, so the
import converts it through ``python -m backend splat-asset`` into the assets folder, as it converts meshes, and the
object holds the values core reads from the SOG."""

import os

import bpy
import numpy as np

import sog_fixtures as S
from scpainter_blender.core.splats import sog
from scpainter_blender.scene import gaussians


def _attr(obj, name, width):
    a = obj.data.attributes[name]
    out = np.empty(len(a.data) * width, np.float32)
    a.data.foreach_get("vector" if width == 3 else "value", out)
    return out.reshape(-1, width) if width > 1 else out


def test_sog_bundle_and_meta_json_import_through_the_backend(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))  # the .blend is unsaved: the user's cache
    meta, images = S.tiny(n=40, bands=1, side=8, seed=3)
    bundle = S.write_bundle(tmp_path / "van.sog", meta, images)
    want = sog.read(bundle)
    assert bpy.ops.scpainter.import_gaussians(filepath=bundle, target_length=4.0) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj.name == "van" and obj["scpainter_format"] == "sog" and obj["scpainter_splat_source"] == bundle
    out = obj["scpainter_source"]
    assert out.startswith(str(tmp_path / "cache" / "scpainter" / "assets")) and out.endswith(".gaussians.ply")
    assert os.path.basename(out).startswith("van.sog.") and len(obj.data.vertices) == 40
    assert np.array_equal(_attr(obj, "sh_0", 3), want.f_dc) and np.array_equal(_attr(obj, "opacity", 1), want.opacity)
    assert np.array_equal(_attr(obj, "sh_3", 3), want.f_rest[:, :, 2]) and obj["scpainter_sh_degree"] == 1
    folder = S.write_folder(tmp_path / "truck", meta, images)
    r = gaussians.import_gaussians(bpy.context, folder)
    assert r.object.name == "truck" and r.format == "sog" and "PlayCanvas SOG" in r.report()
    assert os.path.basename(r.object["scpainter_source"]).startswith("truck-meta.json.")
    assert np.array_equal(_attr(r.object, "sh_0", 3), want.f_dc)
    assert "*.sog" in gaussians.FILE_FILTER.split(";") and "meta.json" in gaussians.FILE_FILTER.split(";")


def test_a_broken_sog_is_refused_naming_the_entry_and_creates_nothing(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    meta, images = S.tiny(n=10)
    bundle = S.write_bundle(tmp_path / "car.sog", meta, images, leave_out=["quats.webp"])
    before = len(bpy.data.objects)
    from scpainter_blender.runs import client as backend_client

    try:
        gaussians.import_gaussians(bpy.context, bundle)
    except backend_client.BackendError as e:
        assert e.bad_input and e.field == "quats.webp" and "no entry 'quats.webp'" in str(e)
    else:
        raise AssertionError("a SOG without its quats.webp was imported")
    assert len(bpy.data.objects) == before
