"""The custom (ID) property keys the add-on stores on Blender data: objects, cameras, images, movie clips, node
groups. Saved .blend files hold these strings: renaming one loses what older files carry, so the values never change
(``tests/scene/test_keys.py``); code names them through these constants, never by their strings. The properties
registered with ``bpy.props`` (``Scene.scpainter_output_dir``, ...: ``scene/props.py``) and ``kinds.PROPERTY`` (the
kind of object, with its finders in ``scene/kinds.py``) are not here."""

from __future__ import annotations

# -- The points object (``scene/importer.py``; read back by ``job_export``, ``replace``, ``drive_lane``)
#: The file the object was imported from (predictions .npz; on an asset: its Gaussian file).
SOURCE = "scpainter_source"
#: Frames of the recording.
NUM_FRAMES = "scpainter_num_frames"
#: A multi-camera recording's scene frame offset per VGGT frame (on the points object; (S,) ints from 0 at the
#: import's first frame, ``core.vggt.sensors.Sensors.scene_frames``: every sensor's frame grouped at a scene frame).
#: Absent (a single-camera recording): VGGT frame i is scene frame offset i.
SCENE_FRAMES = "scpainter_scene_frames"
#: A multi-camera recording's sensor per VGGT frame (on the points object; (S,) strings, the sidecar's
#: ``frames[i].sensor``): which recorded camera each VGGT frame is (``core.vggt.sensors.camera_frames``). Absent: one
#: camera.
FRAME_SENSORS = "scpainter_frame_sensors"
#: The scene frame of the recording's first frame.
FRAME_START = "scpainter_frame_start"
#: (16,) the row-major 4x4 similarity from VGGT's frame to Blender's world.
VGGT_TO_WORLD = "scpainter_vggt_to_world"
#: The extrinsic convention the import resolved (``core.vggt``).
EXTRINSIC_CONVENTION = "scpainter_extrinsic_convention"
#: (left, top, right, bottom) pixels the import cropped.
CROP = "scpainter_crop"
#: The confidence percentile the points were kept at.
CONFIDENCE_PERCENTILE = "scpainter_confidence_percentile"
#: The depth-edge ratio the points were cleaned with.
DEPTH_EDGE_RATIO = "scpainter_depth_edge_ratio"
#: (16,) the object's matrix_world when imported (moved since: the job follows).
MATRIX_WORLD_AT_IMPORT = "scpainter_matrix_world_at_import"
#: (9,) a recorded camera's K, row-major (on the recorded camera; on a rig camera: the K it was added with).
INTRINSICS = "scpainter_intrinsics"
#: A multi-camera recording's rig (``core.rig.Rig.to_dict()`` as JSON text; on the points object: *Add Camera Rig*'s
#: preset "recording", read back by ``scene/recording_rig.py``).
RECORDING_RIG = "scpainter_recording_rig"
#: The sensor (camera channel) a recorded camera of a multi-camera recording is (on the recorded camera); a rig
#: camera's or LiDAR's sensor name (``scene/rig.py``: "CAM_FRONT"; the object's name may carry Blender's ".001").
SENSOR = "scpainter_sensor"
#: How the metric scale was found.
SCALE_METHOD = "scpainter_scale_method"
#: The scale fit's residual, metres.
SCALE_RESIDUAL_M = "scpainter_scale_residual_m"

# -- A Gaussian asset (``scene/gaussians.py``; read by ``placement``, ``job_export``, the panel)
#: (16,) the asset file's frame to the object's data frame, row-major.
FILE_TO_DATA = "scpainter_file_to_data"
#: The file axes applied (AUTO's choice, TRELLIS, NONE).
AXES = "scpainter_axes"
#: Why those axes.
AXES_REASON = "scpainter_axes_reason"
#: (3,) the asset's size, metres.
SIZE = "scpainter_size"
#: (3,) its oriented box's size, metres.
OBB_SIZE = "scpainter_obb_size"
#: The SH degree read.
SH_DEGREE = "scpainter_sh_degree"
#: The file format read.
FORMAT = "scpainter_format"
#: Rows dropped as invalid.
DROPPED = "scpainter_dropped"
#: The mesh a mesh car was converted from.
MESH_SOURCE = "scpainter_mesh_source"
#: The file a SOG was converted from.
SPLAT_SOURCE = "scpainter_splat_source"
#: The placement's first stage (how the asset was put on the road).
STAGE1 = "scpainter_stage1"
#: How far the first stage's fit deviates.
STAGE1_DEVIATION = "scpainter_stage1_deviation"
#: The artist's review: unchecked, accepted or rejected.
REVIEW = "scpainter_review"

# -- Placement (``scene/placement.py``, ``scene/replace.py``)
#: The box an asset was placed into.
TARGET_BOX = "scpainter_target_box"
#: The name of the points object it belongs to.
POINTS_OBJECT = "scpainter_points_object"

# -- A camera path (``scene/camera.py``)
#: The recorded camera it was made from.
SOURCE_CAMERA = "scpainter_source_camera"
#: Its sideways shift, metres.
SHIFT_M = "scpainter_shift_m"

# -- A camera rig (``scene/rig.py``): the rig empty, its cameras and its LiDAR; a rig camera's K as added is
#    ``INTRINSICS``
#: The rig's name (a preset's: "nuscenes", "front"; "recording"), on the rig empty.
RIG_NAME = "scpainter_rig_name"
#: The sensor the camera path is (the rig empty follows the path as this camera's ego pose), on the rig empty.
RIG_FOLLOW = "scpainter_rig_follow"
#: (a rig camera's or LiDAR's sensor name is ``SENSOR``)
#: A rig sensor's place in the rig (the order of its cameras in the job and every export).
SENSOR_INDEX = "scpainter_sensor_index"
#: (2,) a rig camera's own resolution, pixels (Blender renders one resolution per scene).
RESOLUTION = "scpainter_resolution"
#: (2,) a rig camera's pixel aspect (x, y): how fx != fy is held, as the scene's render settings hold it.
PIXEL_ASPECT = "scpainter_pixel_aspect"
#: (16,) a rig sensor's mounting pose as added, row-major: camera_to_ego / lidar_to_ego in float64.
MOUNT = "scpainter_mount"
#: A rig LiDAR's model (a key of ``core.lidar_model.MODELS``).
LIDAR_MODEL = "scpainter_lidar_model"

# -- An asset's label box (``scene/asset_box.py``); a recorded object (``scene/recorded_objects.py``)
#: Its label class.
CLASS = "scpainter_class"
#: A recorded object's track id (the job's ``recorded_objects[i].id``; a proposal's ``proposal_NN``).
TRACK_ID = "scpainter_track_id"
#: Whether a recorded object is seen but not labelled (an ignore region in every export).
IGNORE = "scpainter_ignore"
#: The scene frames a recorded object is in (its track's frames); absent: every frame.
TRACK_FRAMES = "scpainter_track_frames"

# -- A box proposal (``scene/proposals.py``): also a TRACK_ID (its ``proposal_NN``) and a CLASS
#: Its score, 0-1 (``core.variation.proposals``).
PROPOSAL_SCORE = "scpainter_proposal_score"

# -- A loaded result (image sequence, movie clip: ``scene/results.py``)
#: Its kind (``results.CONDITIONS``, ...).
RESULT = "scpainter_result"
#: The name of the camera that saw it.
CAMERA = "scpainter_camera"
#: The generator (scpainter, baseline).
MODEL = "scpainter_model"
#: The backend's one line about what made it.
DESCRIPTION = "scpainter_description"
#: Files in the sequence.
FRAMES = "scpainter_frames"

# -- A node group the add-on builds (``scene/node_groups.py``)
#: Its version.
VERSION = "scpainter_version"

#: Keys renamed since older .blend files were saved: {current key: the key older files carry} (``props.matrix_property``
#: reads either).
RENAMED = {VGGT_TO_WORLD: "scpainter_world_from_vggt", FILE_TO_DATA: "scpainter_data_from_file"}

#: Every key above, the renamed ones' old names included.
ALL = (SOURCE, NUM_FRAMES, SCENE_FRAMES, FRAME_SENSORS, FRAME_START, VGGT_TO_WORLD, EXTRINSIC_CONVENTION, CROP,
       CONFIDENCE_PERCENTILE, DEPTH_EDGE_RATIO, MATRIX_WORLD_AT_IMPORT, INTRINSICS, RECORDING_RIG, SENSOR, SCALE_METHOD, SCALE_RESIDUAL_M, FILE_TO_DATA, AXES,
       AXES_REASON, SIZE, OBB_SIZE, SH_DEGREE, FORMAT, DROPPED, MESH_SOURCE, SPLAT_SOURCE, STAGE1, STAGE1_DEVIATION,
       REVIEW, TARGET_BOX, POINTS_OBJECT, SOURCE_CAMERA, SHIFT_M, CLASS, TRACK_ID, IGNORE, TRACK_FRAMES,
       PROPOSAL_SCORE, RESULT, CAMERA, MODEL, DESCRIPTION, FRAMES, VERSION, RIG_NAME, RIG_FOLLOW,
       SENSOR_INDEX, RESOLUTION, PIXEL_ASPECT, MOUNT, LIDAR_MODEL, *RENAMED.values())
