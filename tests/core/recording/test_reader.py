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
