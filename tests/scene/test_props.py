"""scene/props.py: where a scene's runs write: one output folder per camera inside the scene's, named after it;
folder names that would be shared are refused naming the camera."""

import os

import bpy
import pytest

from scpainter_blender.scene import kinds, props


def _camera(name, kind=None):
    obj = bpy.data.objects.new(name, bpy.data.cameras.new(name))
    bpy.context.scene.collection.objects.link(obj)
    if kind:
        kinds.mark(obj, kind)
    return obj


def test_each_camera_has_its_folder_in_the_scene_folder(empty_scene, tmp_path):
    scene = empty_scene
    a, b = _camera("Camera path 2 m left"), _camera("Camera path 2 m right")
    scene.camera = a
    scene.scpainter_output_dir = str(tmp_path / "mine")         # what the user set stays the parent
    assert props.camera_folder_name(a) == "Camera_path_2_m_left"
    assert props.camera_output_dir(scene) == str(tmp_path / "mine" / "Camera_path_2_m_left")
    assert props.camera_output_dir(scene, b) == str(tmp_path / "mine" / "Camera_path_2_m_right")
    assert scene.camera == a                                     # asking for b's folder changes nothing
    scene.scpainter_output_dir = ""                              # the default, beside the saved .blend
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "s.blend"))
    assert props.camera_output_dir(bpy.context.scene) == os.path.join(str(tmp_path), "scpainter", "Scene",
                                                                      "Camera_path_2_m_left")


def test_a_folder_two_cameras_would_share_is_refused(empty_scene, tmp_path):
    scene = empty_scene
    scene.scpainter_output_dir = str(tmp_path)
    a, twin = _camera("Cam.1"), _camera("cam_1")   # the same folder once cleaned (and on a case-blind disk)
    with pytest.raises(props.SceneError, match=r"objects\['Cam.1'\]: its output folder 'Cam_1' would also be the "
                                               r"output folder of camera 'cam_1'"):
        props.camera_output_dir(scene, a)
    with pytest.raises(props.SceneError, match="output folder of camera 'Cam.1'"):
        props.camera_output_dir(scene, twin)
    twin.name = "Cam 2"
    assert props.camera_output_dir(scene, a) == str(tmp_path / "Cam_1")
    for reserved in ("assets", "conditions", "generated", "export", "Assets"):   # names the scene folder uses
        with pytest.raises(props.SceneError, match=rf"objects\['{reserved}'\]: .*'{reserved}', a name the scene"):
            props.camera_output_dir(scene, _camera(reserved))


def test_no_camera_or_an_unsaved_blend(empty_scene):
    scene = empty_scene
    with pytest.raises(props.SceneError, match=r"scene\.scpainter_output_dir: .*not saved yet"):
        props.camera_output_dir(scene)                           # the .blend first: it says where things go
    scene.scpainter_output_dir = "/tmp/x"
    with pytest.raises(props.SceneError, match=r"scene\.camera: the scene has no active camera"):
        props.camera_output_dir(scene)
    empty = bpy.data.objects.new("Empty", None)
    with pytest.raises(props.SceneError, match=r"objects\['Empty'\]: is not a camera"):
        props.camera_output_dir(scene, empty)


def test_camera_paths_in_name_order(empty_scene):
    scene = empty_scene
    _camera("Camera path b", kinds.CAMERA_PATH)
    _camera("Recorded", kinds.RECORDED_CAMERA)
    _camera("Camera path a", kinds.CAMERA_PATH)
    _camera("Plain camera")
    assert [o.name for o in kinds.camera_paths(scene)] == ["Camera path a", "Camera path b"]
