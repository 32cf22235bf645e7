"""Detecting a recording's format by content, and the errors of files that are none."""

import pytest

from scpainter_blender.core.errors import InputError
from scpainter_blender.core.recording import plain, reader

from .recording_fixtures import drive, openlabel_document, write_json, write_kitti, write_nuscenes


def test_each_format_is_detected_by_content(tmp_path):
    d = drive(2)
    assert reader.detect(write_kitti(str(tmp_path / "k"), d)) == "kitti"
    assert reader.detect(write_nuscenes(str(tmp_path / "n"), d)) == "nuscenes"
    assert reader.detect(write_json(tmp_path / "o.txt", openlabel_document(d))) == "openlabel"
    assert reader.detect(write_json(tmp_path / "p.json", plain.document(2, []))) == "plain"
    assert reader.read(str(tmp_path / "p.json")).tracks == []


@pytest.mark.parametrize("content", ['{"schema": "other/1"}', "hello world\n", "[1, 2]"])
def test_unknown_formats_are_refused_with_the_list(tmp_path, content):
    p = tmp_path / "x.json"
    p.write_text(content)
    with pytest.raises(InputError, match="objects of an unknown format; the formats read: nuscenes, kitti, "
                                         "openlabel, plain") as e:
        reader.read(str(p))
    assert e.value.path == str(p)
    with pytest.raises(InputError, match="unknown objects format 'csv'"):
        reader.read(str(p), "csv")
    with pytest.raises(InputError, match="not a folder of nuScenes tables"):
        reader.detect(str(tmp_path))


def test_a_recorded_car_round_trips_from_file_to_job_to_labels(tmp_path):
    """A plain file's car, mapped into the world, written into a job, read back and labelled: the labels' box is the
    file's box (centre, size, heading) at each frame."""
    import numpy as np

    from scpainter_blender.core import job as J
    from scpainter_blender.core import labels
    from scpainter_blender.core.geometry import boxes

    d = drive(2)
    d["objects"] = d["objects"][:1]                                  # the still car
    path = write_json(tmp_path / "o.json", plain.document(2, d["objects"], d["world_to_camera"]))
    mapped = reader.recorded_objects(reader.read(path), d["world_to_camera"], 1)
    K = [[100.0, 0, 80], [0, 100.0, 48], [0, 0, 1]]
    job = J.Job((160, 96), [J.Frame(1 + i, np.array(K), d["world_to_camera"][i], []) for i in range(2)], "out",
                scene=J.Scene("p.npz", np.eye(4), recorded_objects=mapped.objects))
    J.save(str(tmp_path / "job.json"), job)
    job = J.load(str(tmp_path / "job.json"))
    for i in range(2):
        lab = labels.frame_labels(job, i, instance=np.zeros((96, 160)), hole=np.zeros((96, 160)),
                                  depth=np.full((96, 160), np.inf), amodal_pixels=np.array([0]), asset_hashes=[],
                                  asset_boxes=[])
        (car,) = [o for o in lab["objects"] if not o["synthetic"]]
        truth = boxes.object_pose(d["objects"][0]["boxes"][i], d["objects"][0]["size"])
        assert car["class"] == "car" and car["box_source"] == "recording"
        np.testing.assert_allclose(car["box_world"]["center"], truth["center"], atol=1e-9)
        np.testing.assert_allclose(car["box_world"]["size"], truth["size"], atol=1e-9)
        np.testing.assert_allclose(car["box_world"]["quaternion"], truth["quaternion"], atol=1e-9)
