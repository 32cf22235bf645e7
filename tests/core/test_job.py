"""core.job: the job.json contract, validated field by field with messages that name the field."""

import copy
import json

import numpy as np
import pytest

from scpainter_blender.core import job as J
from scpainter_blender.core import job_inputs


def minimal(frames=(1, 2)):
    return {"schema": J.SCHEMA, "resolution": [64, 32],
            "frames": [{"frame": f, "K": [[50, 0, 32], [0, 50, 16], [0, 0, 1]], "world_to_camera": np.eye(4).tolist(),
                        "source_frames": [0, 1]} for f in frames],
            "scene": {"predictions": "recon/predictions.npz", "vggt_to_world": (2 * np.eye(4) - np.diag([0, 0, 0, 1])).tolist(),
                      "confidence_percentile": 50.0,
                      "removal_boxes": [{"box_to_world": np.eye(4).tolist(), "size": [4.5, 1.9, 1.6]}]},
            "assets": [{"name": "car_01", "ply": "assets/car_01.ply",
                        "object_to_world": {str(f): np.diag([3.0, 3, 3, 1]).tolist() for f in frames}}],
            "output_dir": "out",
            "generate": {"checkpoint": "/models/scpainter", "steps": 25, "window": 14, "overlap": 4, "seed": 0}}


def test_valid_job_round_trip(tmp_path):
    job = minimal()
    J.save(tmp_path / "job.json", job)
    loaded = J.load(tmp_path / "job.json")
    assert isinstance(loaded, J.Job) and isinstance(loaded.scene, J.Scene) and isinstance(loaded.frames[0], J.Frame)
    expected = json.loads(json.dumps(job))
    expected["scene"].update(extrinsic_convention="world_to_camera", crop=[0, 0, 0, 0],  # defaults, written out
                             point_cleaning=J.POINT_CLEANING)
    assert loaded.to_dict() == expected
    assert json.loads((tmp_path / "job.json").read_text()) == expected
    assert loaded.assets[0].object_to_world[2].shape == (4, 4)    # frame numbers are ints in the classes
    assert J.resolve(tmp_path / "job.json", "assets/car_01.ply") == str(tmp_path / "assets" / "car_01.ply")
    without = {k: v for k, v in job.items() if k not in ("scene", "assets", "generate")}
    J.validate(without)


@pytest.mark.parametrize("mutate,field", [
    (lambda j: j.update(schema="scpainter.job/0"), "schema"),
    (lambda j: j.update(resolution=[64]), "resolution"),
    (lambda j: j["resolution"].__setitem__(1, 0), "resolution[1]"),
    (lambda j: j.update(frames=[]), "frames"),
    (lambda j: j["frames"][1].update(frame=1), "frames[1].frame"),
    (lambda j: j["frames"][0].update(K=[[0, 0, 1], [0, 1, 1], [0, 0, 1]]), "frames[0].K"),
    # a NaN literal (Python's json writes them) is named down to the element by the reader
    (lambda j: j["frames"][1]["K"][0].__setitem__(0, float("nan")), "frames[1].K[0][0]"),
    (lambda j: j["frames"][0].update(world_to_camera=np.diag([2.0, 2, 2, 1]).tolist()), "frames[0].world_to_camera"),
    (lambda j: j["frames"][0].update(source_frames=[-1]), "frames[0].source_frames[0]"),
    (lambda j: j["scene"].update(vggt_to_world=np.diag([1.0, 2, 1, 1]).tolist()), "scene.vggt_to_world"),
    (lambda j: j["scene"].update(confidence_percentile=120), "scene.confidence_percentile"),
    (lambda j: j["scene"].update(extrinsic_convention="auto"), "scene.extrinsic_convention"),
    (lambda j: j["scene"].update(crop=[0, 5, 0]), "scene.crop"),
    (lambda j: j["scene"].update(crop="auto"), "scene.crop"),
    (lambda j: j["scene"].update(crop=[0, -5, 0, 5]), "scene.crop[1]"),
    (lambda j: j["scene"].update(crop=[0, 5.5, 0, 5]), "scene.crop[1]"),
    (lambda j: j["scene"]["removal_boxes"][0].update(size=[1, 2]), "scene.removal_boxes[0].size"),
    (lambda j: j["scene"].update(point_cleaning=[]), "scene.point_cleaning"),
    (lambda j: j["scene"].update(point_cleaning={"depth_edge_ratio": 0}), "scene.point_cleaning.depth_edge_ratio"),
    (lambda j: j["scene"].update(point_cleaning={"depth_edge_ratio": "on"}), "scene.point_cleaning.depth_edge_ratio"),
    (lambda j: j["scene"].update(point_cleaning={"outliers": {"method": "voxel"}}),
     "scene.point_cleaning.outliers.method"),
    (lambda j: j["scene"].update(point_cleaning={"outliers": {}}), "scene.point_cleaning.outliers.method"),
    (lambda j: j["scene"].update(point_cleaning={"outliers": "statistical"}), "scene.point_cleaning.outliers"),
    (lambda j: j["scene"].update(point_cleaning={"outliers": {"method": "statistical", "neighbours": 0}}),
     "scene.point_cleaning.outliers.neighbours"),
    (lambda j: j["scene"].update(point_cleaning={"outliers": {"method": "statistical", "neighbours": 8.5}}),
     "scene.point_cleaning.outliers.neighbours"),
    (lambda j: j["scene"].update(point_cleaning={"outliers": {"method": "statistical", "std_ratio": -1}}),
     "scene.point_cleaning.outliers.std_ratio"),
    (lambda j: j["scene"].update(point_cleaning={"outliers": {"method": "radius", "radius_m": 0}}),
     "scene.point_cleaning.outliers.radius_m"),
    (lambda j: j["scene"].update(point_cleaning={"outliers": {"method": "radius", "min_points": True}}),
     "scene.point_cleaning.outliers.min_points"),
    (lambda j: j["assets"][0]["object_to_world"].pop("2"), "assets[0].object_to_world"),
    (lambda j: j["assets"][0]["object_to_world"].update({"1": np.zeros((4, 4)).tolist()}),
     "assets[0].object_to_world['1']"),
    (lambda j: j["assets"].append(copy.deepcopy(j["assets"][0])), "assets[1].name"),
    (lambda j: j.update(output_dir=""), "output_dir"),
    (lambda j: j["generate"].update(overlap=14), "generate.overlap"),
    (lambda j: j["generate"].update(steps=0), "generate.steps"),
    # bounds that match what runs (issue 14)
    (lambda j: j.update(resolution=[100000, 32]), "resolution[0]"),
    (lambda j: j.update(resolution=[16384, 16384]), "resolution"),
    (lambda j: j["frames"][0].update(frame=10 ** 7), "frames[0].frame"),
    (lambda j: j["frames"][0].update(source_frames=[0, 10 ** 9]), "frames[0].source_frames[1]"),
    (lambda j: j["frames"][0].update(K=[[1e300, 0, 32], [0, 50, 16], [0, 0, 1]]), "frames[0].K"),
    (lambda j: j["generate"].update(fps=1e300), "generate.fps"),
    (lambda j: j["generate"].update(seed=2 ** 64), "generate.seed"),
    (lambda j: j["generate"].update(decode_chunk=0), "generate.decode_chunk"),
    (lambda j: j["generate"].update(window=1000), "generate.window"),
    (lambda j: j["generate"].update(steps=10 ** 6), "generate.steps"),
    (lambda j: j["generate"].update(min_guidance=4.0, max_guidance=2.0), "generate.min_guidance"),
    (lambda j: j.update(output_dir="x" * 5000), "output_dir"),
    # the loader's own similarity rule: a 1e-5 shear validated before, then failed deep in the renderer
    (lambda j: j["scene"].update(vggt_to_world=(np.eye(4) + 1e-5 * np.eye(4, k=1)).tolist()),
     "scene.vggt_to_world"),
])
def test_bad_fields_are_named(tmp_path, mutate, field):
    job = minimal()
    mutate(job)
    p = tmp_path / "job.json"
    p.write_text(json.dumps(job))
    with pytest.raises(J.JobError) as e:
        J.load(p)
    assert str(e.value).startswith(f"job.json: {field}:"), str(e.value)
    with pytest.raises(J.JobError):  # never half-written: save validates first
        J.save(tmp_path / "other.json", job)
    assert not (tmp_path / "other.json").exists()


def test_not_json(tmp_path):
    (tmp_path / "job.json").write_text("{nope")
    with pytest.raises(J.JobError, match="not valid JSON"):
        J.load(tmp_path / "job.json")
    with pytest.raises(J.JobError, match="not found"):
        J.load(tmp_path / "missing.json")


def test_scene_reading_of_the_predictions():
    """scene.extrinsic_convention and scene.crop: optional (VGGT's world-to-camera, no crop), checked."""
    from scpainter_blender.core.vggt import predictions as vggt

    assert J.EXTRINSIC_CONVENTIONS == vggt.EXTRINSIC_CONVENTIONS
    job = minimal()
    J.validate(job)
    job["scene"].update(extrinsic_convention="camera_to_world", crop=[0, 77, 0, 77])
    J.validate(job)


def test_paths_stay_in_the_job_folder(tmp_path):
    """Every path a job names resolves inside its folder unless the user allows more (issue 14)."""
    import os

    job = minimal()
    path = tmp_path / "job.json"
    paths = job_inputs.job_paths(path, J.validate(job))
    assert paths["output_dir"] == str(tmp_path / "out")
    assert paths["scene.predictions"] == str(tmp_path / "recon" / "predictions.npz")
    assert "generate.checkpoint" not in paths            # asked for only when the job's checkpoint is used
    with pytest.raises(J.JobError) as e:
        job_inputs.job_paths(path, J.validate(job), checkpoint=True)
    assert e.value.field == "generate.checkpoint"
    for field, change in [("output_dir", {"output_dir": "../x"}), ("output_dir", {"output_dir": "a/../../x"}),
                          ("assets[0].ply", {"assets": [{**job["assets"][0], "ply": "/etc/passwd"}]})]:
        bad = {**job, **change}
        with pytest.raises(J.JobError) as e:
            job_inputs.job_paths(path, J.validate(bad))
        assert e.value.field == field and "outside the job's folder" in str(e.value)
        assert "--allow-outside" in e.value.hint and "--data-root" in e.value.hint
        assert job_inputs.job_paths(path, J.validate(bad), allow_outside=True)[field].startswith("/")
    os.symlink(tmp_path.parent, tmp_path / "up")          # inside by name, outside in fact
    with pytest.raises(J.JobError, match="symbolic link"):
        job_inputs.job_paths(path, J.validate({**job, "output_dir": "up/out"}))
    assert job_inputs.job_paths(path, J.validate({**job, "output_dir": "sub/../out/."}))["output_dir"] == str(tmp_path / "out")


def test_paths_may_also_lead_into_a_data_root(tmp_path):
    """A data root the user trusts (--data-root, a list's data-root:): a path may resolve inside the job's folder
    or inside the root, links and .. followed; anything else is refused naming the field and both folders."""
    import os

    from scpainter_blender.core import errors, outputs

    data = tmp_path / "data"                                # the shared recording and asset library
    (data / "recon").mkdir(parents=True)
    (data / "assets").mkdir()
    variant = tmp_path / "variants" / "v1"
    variant.mkdir(parents=True)
    path = variant / "job.json"
    roots = outputs.data_roots_option([str(data)])
    assert roots == (str(data),)
    job = minimal()
    job["scene"]["predictions"] = "../../data/recon/predictions.npz"
    job["assets"][0]["ply"] = str(data / "assets" / "car_01.ply")   # absolute, inside the root
    job["output_dir"] = "out"                                       # the job's own folder
    paths = job_inputs.job_paths(path, J.validate(job), data_roots=roots)
    assert paths["scene.predictions"] == str(data / "recon" / "predictions.npz")
    assert paths["assets[0].ply"] == str(data / "assets" / "car_01.ply")
    assert paths["output_dir"] == str(variant / "out")
    job["output_dir"] = "../../data/renders/v1"                     # the output folder may lie in the root too
    assert job_inputs.job_paths(path, J.validate(job), data_roots=roots)["output_dir"] == str(data / "renders" / "v1")

    def refused(change, field):
        bad = copy.deepcopy(job)
        change(bad)
        with pytest.raises(J.JobError) as e:
            job_inputs.job_paths(path, J.validate(bad), data_roots=roots)
        assert e.value.path == str(path) and e.value.field == field
        assert str(variant) in e.value.message and str(data) in e.value.message, e.value.message   # both folders
        assert "--data-root" in e.value.hint and "--allow-outside" in e.value.hint
        assert job_inputs.job_paths(path, J.validate(bad), allow_outside=True, data_roots=roots)[field]  # overrides
        return e.value

    (tmp_path / "elsewhere").mkdir()
    refused(lambda j: j["assets"][0].update(ply="../../elsewhere/car.ply"), "assets[0].ply")   # outside both
    refused(lambda j: j["assets"][0].update(ply="../../data/../elsewhere/car.ply"), "assets[0].ply")  # .. out of it
    refused(lambda j: j["scene"].update(predictions=str(data / ".." / "elsewhere" / "p.npz")), "scene.predictions")
    os.symlink(tmp_path / "elsewhere", data / "recon" / "linked")   # inside the root by name, outside in fact
    e = refused(lambda j: j["scene"].update(predictions="../../data/recon/linked/predictions.npz"),
                "scene.predictions")
    assert "symbolic link" in e.message
    refused(lambda j: j.update(output_dir="../../data/recon/linked/out"), "output_dir")
    # the root itself must be a folder: a file or a missing path is an ArgumentError naming the option
    (tmp_path / "file").write_text("not a folder")
    for root, what in ((tmp_path / "file", "is not a folder"), (tmp_path / "missing", "does not exist")):
        with pytest.raises(errors.ArgumentError) as e:
            outputs.data_roots_option([str(data), str(root)])
        assert e.value.field == "--data-root" and what in e.value.message and str(root) in e.value.message
    assert outputs.data_roots_option(None) == ()


def test_job_file_limits(tmp_path):
    """A job file is read within limits (files.read_json): too deep, a FIFO, NaN named by its field."""
    import os

    p = tmp_path / "job.json"
    p.write_text("[" * 100000)
    with pytest.raises(J.JobError, match="nested deeper"):
        J.load(p)
    job = minimal()
    text = json.dumps(job).replace('"confidence_percentile": 50.0', '"confidence_percentile": NaN')
    p.write_text(text)
    with pytest.raises(J.JobError) as e:
        J.load(p)
    assert e.value.field == "scene.confidence_percentile"
    os.remove(p)
    os.mkfifo(p)
    with pytest.raises(J.JobError, match="FIFO"):
        J.load(p)


def test_old_schema_still_loads_and_saves_in_the_new_one(tmp_path):
    """A scpainter.job/1 file (scene.world_from_vggt, before the a_to_b rule) loads; saving writes job/2."""
    old = minimal()
    old["schema"] = "scpainter.job/1"
    old["scene"]["world_from_vggt"] = old["scene"].pop("vggt_to_world")
    p = tmp_path / "old.json"
    p.write_text(json.dumps(old))
    job = J.load(p)
    np.testing.assert_array_equal(job.scene.vggt_to_world, np.array(old["scene"]["world_from_vggt"]))
    J.save(tmp_path / "new.json", job)
    new = json.loads((tmp_path / "new.json").read_text())
    assert new["schema"] == J.SCHEMA == "scpainter.job/2"
    assert "vggt_to_world" in new["scene"] and "world_from_vggt" not in new["scene"]
    # an old file's error names the field by the name that file uses
    old["scene"]["world_from_vggt"] = np.diag([1.0, 2, 1, 1]).tolist()
    p.write_text(json.dumps(old))
    with pytest.raises(J.JobError) as e:
        J.load(p)
    assert e.value.field == "scene.world_from_vggt"
    # the new schema does not accept the old name, and says which one it wants
    new["scene"]["world_from_vggt"] = new["scene"].pop("vggt_to_world")
    with pytest.raises(J.JobError) as e:
        J.validate(new)
    assert e.value.field == "scene.world_from_vggt" and "'vggt_to_world'" in e.value.message


@pytest.mark.parametrize("mutate,field", [
    (lambda j: j["generate"].update(windw=8), "generate.windw"),              # a typo would fall back silently
    (lambda j: j["scene"].update(vgt_to_world=np.eye(4).tolist()), "scene.vgt_to_world"),
    (lambda j: j["frames"][0].update(source_frame=[0]), "frames[0].source_frame"),
    (lambda j: j["assets"][0].update(object_to_wrld={}), "assets[0].object_to_wrld"),
    (lambda j: j["scene"]["removal_boxes"][0].update(sizes=[1, 1, 1]), "scene.removal_boxes[0].sizes"),
    (lambda j: j["scene"].update(point_cleaning={"edge_ratio": 0.1}), "scene.point_cleaning.edge_ratio"),
    # a field of the other method is refused, not silently ignored
    (lambda j: j["scene"].update(point_cleaning={"outliers": {"method": "radius", "neighbours": 8}}),
     "scene.point_cleaning.outliers.neighbours"),
    (lambda j: j.update(output=""), "output"),
])
def test_unknown_fields_are_refused(mutate, field):
    job = minimal()
    mutate(job)
    with pytest.raises(J.JobError) as e:
        J.validate(job)
    assert e.value.field == field and "spelling" in e.value.hint


def test_generation_settings_resolve_once():
    """Defaults live in GENERATE_DEFAULTS; window, guidance and fps default to the checkpoint's own."""
    class Config:
        window, min_guidance, max_guidance, fps = 8, 1.5, 2.5, 10.0

    s = J.GenerateSettings().resolve(Config())
    assert s == {"steps": 18, "window": 8, "overlap": 4, "seed": 0, "min_guidance": 1.5, "max_guidance": 2.5,
                 "fps": 10.0, "decode_chunk": 8, "sampler": "euler", "feature_reuse": 2, "guidance_sigma_min": 0.0,
                 "guidance_sigma_max": 30.0, "compile": "off", "gpu_tuning": "on"}
    assert {k: s[k] for k in J.GENERATE_DEFAULTS} == J.GENERATE_DEFAULTS
    s = J.GenerateSettings(steps=3, window=12).resolve(Config(), {"steps": 5, "seed": None})
    assert (s["steps"], s["window"], s["seed"]) == (5, 12, 0)         # command line > job > checkpoint > default
    class Small(Config):
        window = 3

    with pytest.raises(J.JobError, match="checkpoint's window") as e:  # overlap 4 against the checkpoint's 3
        J.GenerateSettings().resolve(Small(), path="job.json")
    assert e.value.field == "generate.overlap"
    with pytest.raises(J.JobError) as e:                               # overrides are named as flags
        J.check_generate_settings({"steps": 0}, "(command line)", "--")
    assert e.value.field == "--steps"
    # the speed settings (issue 44): validated like the others, the stock sampler reachable
    s = J.GenerateSettings(sampler="dpmpp2m").resolve(Config(), J.STOCK_SAMPLING)
    assert {k: s[k] for k in J.STOCK_SAMPLING} == J.STOCK_SAMPLING
    assert J.GenerateSettings.from_dict({"sampler": "heun", "feature_reuse": 3, "compile": "reduce-overhead"},
                                        "job.json").resolve(Config())["feature_reuse"] == 3
    for bad, field in (({"sampler": "ddim"}, "generate.sampler"), ({"feature_reuse": 0}, "generate.feature_reuse"),
                       ({"compile": True}, "generate.compile"), ({"gpu_tuning": "yes"}, "generate.gpu_tuning"),
                       ({"guidance_sigma_min": 5.0, "guidance_sigma_max": 1.0}, "generate.guidance_sigma_min"),
                       ({"guidance_sigma_max": -1.0}, "generate.guidance_sigma_max")):
        with pytest.raises(J.JobError) as e:
            J.GenerateSettings.from_dict(bad, "job.json")
        assert e.value.field == field


def test_job_built_in_code_is_validated_on_save(tmp_path):
    """save() validates a Job built in code, so a bad value never reaches a file."""
    job = J.validate(minimal())
    job.frames[0].K = np.zeros((3, 3))
    with pytest.raises(J.JobError) as e:
        J.save(tmp_path / "job.json", job)
    assert e.value.field == "frames[0].K" and not (tmp_path / "job.json").exists()


def test_point_cleaning_defaults_and_switches(tmp_path):
    """scene.point_cleaning: absent = the defaults (POINT_CLEANING, the one place they are written); a field
    absent = its default; null = off; an outlier method's own fields default per method; saved as resolved."""
    job = minimal()
    assert "point_cleaning" not in job["scene"]       # a job written before the setting existed
    c = J.validate(job).scene.point_cleaning
    assert c.to_dict() == J.POINT_CLEANING
    assert J.Scene("p.npz", np.eye(4)).point_cleaning.to_dict() == J.POINT_CLEANING   # the dataclass default too
    job["scene"]["point_cleaning"] = None
    c = J.validate(job).scene.point_cleaning
    assert c.depth_edge_ratio is None and c.outliers is None
    job["scene"]["point_cleaning"] = {"depth_edge_ratio": None}
    c = J.validate(job).scene.point_cleaning
    assert c.depth_edge_ratio is None
    assert (None if c.outliers is None else c.outliers.to_dict()) == J.POINT_CLEANING["outliers"]
    job["scene"]["point_cleaning"] = {"depth_edge_ratio": 0.2, "outliers": {"method": "radius", "min_points": 9}}
    saved = J.save(tmp_path / "job.json", job)
    written = json.loads((tmp_path / "job.json").read_text())["scene"]["point_cleaning"]
    assert written == {"depth_edge_ratio": 0.2,
                       "outliers": {"method": "radius", "radius_m": J.OUTLIER_FIELDS["radius"]["radius_m"],
                                    "min_points": 9}}
    assert saved.scene.point_cleaning.outliers.min_points == 9
    assert J.load(tmp_path / "job.json").to_dict() == saved.to_dict()
    for method, names in J.OUTLIER_FIELDS.items():
        o = J.OutlierRemoval.from_dict({"method": method}, "job.json", "x")
        assert o.to_dict() == {"method": method, **names}
    # a Job built in code with an unknown method is refused by name on save, never a KeyError
    bad = J.validate(minimal())
    bad.scene.point_cleaning.outliers = J.OutlierRemoval("voxel")
    with pytest.raises(J.JobError) as e:
        J.save(tmp_path / "bad.json", bad)
    assert e.value.field == "scene.point_cleaning.outliers.method"


def test_label_fields_round_trip_and_stay_out_of_the_layers():
    """assets[].class/.box, scene.recorded_frames/.recorded_objects and fps are read, written back, validated by
    name, and left out of layers_dict (the render's layer key): editing them changes labels only."""
    d = minimal()
    d["scene"] = {"predictions": "p.npz", "vggt_to_world": np.eye(4).tolist()}
    d["assets"] = [{"name": "car", "ply": "car.ply", "object_to_world": {"1": np.eye(4).tolist(),
                                                                        "2": np.eye(4).tolist()}}]
    plain = J.Job.from_dict(d).layers_dict()
    d["fps"] = 12.5
    d["assets"][0].update({"class": "van", "box": {"box_to_file": np.eye(4).tolist(), "size": [1.9, 4.5, 1.6]}})
    d["scene"].update({"recorded_frames": [1, 2], "recorded_objects": [
        {"id": "parked", "size": [1.8, 4.4, 1.5], "boxes": {"1": np.eye(4).tolist()}}]})
    job = J.Job.from_dict(d)
    assert job.to_dict()["fps"] == 12.5 and job.frame_rate() == (12.5, "job")
    assert job.assets[0].category == "van" and job.assets[0].box.size.tolist() == [1.9, 4.5, 1.6]
    assert job.scene.recorded_objects[0].boxes[1].shape == (4, 4) and job.scene.recorded_frames == [1, 2]
    assert J.Job.from_dict(job.to_dict()).to_dict() == job.to_dict()
    assert job.layers_dict() == plain
    for edit, field in (({"class": "a car"}, "assets[0].class"), ({"class": "hovercraft"}, "assets[0].class"),
                        ({"box": {"box_to_file": (2 * np.eye(4)).tolist(), "size": [1, 2, 3]}},
                         "assets[0].box.box_to_file"),
                        ({"box": {"box_to_file": np.eye(4).tolist(), "size": [1, 2]}}, "assets[0].box.size")):
        bad = {**d, "assets": [{**d["assets"][0], **edit}]}
        with pytest.raises(J.JobError) as e:
            J.Job.from_dict(bad)
        assert e.value.field == field
        if edit.get("class") == "hovercraft":          # not in the fixed table: the hint lists it
            assert "hovercraft" in e.value.message and "car, truck" in e.value.hint
    twice = {**d, "scene": {**d["scene"], "recorded_objects": d["scene"]["recorded_objects"] * 2}}
    with pytest.raises(J.JobError, match="appears twice"):
        J.Job.from_dict(twice)
    ignored = {**d, "scene": {**d["scene"], "recorded_objects": [
        {**d["scene"]["recorded_objects"][0], "ignore": True}]}}
    job = J.Job.from_dict(ignored)
    assert job.scene.recorded_objects[0].ignore and J.Job.from_dict(job.to_dict()).to_dict() == job.to_dict()
    assert not J.Job.from_dict(d).scene.recorded_objects[0].ignore
    assert "ignore" not in J.Job.from_dict(d).to_dict()["scene"]["recorded_objects"][0]
    bad = {**d, "scene": {**d["scene"], "recorded_objects": [{**d["scene"]["recorded_objects"][0], "ignore": 1}]}}
    with pytest.raises(J.JobError) as e:
        J.Job.from_dict(bad)
    assert e.value.field == "scene.recorded_objects[0].ignore"
    with pytest.raises(J.JobError) as e:
        J.Job.from_dict({**d, "scene": {**d["scene"], "recorded_frames": [3, 1]}})
    assert e.value.field == "scene.recorded_frames"
