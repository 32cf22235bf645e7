"""Spinning LiDAR models (docs/design.md §17): the beam elevations, azimuth step, range and rate of each preset.

``MODELS`` is the one table of them; ``model(name)`` finds one, an unknown name an error listing the names.
(A first version by the lead, so the rig contract can name its models; the LiDAR work fills it in.)

No bpy, no torch: numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ArgumentError


@dataclass(frozen=True)
class LidarModel:
    """``elevations_deg`` (B,) beam elevations, top beam first, degrees above the sensor's xy plane;
    ``azimuth_step_deg`` between firings; ``min_range_m``, ``max_range_m``; ``rate_hz`` revolutions per second."""
    name: str
    elevations_deg: tuple
    azimuth_step_deg: float
    min_range_m: float
    max_range_m: float
    rate_hz: float
    description: str = ""


MODELS = {
    "nuscenes-32": LidarModel("nuscenes-32", tuple(np.linspace(10.67, -30.67, 32).round(4)), 0.3332, 1.0, 70.0, 20.0,
                              "nuScenes' LIDAR_TOP, a Velodyne HDL-32E at 20 Hz"),
    "velodyne-64": LidarModel("velodyne-64", tuple(np.linspace(2.0, -24.9, 64).round(4)), 0.1728, 1.0, 120.0, 10.0,
                              "a Velodyne HDL-64E at 10 Hz"),
}


def model(name: str, field: str = "--lidar") -> LidarModel:
    """The model called ``name``; an ``ArgumentError`` on ``field`` listing the names otherwise."""
    if name not in MODELS:
        raise ArgumentError(field, f"no LiDAR model {name!r}: expected one of {sorted(MODELS)}")
    return MODELS[name]
