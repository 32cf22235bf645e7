"""The nuScenes export (backend/export/nuscenes.py, nuscenes_tables.py) read back by nuscenes-devkit 1.2.0 (test-only):
a rendered rig job (``rig_fixtures``: nuScenes' six cameras and LIDAR_TOP at 1/20 scale, six frames at 10 fps)
loads; every box of every camera projects onto the labels' 2D box; the evaluation filter keeps every inserted box;
``render_sample`` runs; mmdetection3d's converter's checks hold (replayed: its code needs mmcv); a single-camera job
exports as CAM_FRONT with its warning; one dataset of several jobs; bad destinations and options are refused."""

import json
import os

import numpy as np
import pytest

from backend.export import dataset, nuscenes
from backend.export import nuscenes_tables as T
from scpainter_blender.core import outputs
from scpainter_blender.core import job as job_mod
from scpainter_blender.core.output_layout import OutputLayout
from tests.backend.export import export_fixtures as F
from tests.backend.export import rig_fixtures as R
from tests.backend.export.nuscenes_checks import evaluation_filter
from tests_support import run_backend_here

devkit = pytest.importorskip("nuscenes.nuscenes")
VERSION = nuscenes.DEFAULT_VERSION


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """(dataroot, the fixture's output folder, the counts, the NuScenes object)."""
    tmp = tmp_path_factory.mktemp("nus")
    root = R.build(str(tmp / "out"))
    out = tmp / "dataroot"
    out.mkdir()
    counts = nuscenes.write_clips(str(out), [R.clip(root)])
    return str(out), root, counts, devkit.NuScenes(VERSION, str(out), verbose=False)


def _labels(root: str, channel: str, frame: int) -> dict:
    return json.load(open(OutputLayout(os.path.join(root, channel)).frame_labels(frame)))


def test_the_tables_keyframes_and_files(exported):
    out, _, counts, nusc = exported
    assert counts == {"frames": 6, "samples": 2, "objects": 6, "inserted": 4, "ignore_regions": 4,
                      "version": VERSION, "keyframe_hz": 2.0}   # 3 objects per keyframe; the ignored car seen twice
    assert [len(getattr(nusc, t)) for t in ("category", "attribute", "visibility")] == [23, 8, 4]
    assert [s["timestamp"] - T.EPOCH_US for s in nusc.sample] == [0, 500_000]             # frames 10 and 15
    assert nusc.sample[0]["next"] == nusc.sample[1]["token"] and nusc.sample[1]["prev"] == nusc.sample[0]["token"]
    channels = sorted(c.name for c in R.RIG.cameras) + ["LIDAR_TOP"]
    assert sorted(nusc.sample[0]["data"]) == channels
    for ch in channels:
        chain = sorted((sd for sd in nusc.sample_data if sd["channel"] == ch), key=lambda sd: sd["timestamp"])
        assert [sd["is_key_frame"] for sd in chain] == [True, False, False, False, False, True]
        assert [sd["filename"].split("/")[0] for sd in chain] == ["samples"] + ["sweeps"] * 4 + ["samples"]
        assert all(a["next"] == b["token"] and b["prev"] == a["token"] for a, b in zip(chain, chain[1:]))
        assert all(os.path.isfile(os.path.join(out, sd["filename"])) for sd in chain)
        # a sweep belongs to the next keyframe: the devkit interpolates its boxes towards it
        assert {sd["sample_token"] for sd in chain[1:]} == {nusc.sample[1]["token"]}
    cam = nusc.get("calibrated_sensor", nusc.get("sample_data", nusc.sample[0]["data"]["CAM_BACK"])
                   ["calibrated_sensor_token"])
    K = R.RIG.camera("CAM_BACK").K
    assert np.allclose(cam["camera_intrinsic"], [[K[0, 0], 0, K[0, 2] - 0.5], [0, K[1, 1], K[1, 2] - 0.5], [0, 0, 1]])
    assert np.allclose(cam["translation"], R.RIG.camera("CAM_BACK").camera_to_ego[:3, 3])


def test_every_box_projects_onto_the_labels_2d_box(exported):
    from nuscenes.utils.geometry_utils import view_points

    _, root, _, nusc = exported
    checked = 0
    for s, frame in zip(nusc.sample, (R.FRAMES[0], R.FRAMES[5])):
        for cam in R.RIG.cameras:
            lab = _labels(root, cam.name, frame)
            by_track = {o["track_id"]: o for o in lab["objects"]}
            _, boxes, K = nusc.get_sample_data(s["data"][cam.name])
            W, H = cam.resolution
            for box in boxes:
                corners = view_points(box.corners(), K, normalize=True)[:2] + 0.5     # ours: pixel centres +0.5
                mine = np.r_[corners.min(1).clip(0, [W, H]), corners.max(1).clip(0, [W, H])]
                ours = by_track[nusc.get("sample_annotation", box.token)["track_id"]]["bbox_amodal"]
                assert np.abs(mine - ours).max() < 1.0, (cam.name, box.token)
                checked += 1
    assert checked >= 6   # car_a, car_b twice (two cameras) and the van, at both keyframes


def test_lidar_points_are_counted_as_the_devkit_counts_them(exported):
    from nuscenes.utils.data_classes import LidarPointCloud
    from nuscenes.utils.geometry_utils import points_in_box
    from pyquaternion import Quaternion

    out, _, _, nusc = exported
    for s in nusc.sample:
        sd = nusc.get("sample_data", s["data"]["LIDAR_TOP"])
        pc = LidarPointCloud.from_file(os.path.join(out, sd["filename"]))
        for rec in (nusc.get("calibrated_sensor", sd["calibrated_sensor_token"]),
                    nusc.get("ego_pose", sd["ego_pose_token"])):   # sensor -> ego -> global, as the devkit does
            pc.rotate(Quaternion(rec["rotation"]).rotation_matrix)
            pc.translate(np.array(rec["translation"]))
        for ann in s["anns"]:
            rec = nusc.get("sample_annotation", ann)
            inside = points_in_box(nusc.get_box(ann), pc.points[:3]).sum()
            assert rec["num_lidar_pts"] == inside == R.LATTICE ** 3


def test_the_evaluation_filter_keeps_every_inserted_box(exported):
    _, _, _, nusc = exported
    assert evaluation_filter(nusc) == (4, 4, 6)


def test_render_sample_runs(exported, tmp_path):
    import matplotlib
    from PIL import Image

    matplotlib.use("Agg")
    out, _, _, nusc = exported
    with Image.open(os.path.join(out, nusc.map[0]["filename"])) as im:     # the map under the LiDAR's view
        assert im.mode == "L" and im.getextrema() == (0, 255)
    nusc.render_sample(nusc.sample[1]["token"], out_path=str(tmp_path / "sample.png"), verbose=False)
    assert os.path.getsize(tmp_path / "sample.png") > 10_000


def test_mmdetection3d_converter_checks(exported):
    """What ``tools/dataset_converters/nuscenes_converter.py`` reads, replayed with the devkit: the scene's first
    LIDAR_TOP file exists (``get_available_scenes``), every keyframe's LIDAR_TOP file (``check_file_exist``), the six
    camera channels, ``valid_flag`` (num_lidar_pts + num_radar_pts > 0) true for every inserted box, velocities
    from prev/next (``box_velocity``); the attributes from them."""
    from nuscenes.utils.splits import mini_train

    _, _, _, nusc = exported
    speeds = {"car_a": 3.0, "car_b": 0.0, "rec_van": R.EGO_SPEED}
    attrs = {"car_a": ["vehicle.moving"], "car_b": ["vehicle.parked"], "rec_van": ["vehicle.moving"]}
    for scene in nusc.scene:
        first = nusc.get("sample", scene["first_sample_token"])
        assert os.path.isfile(nusc.get_sample_data(first["data"]["LIDAR_TOP"])[0])
        assert scene["name"] not in mini_train        # the converter puts it in val: splits.json says train
    for s in nusc.sample:
        lidar_path, boxes, _ = nusc.get_sample_data(s["data"]["LIDAR_TOP"])
        assert os.path.isfile(lidar_path) and len(boxes) == len(s["anns"])
        assert all(ch in s["data"] for ch in ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_FRONT_LEFT", "CAM_BACK",
                                              "CAM_BACK_LEFT", "CAM_BACK_RIGHT"))
        for ann in s["anns"]:
            rec = nusc.get("sample_annotation", ann)
            name = nusc.get("instance", rec["instance_token"])["name"]
            assert (rec["num_lidar_pts"] + rec["num_radar_pts"] > 0) or not rec["synthetic"]
            v = nusc.box_velocity(ann)[:2]
            assert np.allclose(v, speeds[name] * np.array([np.cos(R.HEADING), np.sin(R.HEADING)]), atol=1e-6)
            assert [nusc.get("attribute", t)["name"] for t in rec["attribute_tokens"]] == attrs[name]
    splits = json.load(open(os.path.join(nusc.dataroot, VERSION, nuscenes.SPLITS)))
    assert splits == {"train": [nusc.scene[0]["name"]]}


def test_a_single_camera_job_is_cam_front_without_lidar_and_says_so(tmp_path, capsys):
    from nuscenes.utils.geometry_utils import view_points

    # a camera pitched and rolled: the ego pose (camera_to_world · CAM_FRONT's mount⁻¹) must carry the tilt
    frames = F.export_frames(tmp_path, [F.tilted_camera(0.1 * i) for i in range(len(F.FRAMES))])
    out = tmp_path / "dataroot"
    out.mkdir()
    counts = nuscenes.write(str(out), frames, keyframe_hz=10.0)
    assert (counts["frames"], counts["samples"], counts["objects"], counts["ignore_regions"]) == (2, 2, 6, 2)
    codes = [json.loads(line).get("code") for line in capsys.readouterr().out.splitlines()]
    assert nuscenes.NO_LIDAR in codes and nuscenes.ONE_KEYFRAME not in codes
    nusc = devkit.NuScenes(VERSION, str(out), verbose=False)
    assert [s["channel"] for s in nusc.sensor] == ["CAM_FRONT"]
    for s, fr in zip(nusc.sample, frames):
        assert sorted(s["data"]) == ["CAM_FRONT"] and all(
            nusc.get("sample_annotation", a)["num_lidar_pts"] == 0 for a in s["anns"])
        _, boxes, K = nusc.get_sample_data(s["data"]["CAM_FRONT"])
        assert len(boxes) == 3          # the two cars and the van: the ignored car is no annotation
        by_track = {o["track_id"]: o for o in fr.labels["objects"]}
        for box in boxes:
            corners = view_points(box.corners(), K, normalize=True)[:2] + 0.5
            mine = np.r_[corners.min(1).clip(0, [F.W, F.H]), corners.max(1).clip(0, [F.W, F.H])]
            ours = by_track[nusc.get("sample_annotation", box.token)["track_id"]]["bbox_amodal"]
            assert np.abs(mine - ours).max() < 1.0


def test_write_export_of_an_output_folder(tmp_path, capsys):
    from backend.export import command
    from tests.backend.export.test_command import _output_folder

    j, layout = _output_folder(tmp_path, generated=False)
    job_mod.save(tmp_path / "job.json", j)
    dest = layout.export("nuscenes")
    result = command.write_export(str(tmp_path / "job.json"), j, layout, "nuscenes", dest,
                                  options=nuscenes.check_options("v1.0-trainval", 2.0))
    assert result == {"frames": 2, "samples": 1, "objects": 3, "inserted": 2, "ignore_regions": 1,
                      "version": "v1.0-trainval", "keyframe_hz": 2.0, "images": "conditions"}
    evs = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert sorted(e["code"] for e in evs if e["event"] == "warning") == sorted(
        [command.NO_GENERATED, nuscenes.NO_LIDAR, nuscenes.ONE_KEYFRAME, nuscenes.NOT_SIX_CAMERAS])
    assert [(e["done"], e["frame"]) for e in evs if e["event"] == "progress"] == [(1, 4), (2, 5)]
    assert json.load(open(os.path.join(dest, OutputLayout.EXPORT_RECORD)))["format"] == "nuscenes"
    nusc = devkit.NuScenes("v1.0-trainval", dest, verbose=False)
    assert [sd["filename"].split("/")[0] for sd in nusc.sample_data] == ["samples", "sweeps"]
    assert nusc.scene[0]["description"] == f"job {tmp_path.name}/job.json"   # never the absolute path
    assert nusc.scene[0]["name"] == nuscenes.job_scene_name(str(tmp_path / "job.json")) == tmp_path.name


def test_two_jobs_exported_alone_share_no_token_and_name_themselves(tmp_path):
    """Two variants' single exports merge: their scene names say which job, their tokens and start times differ,
    and a job exported again keeps its own."""
    from backend.export import command
    from tests.backend.export.test_command import _output_folder

    run = tmp_path / "my run (1)"
    tables = {}
    for name, dest in (("v0000", "a"), ("v0001", "b"), ("v0000", "again")):
        folder = run / name
        folder.mkdir(parents=True, exist_ok=True)
        j, layout = _output_folder(folder, generated=False) if dest != "again" else (j0, layout0)
        if dest == "a":
            j0, layout0 = j, layout
        job_mod.save(folder / "job.json", j)
        command.write_export(str(folder / "job.json"), j, layout, "nuscenes", str(tmp_path / dest))
        tables[dest] = {t: json.load(open(tmp_path / dest / VERSION / f"{t}.json")) for t in T.TABLE_NAMES}
    a, b = tables["a"], tables["b"]
    assert (a["scene"][0]["name"], b["scene"][0]["name"]) == ("v0000", "v0001")
    assert str(tmp_path) not in json.dumps(a["scene"]) + json.dumps(a["log"])
    own = ("scene", "sample", "sample_data", "ego_pose", "log", "calibrated_sensor", "instance", "sample_annotation",
           "map")
    for t in own:
        assert a[t] and not {r["token"] for r in a[t]} & {r["token"] for r in b[t]}, t
    assert {r["token"] for r in a["sensor"]} == {r["token"] for r in b["sensor"]}   # one CAM_FRONT sensor
    assert a["sample"][0]["timestamp"] != b["sample"][0]["timestamp"]
    assert tables["again"] == a                                                     # stable over exports
    assert nuscenes.job_scene_name("/x/my drive (2)/night.json") == "my_drive__2_-night"


def test_one_dataset_of_several_jobs_with_its_split(tmp_path):
    frames = F.export_frames(tmp_path)
    writer = dataset._Writer(str(tmp_path / "ds"), ["nuscenes"], ["train", "val"],
                             nuscenes.check_options(keyframe_hz=10.0))
    for k, split in enumerate(("train", "val")):
        writer.add(dataset.Member(f"/jobs/{k}/job.json", F.job(), split=split, sequence=k), frames)
    rig = dataset.Member("/jobs/rig/job.json", R.rig_job(), split="val", sequence=2)   # a rig job beside them
    writer.add_rig(rig, R.build(str(tmp_path / "rig")))
    writer.finish()
    nusc = devkit.NuScenes(VERSION, str(tmp_path / "ds" / "nuscenes"), verbose=False)
    assert [s["name"] for s in nusc.scene] == ["scpainter-0000", "scpainter-0001", "scpainter-0002"]
    assert len(nusc.log) == len(nusc.map) == 3 and len(nusc.sample) == 4 + 6        # 10 Hz: every frame a sample
    assert len({sd["token"] for sd in nusc.sample_data}) == len(nusc.sample_data) == 4 + 6 * 7
    for table in ("scene", "log", "sample", "ego_pose", "calibrated_sensor", "instance", "sample_annotation"):
        rows = getattr(nusc, table)
        assert len({r["token"] for r in rows}) == len(rows), table        # unique over the dataset's jobs
    assert json.load(open(tmp_path / "ds" / "nuscenes" / VERSION / nuscenes.SPLITS)) == {
        "train": ["scpainter-0000"], "val": ["scpainter-0001", "scpainter-0002"]}
    assert writer.counts["nuscenes"]["val"] == {"frames": 2 + 6, "objects": 6 + 3 * 6, "ignore_regions": 2 + 2 * 6}
    assert [r["camera"] for r in writer.rows[-6:]] == ["CAM_FRONT"] * 6 and rig.images == "conditions"


def _bare_job(tmp_path) -> str:
    j = job_mod.Job((F.W, F.H), [job_mod.Frame(f, F.K.copy(), F.world_to_camera(0.1 * i))
                                 for i, f in enumerate(F.FRAMES)], "out", None, [], fps=10.0)
    job_mod.save(tmp_path / "job.json", j)
    return str(tmp_path / "job.json")


def test_a_folder_holding_another_dataset_or_bad_options_are_refused(tmp_path):
    job = _bare_job(tmp_path)
    other = tmp_path / "other"
    other.mkdir()
    (other / "v1.0-trainval").mkdir()                       # somebody's nuScenes
    (other / "v1.0-trainval" / "scene.json").write_text("[]")
    coco = tmp_path / "coco"
    coco.mkdir()
    outputs.write_json(coco / OutputLayout.EXPORT_RECORD, {"format": "coco", "files": []})
    for out, said in ((other, "other content"), (coco, "holds a coco export, not nuscenes")):
        code, ev, _ = run_backend_here("export", job, "--format", "nuscenes", "--out", out, "--device", "cpu")
        assert code == 2 and ev[-1]["field"] == "--out" and said in ev[-1]["message"], ev[-1]
    assert (other / "v1.0-trainval" / "scene.json").read_text() == "[]"
    for option, value in (("--version", "v1.0-test"), ("--keyframe-hz", "0")):
        code, ev, _ = run_backend_here("export", job, "--format", "nuscenes", option, value)
        assert code == 2 and ev[-1]["field"] == option, ev[-1]
    job_mod.save(tmp_path / "rig.json", R.rig_job())   # a dataset of rig jobs: nuScenes only, said on its rig
    code, ev, _ = run_backend_here("export", tmp_path / "rig.json", "--format", "kitti,coco", "--out",
                                   tmp_path / "ds")
    assert code == 2 and ev[-1]["field"] == "rig" and "one export per camera" in ev[-1]["hint"], ev[-1]
    assert "--format nuscenes" in ev[-1]["hint"]
    (tmp_path / "two").mkdir()                          # nuScenes alone: rig jobs taken, given as paths too
    job_mod.save(tmp_path / "two" / "job.json", R.rig_job())
    assert len(dataset.members([tmp_path / "rig.json", tmp_path / "two" / "job.json"], formats=["nuscenes"])) == 2


def test_a_rendered_rig_job_with_its_simulated_lidar_loads_and_keeps_its_inserted_car(tmp_path):
    """End to end through the command line: a job made a nuScenes-rig job (``rig``), rendered (six cameras and the
    simulated LIDAR_TOP sweeps), exported; the devkit loads it and its evaluation filter keeps the inserted car:
    its num_lidar_pts are the simulated sweep's points in its box."""
    from tests_support import small_job

    base = small_job(tmp_path / "drive", fps=10.0)
    code, ev, err = run_backend_here("rig", base, "--preset", "nuscenes", "--scale", "0.02", "--out",
                                     tmp_path / "surround" / "job.json")
    assert code == 0, err
    job = tmp_path / "surround" / "job.json"
    code, ev, err = run_backend_here("export", job, "--format", "nuscenes", "--out", tmp_path / "nus",
                                     "--device", "cpu", "--data-root", tmp_path / "drive")
    assert code == 0, err
    assert ev[-1]["rendered"] > 0
    nusc = devkit.NuScenes(VERSION, str(tmp_path / "nus"), verbose=False)
    assert sorted(nusc.sample[0]["data"]) == sorted(list(R.RIG.sensor_names))
    car = [a for a in nusc.sample_annotation if a["synthetic"]]
    assert car and all(a["num_lidar_pts"] > 0 for a in car)
    inserted, kept_inserted, _ = evaluation_filter(nusc)
    assert inserted == len(car) and kept_inserted == inserted
    # the same rig job as a dataset (--list, batch --command export): nuScenes takes rig jobs (rendered: no render)
    (tmp_path / "variants.txt").write_text(f"{job}\n")
    for command in (("export", "--list", tmp_path / "variants.txt"), ("batch", job, "--command", "export")):
        out = tmp_path / f"ds-{command[0]}"
        code, ev, err = run_backend_here(*command, "--format", "nuscenes", "--out", out, "--device", "cpu",
                                         "--data-root", tmp_path / "drive")
        assert code == 0, err[-3000:]
        ds = devkit.NuScenes(VERSION, str(out / "nuscenes"), verbose=False)
        assert [s["name"] for s in ds.scene] == ["scpainter-0000"] and len(ds.sample) == len(nusc.sample)
        assert sorted(ds.sample[0]["data"]) == sorted(R.RIG.sensor_names)
