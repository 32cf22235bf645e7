"""scene/keys.py: the one home of the custom (ID) property keys the add-on stores on Blender data."""

import ast
import os

from scpainter_blender.scene import keys

HOME = "scpainter_blender/scene/keys.py"


def test_stored_keys_never_change():
    """Saved .blend files hold these strings: renaming one loses what every older file carries."""
    assert {name: getattr(keys, name) for name in dir(keys) if name.isupper() and name not in ("ALL", "RENAMED")} == {
        "SOURCE": "scpainter_source", "NUM_FRAMES": "scpainter_num_frames",
        "SCENE_FRAMES": "scpainter_scene_frames", "FRAME_SENSORS": "scpainter_frame_sensors",
        "FRAME_START": "scpainter_frame_start",
        "VGGT_TO_WORLD": "scpainter_vggt_to_world", "EXTRINSIC_CONVENTION": "scpainter_extrinsic_convention",
        "CROP": "scpainter_crop", "CONFIDENCE_PERCENTILE": "scpainter_confidence_percentile",
        "DEPTH_EDGE_RATIO": "scpainter_depth_edge_ratio", "MATRIX_WORLD_AT_IMPORT": "scpainter_matrix_world_at_import",
        "INTRINSICS": "scpainter_intrinsics", "RECORDING_RIG": "scpainter_recording_rig",
        "SENSOR": "scpainter_sensor", "SCALE_METHOD": "scpainter_scale_method",
        "SCALE_RESIDUAL_M": "scpainter_scale_residual_m", "FILE_TO_DATA": "scpainter_file_to_data",
        "AXES": "scpainter_axes", "AXES_REASON": "scpainter_axes_reason", "SIZE": "scpainter_size",
        "OBB_SIZE": "scpainter_obb_size", "SH_DEGREE": "scpainter_sh_degree", "FORMAT": "scpainter_format",
        "DROPPED": "scpainter_dropped", "MESH_SOURCE": "scpainter_mesh_source",
        "SPLAT_SOURCE": "scpainter_splat_source",
        "STAGE1": "scpainter_stage1", "STAGE1_DEVIATION": "scpainter_stage1_deviation", "REVIEW": "scpainter_review",
        "TARGET_BOX": "scpainter_target_box", "POINTS_OBJECT": "scpainter_points_object",
        "SOURCE_CAMERA": "scpainter_source_camera", "SHIFT_M": "scpainter_shift_m", "CLASS": "scpainter_class",
        "TRACK_ID": "scpainter_track_id", "IGNORE": "scpainter_ignore", "TRACK_FRAMES": "scpainter_track_frames",
        "PROPOSAL_SCORE": "scpainter_proposal_score",
        "RESULT": "scpainter_result", "CAMERA": "scpainter_camera", "MODEL": "scpainter_model",
        "DESCRIPTION": "scpainter_description", "FRAMES": "scpainter_frames", "VERSION": "scpainter_version",
        "RIG_NAME": "scpainter_rig_name", "RIG_FOLLOW": "scpainter_rig_follow",
        "SENSOR_INDEX": "scpainter_sensor_index", "RESOLUTION": "scpainter_resolution",
        "PIXEL_ASPECT": "scpainter_pixel_aspect", "MOUNT": "scpainter_mount", "LIDAR_MODEL": "scpainter_lidar_model"}
    assert keys.RENAMED == {"scpainter_vggt_to_world": "scpainter_world_from_vggt",
                            "scpainter_file_to_data": "scpainter_data_from_file"}
    assert len(set(keys.ALL)) == len(keys.ALL) == 53


def _spelled_keys(source, rel):
    """(line, key) of every string literal in ``source`` that is one of ``keys.ALL`` (f-strings' parts included)."""
    return sorted((node.lineno, node.value) for node in ast.walk(ast.parse(source, rel))
                  if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in keys.ALL)


def test_the_check_sees_each_spelling():
    src = ('a = o["scpainter_size"]\nb = o.get(\'scpainter_axes\', "?")\nc = f"{o[\'scpainter_review\']}"\n'
           'd = "the scpainter_size of it"\n"""``scpainter_crop`` in a docstring"""\n')
    assert _spelled_keys(src, "x.py") == [(1, "scpainter_size"), (2, "scpainter_axes"), (3, "scpainter_review")]


def test_keys_are_spelled_only_in_their_home():
    """Code names a key through scene/keys.py, never by its string (prose in docstrings may name it)."""
    from tests_support import tracked_sources

    sources = tracked_sources(exclude=(HOME,))
    assert "scpainter_blender/scene/gaussians.py" in sources and "panels/main.py" in sources
    assert os.path.isfile(os.path.join(os.path.dirname(__file__), "..", "..", HOME))
    spelled = {rel: found for rel, text in sources.items() if (found := _spelled_keys(text, rel))}
    assert spelled == {}
