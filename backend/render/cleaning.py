"""Point cleaning, once per scene: ``clean_cloud`` makes a scene's points as the renderer (``frames.load_scene``)
and the training pairs (``train.pairs``) both take them; ``outlier_keep`` is open3d's outlier removal.

The depth-edge test runs earlier, per source frame on its depth map (``core.geometry.point_cloud.depth_edges``); what is
left here are points that no depth map shows as odd: floaters a little off every surface, sparse where real
surfaces are dense. Two rules, open3d's own (``job.OutlierRemoval`` holds the settings, ``job.POINT_CLEANING``
the measured defaults):

- ``statistical`` (``PointCloud.remove_statistical_outlier(nb_neighbors=neighbours, std_ratio)``): m_i = the
  mean distance from point i to its ``neighbours`` nearest points, i itself among them (open3d 0.19's k-NN
  search returns the point itself, at distance 0); drop i when m_i > mean(m) + std_ratio · std(m), the mean and
  the sample standard deviation (N − 1) taken over the whole cloud.
- ``radius`` (``PointCloud.remove_radius_outlier(nb_points=min_points, radius=radius_m)``): drop i when fewer
  than ``min_points`` other points lie within ``radius_m`` metres (open3d 0.19 does not count i itself).

Both rules as stated are checked against a brute-force numpy version in tests/backend/render/test_cleaning.py,
so an open3d that changes them fails there.

open3d is imported here only, and only when a rule is on (docs/design.md §2: nothing outside the backend imports
it). Positions go in relative to a point near the cloud so float64 keeps them exact far from the world origin.
"""

from __future__ import annotations

import time

import numpy as np

from scpainter_blender.core.geometry import point_cloud
from scpainter_blender.core import job as job_mod


def clean_cloud(pred, confidence_percentile: float, vggt_to_world, point_cleaning, removal_boxes=()):
    """A scene's points, cleaned: ``point_cloud.scene_cloud`` (confidence filter and, with
    ``point_cleaning.depth_edge_ratio``, the depth-edge test per source frame; then the ``removal_boxes``,
    ``job.RemovalBox``), then ``outlier_keep`` among the points still kept. ``point_cleaning``: a
    ``job.PointCleaning``, None: no cleaning.

    Returns (cloud ``point_cloud.FramePoints``, keep (N,) bool over its points, stats {``removed_points``,
    ``depth_edge_points``, ``outlier_points``, ``cloud_s``, ``outliers_s``}). One function, so the points the
    model is trained on and those it is given at inference are cleaned alike."""
    clean = point_cleaning or job_mod.PointCleaning(None, None)
    t0 = time.perf_counter()
    cloud, keep = point_cloud.scene_cloud(pred, confidence_percentile, vggt_to_world, clean.depth_edge_ratio,
                                          removal_boxes)
    t_cloud = time.perf_counter() - t0
    removed = int((~keep).sum())
    t0 = time.perf_counter()
    inliers = np.ones(len(cloud), bool)
    inliers[keep] = outlier_keep(cloud.positions[keep], clean.outliers)
    keep &= inliers
    stats = {"removed_points": removed, "depth_edge_points": cloud.depth_edge_points,
             "outlier_points": int((~inliers).sum()), "cloud_s": t_cloud, "outliers_s": time.perf_counter() - t0}
    return cloud, keep, stats


def outlier_keep(positions, outliers) -> np.ndarray:
    """(N,) bool: True for the points ``outliers`` (a ``job.OutlierRemoval``, or None: keep all) keeps.

    ``positions`` (N, 3) world metres, any float dtype (used in float64)."""
    positions = np.asarray(positions)
    keep = np.ones(len(positions), bool)
    if outliers is None or len(positions) == 0:
        return keep
    import open3d as o3d  # lazily: only a scene that asks for it pays the import (~1 s)

    xyz = np.asarray(positions, np.float64)
    xyz = xyz - xyz[0]  # open3d's KD-tree works in float64; relative keeps 1e5 m scenes exact
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    if outliers.method == "statistical":
        _, index = cloud.remove_statistical_outlier(nb_neighbors=int(outliers.neighbours),
                                                    std_ratio=float(outliers.std_ratio))
    elif outliers.method == "radius":
        _, index = cloud.remove_radius_outlier(nb_points=int(outliers.min_points), radius=float(outliers.radius_m))
    else:  # job.OutlierRemoval validates the method: only code that builds one by hand can get here
        raise ValueError(f"unknown outlier method {outliers.method!r}")
    keep[:] = False
    keep[np.asarray(index, np.int64)] = True
    return keep
