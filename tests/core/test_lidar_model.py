"""core/lidar_model.py: the presets and the unknown-name error."""

import pytest

from scpainter_blender.core import errors, lidar_model


def test_presets_have_their_beams_and_an_unknown_name_lists_them():
    m = lidar_model.model("nuscenes-32")
    assert len(m.elevations_deg) == 32 and m.elevations_deg[0] > m.elevations_deg[-1]
    assert len(lidar_model.model("velodyne-64").elevations_deg) == 64
    with pytest.raises(errors.ArgumentError) as e:
        lidar_model.model("hdl-999")
    assert "nuscenes-32" in str(e.value) and e.value.field == "--lidar"
