"""Spinning LiDAR sensor models: the beam elevation table, the azimuth step, the range window and the spin rate
(docs/design.md §10a). The simulator is ``backend/lidar``; a rig names its LiDAR's model by key (``core.rig``).

Conventions (one place for them; the simulator and the nuScenes export follow them):

- **Sensor frame**: nuScenes' ``LIDAR_TOP`` frame, which is the Velodyne's own: x right, y forward, z up, metres,
  origin at the sensor. ``.pcd.bin`` points are in it.
- **Elevation** e (degrees) is the angle above the x-y plane; ``elevations_deg`` lists the beams top first
  (largest elevation first). A beam's place in that list is its *row*.
- **Ring**: ``ring = B - 1 - row``, so ring 0 is the lowest beam and ring B - 1 the top one. This is the Velodyne
  ROS driver's ring number (ros-drivers/velodyne, ``velodyne_pointcloud/src/lib/calibration.cpp``: rings are
  assigned in increasing vertical angle, 0 the lowest), which nuScenes' ``.pcd.bin`` 5th column carries (the
  HDL-32E range-image tools for nuScenes map ring 0 to −30.67° and ring 31 to +10.67°).
- **Azimuth** φ (degrees) is the Velodyne's: 0 along +y (forward), growing clockwise seen from above (towards +x,
  right). Column c of a sweep is at φ = c · ``azimuth_step_deg``, c = 0 .. ``columns`` − 1. A ray's unit direction
  is (sin φ cos e, cos φ cos e, sin e).

The presets (public figures):

- ``nuscenes-32``: nuScenes' ``LIDAR_TOP``, a Velodyne HDL-32E: 32 beams evenly spaced from +10.67° down to
  −30.67° (41.3° vertical field, the HDL-32E manual; 1.33° apart), spun at 20 Hz with "1080 (±10) points per ring"
  and "usable returns up to 70 meters" (nuScenes' sensor description, as quoted in lkk688/mytutorial
  ``docs/source/nuscenes.rst``): an azimuth step of 360°/1080 = 1/3°, 34 560 rays a sweep, 70 m. Returns nearer
  than 1 m are dropped (the ego car's own body, which no reconstruction holds; the devkit's ``remove_close``
  drops the same radius).
- ``velodyne-64``: a Velodyne HDL-64E (KITTI's): 64 beams evenly spaced from +2° down to −24.9° (the 26.8-26.9°
  vertical field of the HDL-64E manual), 10 Hz, an azimuth step of 0.17° (2 118 columns), "usable returns up to
  120 meters" (HDL-64E manual). The real sensor's beams are not evenly spaced; the even table is the common
  simulation stand-in.

numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ArgumentError, did_you_mean


@dataclass(frozen=True)
class LidarModel:
    """A spinning LiDAR: ``elevations_deg`` (B,) beam elevations in degrees, top first (row 0 = top, ring B − 1);
    ``azimuth_step_deg`` the angle between two columns; returns only at ranges in [``min_range_m``,
    ``max_range_m``]; ``rate_hz`` sweeps a second; ``description`` says what sensor it stands for."""
    name: str
    elevations_deg: tuple
    azimuth_step_deg: float
    min_range_m: float
    max_range_m: float
    rate_hz: float
    description: str = ""

    @property
    def beams(self) -> int:
        """B, the number of beams (rings)."""
        return len(self.elevations_deg)

    @property
    def columns(self) -> int:
        """A, the number of azimuth columns of one turn: round(360 / ``azimuth_step_deg``)."""
        return int(round(360.0 / self.azimuth_step_deg))

    @property
    def rays(self) -> int:
        """B · A, the rays of one sweep."""
        return self.beams * self.columns

    def ring(self, row: int | np.ndarray) -> int | np.ndarray:
        """The ring index (0 = lowest beam) of a row (0 = top beam) or an array of rows."""
        return self.beams - 1 - np.asarray(row)

    def directions(self) -> np.ndarray:
        """(A, B, 3) float64 unit ray directions in the sensor frame, [column, row] (see the module's conventions)."""
        e = np.deg2rad(np.asarray(self.elevations_deg, np.float64))[None, :]
        phi = np.deg2rad(np.arange(self.columns) * (360.0 / self.columns))[:, None]
        return np.stack([np.sin(phi) * np.cos(e), np.cos(phi) * np.cos(e), np.broadcast_to(np.sin(e), (
            self.columns, self.beams))], -1)


def _even(top: float, bottom: float, beams: int) -> tuple:
    return tuple(float(x) for x in np.linspace(top, bottom, beams))


MODELS = {
    "nuscenes-32": LidarModel("nuscenes-32", _even(10.67, -30.67, 32), 360.0 / 1080, 1.0, 70.0, 20.0,
                              "nuScenes LIDAR_TOP (Velodyne HDL-32E): 32 beams +10.67..-30.67 deg, 20 Hz, "
                              "1080 columns, 70 m"),
    "velodyne-64": LidarModel("velodyne-64", _even(2.0, -24.9, 64), 0.17, 1.0, 120.0, 10.0,
                              "Velodyne HDL-64E: 64 beams +2..-24.9 deg, 10 Hz, 0.17 deg columns, 120 m"),
}

#: The model a rig's LiDAR gets when none is named.
DEFAULT = "nuscenes-32"


def model(name: str, field: str = "--lidar") -> LidarModel:
    """The preset called ``name``; an unknown name is an ``ArgumentError`` on ``field`` listing the presets (a
    job file's reader catches it and names its own file and field, or checks ``name in MODELS`` itself)."""
    if name not in MODELS:
        raise ArgumentError(field, f"no LiDAR model {name!r}{did_you_mean(name, MODELS)}",
                            hint="one of: " + ", ".join(sorted(MODELS)))
    return MODELS[name]
