"""A job renders what Blender's render would (scene/visibility.py): the view layer's collections and
``hide_render`` (checked against real Cycles renders), one reconstruction (the one that renders; two are refused),
the removal boxes the points object's modifiers apply, and a scene with nothing to render refused."""

import os

import bpy
import numpy as np
import pytest

from scpainter_blender.core import job as J
from scpainter_blender.scene import compat, visibility  # the repo's copy of the installed add-on's modules


def _emissive_plane(scene):
    """A white emissive plane filling the view of a camera 5 m above it (the scene camera), linked into the
    collection C inside the collection P; returns (plane, P, C)."""
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.location = (0.0, 0.0, 5.0)
    mesh = bpy.data.meshes.new("plane")
    mesh.from_pydata([(-10, -10, 0), (10, -10, 0), (10, 10, 0), (-10, 10, 0)], [], [(0, 1, 2, 3)])
    plane = bpy.data.objects.new("plane", mesh)
    mat = bpy.data.materials.new("white")
    tree = compat.node_tree(mat, clear=True)
    emission = tree.nodes.new("ShaderNodeEmission")
    tree.links.new(emission.outputs[0], tree.nodes.new("ShaderNodeOutputMaterial").inputs[0])
    mesh.materials.append(mat)
    P = bpy.data.collections.new("P")
    scene.collection.children.link(P)
    C = bpy.data.collections.new("C")
    P.children.link(C)
    C.objects.link(plane)
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.device = "CPU"
    scene.render.resolution_x = scene.render.resolution_y = 4
    return plane, P, C


def _cycles_renders(scene, path) -> bool:
    """Whether a real Cycles render of the scene shows the plane (white, on a black world)."""
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path, check_existing=False)
    try:
        return float(np.array(img.pixels[:]).reshape(-1, 4)[:, :3].mean()) > 0.5
    finally:
        bpy.data.images.remove(img)


def test_renders_agrees_with_cycles(empty_scene, tmp_path):
    """``visibility.renders`` against Cycles itself, one setting at a time: an object's and a collection's (or a
    parent collection's) Disable in Renders and the view layer's Exclude hide it; the viewport-only switches do
    not; an object linked into a second, included collection still renders."""
    scene = empty_scene
    plane, P, C = _emissive_plane(scene)
    vl = bpy.context.view_layer
    lp = vl.layer_collection.children["P"]
    lc = lp.children["C"]
    D = bpy.data.collections.new("D")  # a second place for the plane, linked only for the last two cases
    scene.collection.children.link(D)
    ld = vl.layer_collection.children["D"]
    cases = [
        ("nothing hidden", {}, True),
        ("object hide_render", {(plane, "hide_render"): True}, False),
        ("object hide_viewport (viewport only)", {(plane, "hide_viewport"): True}, True),
        ("collection excluded", {(lc, "exclude"): True}, False),
        ("parent collection excluded", {(lp, "exclude"): True}, False),
        ("collection hide_render", {(C, "hide_render"): True}, False),
        ("parent collection hide_render", {(P, "hide_render"): True}, False),
        ("parent layer collection hidden in the viewport", {(lp, "hide_viewport"): True}, True),
        ("excluded here, included in D", {(lp, "exclude"): True, (D, "link"): True}, True),
        ("excluded here, D disabled in renders", {(lp, "exclude"): True, (D, "link"): True, (D, "hide_render"): True},
         False),
    ]
    for name, settings, expected in cases:
        for (owner, attr), value in settings.items():
            if attr == "link":
                D.objects.link(plane)
            else:
                setattr(owner, attr, value)
        bpy.context.view_layer.update()
        assert _cycles_renders(scene, str(tmp_path / "r.png")) is expected, f"Cycles: {name}"
        assert visibility.renders(plane, vl) is expected, name
        assert visibility.rendered([plane], vl) == ([plane] if expected else []), name
        for (owner, attr), value in settings.items():
            if attr == "link":
                D.objects.unlink(plane)
            else:
                setattr(owner, attr, False)
    assert ld.exclude is False


def _street(empty_scene, street, tmp_path):
    from tests_support import street_with_car

    scene = street_with_car(street, tmp_path, count=500)
    car = next(o for o in scene.objects if o.get("scpainter_kind") == "gaussian_asset")
    pts = next(o for o in scene.objects if o.get("scpainter_kind") == "points")
    return scene, pts, car


def _export(tmp_path, name="job.json"):
    path = str(tmp_path / name)
    assert bpy.ops.scpainter.export_job(filepath=path) == {"FINISHED"}
    return J.load(path).to_dict()


def _move_to_new_collection(scene, obj, name):
    """``obj`` linked into a new collection ``name`` (a child of the scene's) and nowhere else."""
    coll = bpy.data.collections.new(name)
    scene.collection.children.link(coll)
    coll.objects.link(obj)
    for c in list(obj.users_collection):
        if c != coll:
            c.objects.unlink(obj)
    return coll


def test_a_car_in_an_excluded_collection_is_not_rendered(empty_scene, street, tmp_path):
    """A car moved into a collection excluded from the view layer (or disabled in renders) is left out of the job,
    as Blender's render leaves it out; included again, it is back."""
    scene, _, car = _street(empty_scene, street, tmp_path)
    cars = _move_to_new_collection(scene, car, "Cars")
    assert [a["name"] for a in _export(tmp_path)["assets"]] == [car.name]
    layer = bpy.context.view_layer.layer_collection.children["Cars"]
    layer.exclude = True
    assert "assets" not in _export(tmp_path)
    layer.exclude = False
    cars.hide_render = True
    assert "assets" not in _export(tmp_path)
    cars.hide_render = False
    car.hide_render = True
    assert "assets" not in _export(tmp_path)
    car.hide_render = False
    assert [a["name"] for a in _export(tmp_path)["assets"]] == [car.name]


def test_removal_boxes_follow_the_points_modifiers(empty_scene, street, tmp_path):
    """A removal box applies when the exported points object's modifier naming it is enabled in renders, whatever
    the box's own visibility: Blender removes the points of a box in an excluded collection too (its evaluated
    cloud is checked here); a box whose modifier is disabled in renders, or deleted, removes nothing."""
    scene, pts, car = _street(empty_scene, street, tmp_path)
    bpy.context.view_layer.objects.active = car
    assert bpy.ops.scpainter.add_removal_box() == {"FINISHED"}
    box = bpy.context.active_object
    box.location = car.location
    _move_to_new_collection(scene, box, "Boxes")
    bpy.context.view_layer.layer_collection.children["Boxes"].exclude = True

    from scpainter_blender.scene import points

    points.points_modifier(pts).show_viewport = False  # the vertices left after the removal modifiers, as a mesh

    def evaluated_points():
        bpy.context.view_layer.update()
        return len(pts.evaluated_get(bpy.context.evaluated_depsgraph_get()).data.vertices)

    (mod,) = [m for m in pts.modifiers if m.node_group and m.node_group.name.startswith("SCPainter Removal Box")]
    mod.show_render = False
    shown_without = evaluated_points()
    mod.show_render = True
    assert evaluated_points() == shown_without  # the viewport's own switch still removes them
    mod.show_viewport = False
    kept = evaluated_points()
    mod.show_viewport = True
    removed = kept - evaluated_points()
    assert removed > 0, "Blender removes the points of a box in an excluded collection"
    (exported,) = _export(tmp_path)["scene"]["removal_boxes"]
    assert np.allclose(np.array(exported["box_to_world"])[:3, 3], np.array(box.matrix_world)[:3, 3], atol=1e-6)
    mod.show_render = False
    assert "removal_boxes" not in _export(tmp_path)["scene"]
    mod.show_render = True
    pts.modifiers.remove(mod)
    assert "removal_boxes" not in _export(tmp_path)["scene"], "a box no modifier applies removes nothing"


def test_reimport_exports_the_rendered_cloud_and_refuses_two(empty_scene, street, tmp_path):
    """Importing the reconstruction again (another confidence) leaves two clouds: the job refuses both rendering,
    naming them; with the old one hidden from renders (or its collection excluded) the job is the new one's."""
    args = dict(filepath=street.predictions_path, scale_mode="TRAJECTORY",
                trajectory_path=os.path.join(street.root, "metric.npz"))
    assert bpy.ops.scpainter.import_vggt(**args, confidence_percentile=0.0) == {"FINISHED"}
    assert bpy.ops.scpainter.import_vggt(**args, confidence_percentile=70.0) == {"FINISHED"}
    old, new = [o for o in empty_scene.objects if o.get("scpainter_kind") == "points"]
    assert (old["scpainter_confidence_percentile"], new["scpainter_confidence_percentile"]) == (0.0, 70.0)
    with pytest.raises(RuntimeError, match=rf"objects\['{old.name}'\], objects\['{new.name}'\]: 2 reconstructions "
                                           r"render .*a job renders one \(hide the old one from renders.*Replace "
                                           r"Reconstruction"):
        bpy.ops.scpainter.export_job(filepath=str(tmp_path / "job.json"))
    old.hide_render = True
    assert _export(tmp_path)["scene"]["confidence_percentile"] == 70.0
    old.hide_render = False  # the other way round: the new one's collection excluded
    bpy.context.view_layer.layer_collection.children[new.users_collection[0].name].exclude = True
    assert _export(tmp_path)["scene"]["confidence_percentile"] == 0.0


def test_nothing_to_render_is_refused(empty_scene, tmp_path):
    """A scene with only a camera (or with its reconstruction hidden from renders and no car) is refused naming
    ``scene.objects`` and what to import, by the export and by Render Conditions (which would make frames of
    holes and report success)."""
    from vggt_cases import drive, write

    scene = empty_scene
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.scpainter_output_dir = str(tmp_path / "out")
    nothing = r"scene\.objects: nothing to render: no reconstruction and no car asset"
    with pytest.raises(RuntimeError, match=nothing + r" \(import one \(Import VGGT Reconstruction, or Import "
                                                     r"Gaussian Asset"):
        bpy.ops.scpainter.export_job(filepath=str(tmp_path / "job.json"))
    with pytest.raises(RuntimeError, match=nothing):
        bpy.ops.scpainter.render_conditions()
    assert not (tmp_path / "job.json").exists() and not (tmp_path / "out" / "Camera" / "job.json").exists()
    arrays, _, _ = drive(S=2, H=12, W=16)
    assert bpy.ops.scpainter.import_vggt(filepath=write(tmp_path, arrays), depth_edge_ratio=0.0) == {"FINISHED"}
    pts = next(o for o in scene.objects if o.get("scpainter_kind") == "points")
    pts.hide_render = True
    with pytest.raises(RuntimeError, match=nothing + rf"; not rendered \(hidden from renders.*\): '{pts.name}'"):
        bpy.ops.scpainter.export_job(filepath=str(tmp_path / "job.json"))
    pts.hide_render = False
    assert _export(tmp_path)["scene"]["predictions"]


def _drawn_by_blender(car) -> list:
    """(4, 4) world matrices of every drawing of ``car`` in Blender's evaluated depsgraph (itself and its collection
    instances), sorted by translation; each once (its Geometry Nodes output is drawn as one instance per geometry
    component, all at the same matrix)."""
    bpy.context.view_layer.update()
    dg = bpy.context.evaluated_depsgraph_get()
    out = {tuple(np.round(np.array(i.matrix_world, dtype=np.float64), 5).ravel()): np.array(i.matrix_world)
           for i in dg.object_instances if i.object.original == car}
    return [out[k] for k in sorted(out, key=lambda k: (k[3], k[7], k[11]))]


def _drawn_by_job(job, car) -> dict:
    """{asset name: [(4, 4) world matrix of the car per frame]} of a job, its file_to_data taken off."""
    D_inv = np.linalg.inv(np.array(car["scpainter_file_to_data"]).reshape(4, 4))
    out = {a.name: [np.asarray(m) @ D_inv for _, m in sorted(a.object_to_world.items())] for a in job.assets}
    return out


def test_collection_instances_are_the_cars_blender_draws(empty_scene, addon, tmp_path):
    """Cars placed as collection instances (an empty drawing a collection, with its instance offset; nested: an
    empty drawing a collection of such empties) are each an asset of the job, with the world matrix Blender's
    depsgraph draws it at (``object_instances``), frame by frame; with the source collection excluded from the view
    layer the car itself no longer renders but its instances do (never "nothing to render"); an instancer hidden from
    renders draws nothing."""
    from scpainter_blender.core import shapes

    scene = empty_scene
    ply = str(tmp_path / "car.ply")
    shapes.save_as_amodal3r(ply, shapes.procedural_car_gaussians(count=60, seed=1))
    assert bpy.ops.scpainter.import_gaussians(filepath=ply, target_length=4.4) == {"FINISHED"}
    car = bpy.context.active_object
    car.location, car.rotation_euler = (1.0, 2.0, 0.0), (0.0, 0.0, 0.4)
    src = bpy.data.collections.new("Src")
    scene.collection.children.link(src)
    for c in list(car.users_collection):
        c.objects.unlink(car)
    src.objects.link(car)
    for child in car.children:  # its box goes along (an empty: never drawn)
        for c in list(child.users_collection):
            c.objects.unlink(child)
        src.objects.link(child)
    src.instance_offset = (1.0, 0.0, 0.0)

    def instancer(name, coll, location, angle, into):
        e = bpy.data.objects.new(name, None)
        e.instance_type, e.instance_collection = "COLLECTION", coll
        e.location, e.rotation_euler = location, (0.0, 0.0, angle)
        into.objects.link(e)
        return e

    one = instancer("One", src, (10.0, 0.0, 0.0), 0.5, scene.collection)
    one.keyframe_insert("location", frame=1)
    one.location.x = 14.0
    one.keyframe_insert("location", frame=2)
    pair = bpy.data.collections.new("Pair")  # held only by the .blend's data, drawn by "Pairs" below
    instancer("Left", src, (0.0, 5.0, 0.0), 0.0, pair)
    instancer("Right", src, (0.0, -5.0, 0.0), 1.0, pair)
    pairs = instancer("Pairs", pair, (-20.0, 0.0, 0.0), -0.3, scene.collection)
    scene.frame_start, scene.frame_end = 1, 2
    scene.camera = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(scene.camera)
    path = str(tmp_path / "job.json")

    def check(expected_names):
        assert bpy.ops.scpainter.export_job(filepath=path) == {"FINISHED"}
        job = J.load(path)
        by_job = _drawn_by_job(job, car)
        assert sorted(by_job) == sorted(expected_names)
        for i, frame in enumerate((1, 2)):
            scene.frame_set(frame)
            blender = _drawn_by_blender(car)
            ours = sorted((m[i] for m in by_job.values()), key=lambda m: tuple(np.round(m[:3, 3], 5)))
            assert len(ours) == len(blender), frame
            for a, b in zip(ours, blender):
                assert np.abs(a - b).max() < 1e-5, frame
        scene.frame_set(1)

    assert car.name == "car"
    check([car.name, "One/car", "Pairs/Left/car", "Pairs/Right/car"])
    bpy.context.view_layer.layer_collection.children["Src"].exclude = True  # the source left out of the render
    check(["One/car", "Pairs/Left/car", "Pairs/Right/car"])
    one.hide_render = True
    assert bpy.ops.scpainter.export_job(filepath=path) == {"FINISHED"}
    assert sorted(a.name for a in J.load(path).assets) == ["Pairs/Left/car", "Pairs/Right/car"]
    pairs.hide_render = True
    with pytest.raises(RuntimeError, match=r"nothing to render"):
        bpy.ops.scpainter.export_job(filepath=path)
