"""Ground plane of a VGGT reconstruction by RANSAC (open3d), for metric scale from a known camera height.

Frames: everything here is in VGGT's world (the first camera's OpenCV frame, y down, VGGT units). The plane is
returned as (a, b, c, d) with a x + b y + c z + d = 0, unit normal, oriented towards the cameras.
"""

from __future__ import annotations

import numpy as np

from scpainter_blender.core import cameras, vggt


def fit_plane(points: np.ndarray, distance_threshold: float, num_iterations: int = 2000, seed: int = 0):
    """RANSAC plane through ``points`` (N, 3) with open3d, refined by least squares on the inliers.

    Returns (plane (4,), inlier indices, inlier RMS distance). Seeded: the same points give the same plane.
    """
    import open3d as o3d

    if len(points) < 3:
        raise ValueError(f"need at least 3 points to fit a plane, got {len(points)}")
    o3d.utility.random.seed(seed)
    origin = points.mean(axis=0)  # fit relative to the centroid: float32 inside open3d stays exact enough
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points - origin))
    _, inliers = pcd.segment_plane(distance_threshold=float(distance_threshold), ransac_n=3,
                                   num_iterations=int(num_iterations))
    inliers = np.asarray(inliers, dtype=np.int64)
    if len(inliers) < 3:
        raise ValueError("RANSAC found no plane")
    P = points[inliers]
    centre = P.mean(axis=0)
    _, _, Vt = np.linalg.svd(P - centre, full_matrices=False)
    n = Vt[2]
    d = -float(n @ centre)
    rms = float(np.sqrt(np.mean((P @ n + d) ** 2)))
    return np.array([*n, d]), inliers, rms


def fit_ground_plane(pred: vggt.VGGTPredictions, confidence_percentile: float = 50.0, max_tilt_deg: float = 30.0,
                     tries: int = 3, seed: int = 0):
    """The road plane under the cameras: the largest plane among low image rows whose normal is near "up".

    "Up" is the average of the cameras' -y axes. A plane tilted more than ``max_tilt_deg`` from it (a wall, a
    parked truck) is set aside and RANSAC runs again on the rest, up to ``tries`` times.
    """
    pts = vggt.ground_candidates(pred, confidence_percentile, seed=seed)
    if len(pts) < 100:
        raise ValueError(f"only {len(pts)} confident points in the lower image rows: too few to find the ground")
    up = -pred.world_to_camera[:, 1, :3].mean(axis=0)
    up /= np.linalg.norm(up)
    centres = cameras.camera_centers(pred.world_to_camera)
    depth_scale = float(np.median(np.linalg.norm(pts - centres.mean(0), axis=1)))
    threshold = 0.01 * depth_scale
    rest = pts
    for attempt in range(tries):
        plane, inliers, rms = fit_plane(rest, threshold, seed=seed + attempt)
        tilt = np.degrees(np.arccos(min(1.0, abs(float(plane[:3] @ up)))))
        if tilt <= max_tilt_deg:
            if np.median(centres @ plane[:3] + plane[3]) < 0:
                plane = -plane
            return plane, {"inliers": int(len(inliers)), "candidates": int(len(pts)), "inlier_rms_vggt": rms,
                           "tilt_deg": float(tilt), "threshold_vggt": threshold}
        rest = np.delete(rest, inliers, axis=0)
        if len(rest) < 100:
            break
    raise ValueError(f"no plane within {max_tilt_deg}° of the cameras' up axis: the ground is not visible "
                     "(use a scale factor or a metric trajectory instead)")
