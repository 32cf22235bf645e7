"""core/lidar_model.py: the presets' public figures, the ring and azimuth conventions, and an unknown name's error."""

import numpy as np
import pytest

from scpainter_blender.core import errors, lidar_model


def test_nuscenes_preset_is_the_hdl32e_as_nuscenes_runs_it():
    m = lidar_model.model("nuscenes-32")
    assert m.beams == 32 and m.columns == 1080 and m.rays == 34_560
    assert m.elevations_deg[0] == pytest.approx(10.67) and m.elevations_deg[-1] == pytest.approx(-30.67)
    assert np.allclose(np.diff(m.elevations_deg), -41.34 / 31)  # evenly spaced, top first
    assert (m.rate_hz, m.max_range_m) == (20.0, 70.0)
    assert lidar_model.DEFAULT == "nuscenes-32"


def test_velodyne64_preset():
    m = lidar_model.model("velodyne-64")
    assert m.beams == 64 and m.elevations_deg[0] == 2.0 and m.elevations_deg[-1] == pytest.approx(-24.9)
    assert (m.rate_hz, m.max_range_m) == (10.0, 120.0) and m.columns == round(360 / 0.17)


def test_ring_zero_is_the_lowest_beam_and_directions_follow_the_sensor_frame():
    m = lidar_model.model("nuscenes-32")
    assert m.ring(0) == 31 and m.ring(31) == 0 and list(m.ring(np.array([0, 31]))) == [31, 0]
    d = m.directions()
    assert d.shape == (1080, 32, 3) and np.allclose(np.linalg.norm(d, axis=-1), 1)
    # column 0 looks forward (+y), a quarter turn later right (+x): azimuth grows clockwise seen from above
    assert d[0, 0, 1] > 0 and abs(d[0, 0, 0]) < 1e-12
    assert d[270, 0, 0] > 0 and abs(d[270, 0, 1]) < 1e-12
    assert np.rad2deg(np.arcsin(d[0, :, 2])) == pytest.approx(np.array(m.elevations_deg))


def test_an_unknown_preset_is_an_argument_error_listing_the_presets():
    with pytest.raises(errors.ArgumentError) as e:
        lidar_model.model("hdl-16", field="rig.lidar.model")
    assert e.value.field == "rig.lidar.model" and "hdl-16" in e.value.message
    assert "nuscenes-32" in e.value.hint and "velodyne-64" in e.value.hint
