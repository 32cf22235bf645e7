"""Which way VGGT's ``extrinsic`` points: world-to-camera (VGGT's) or camera-to-world, decided by the point head.

Some tools around VGGT save camera-to-world poses under ``extrinsic`` (facebookresearch/vggt issues 275, 370).
VGGT's depth and point heads are independent estimates of the same points, so a file's poses can be checked:
unproject each frame's depth with ``extrinsic`` as stored and with its inverse, and see which lands on the file's
``world_points``. ``resolve_convention`` applies the requested convention when loading (``core.vggt.npz``), checking
first when it is "auto", and refuses a camera-to-world file, or one that neither reading fits, naming the frame.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import cameras, unproject
from . import predictions as vggt

#: A reading of ``extrinsic`` agrees with the file's ``world_points`` in a frame when the depth it unprojects
#: lands within this fraction of the frame's median depth of the point head (median over confident pixels).
#: VGGT's depth and point heads are independent estimates that differ by a few percent of the depth; reading
#: camera-to-world poses as world-to-camera misses by twice the camera's offset plus twice its rotation angle
#: times the depth, far beyond this once the camera has moved.
CONVENTION_TOLERANCE = 0.25

#: Within that tolerance, a reading still loses a frame to the other one when the other lands at most half as far
#: and at least this fraction of the depth nearer: a camera-to-world file of a slow drive misses by only ~10-20 %
#: of the depth in its later frames, yet its inverse fits exactly. Frames where the camera barely moved give both
#: readings the same distance and decide nothing.
CONVENTION_MARGIN = 0.02

#: Pixels compared per frame by the convention check (a regular grid; more adds nothing to a median).
CONVENTION_CHECK_PIXELS = 20_000


@dataclass
class ConventionCheck:
    """Depth unprojected with each reading of ``extrinsic`` against the file's ``world_points``, per frame.

    ``frames``: the frames checked (frames without enough confident pixels are left out); ``relative[c]``: per
    checked frame, the median distance between the two point estimates divided by the median depth, for
    convention ``c``; ``distance[c]``: that median distance in VGGT units; ``pixels``: pixels compared per frame.
    """

    frames: np.ndarray
    relative: dict
    distance: dict
    pixels: np.ndarray
    tolerance: float = CONVENTION_TOLERANCE

    def agrees(self, convention: str) -> bool:
        """Every checked frame within the tolerance, and in none does the other reading fit decisively better."""
        this = self.relative[convention]
        other = next(v for k, v in self.relative.items() if k != convention)
        beaten = (other <= 0.5 * this) & (this - other >= CONVENTION_MARGIN)
        return bool(len(self.frames)) and bool(np.all(this <= self.tolerance)) and not bool(np.any(beaten))

    def worst(self, convention: str) -> int:
        """Index (into ``frames``) of the frame where ``convention`` disagrees most."""
        return int(np.argmax(self.relative[convention]))

    def to_json(self) -> dict:
        return {"frames": self.frames.tolist(), "tolerance": self.tolerance, "pixels": self.pixels.tolist(),
                "relative": {k: v.tolist() for k, v in self.relative.items()},
                "distance_vggt": {k: v.tolist() for k, v in self.distance.items()}}



def check_extrinsic_convention(pred: vggt.VGGTPredictions, tolerance: float = CONVENTION_TOLERANCE,
                               max_pixels: int = CONVENTION_CHECK_PIXELS) -> ConventionCheck | None:
    """Each frame's depth, unprojected with ``pred.world_to_camera`` as stored and with its inverse, against the
    file's ``world_points`` (None without them).

    Pixels: a regular grid of at most ``max_pixels`` per frame, with finite values, positive depth and both
    confidences at or above the frame's median (VGGT's point head is least reliable where it is unsure). Per frame
    and reading: median distance between the two estimates, and that divided by the median depth. A frame with
    fewer than 16 such pixels is left out.
    """
    if pred.world_points is None:
        return None
    S, H, W = pred.depth.shape
    step = max(1, int(np.ceil(np.sqrt(H * W / max_pixels))))
    rows, cols = np.mgrid[0:H:step, 0:W:step]
    rows, cols = rows.ravel(), cols.ravel()
    readings = {"world_to_camera": cameras.as_matrix4(pred.world_to_camera),
                "camera_to_world": cameras.rigid_inverse(pred.world_to_camera)}
    K = pred.K
    frames, pixels = [], []
    rel = {k: [] for k in readings}
    dist = {k: [] for k in readings}
    for i in range(S):
        d = pred.depth[i][rows, cols]
        c = pred.depth_conf[i][rows, cols]
        ok = (d > 0) & (c > 1e-5)
        if pred.valid is not None:
            ok &= pred.valid[i][rows, cols]
        if pred.world_points_valid is not None:
            ok &= pred.world_points_valid[i][rows, cols]
        if ok.sum() >= 16:
            ok &= c >= np.median(c[ok])
        if pred.world_points_conf is not None and ok.sum() >= 16:
            wc = pred.world_points_conf[i][rows, cols]
            ok &= wc >= np.median(wc[ok])
        if ok.sum() < 16:
            continue
        r, q = rows[ok], cols[ok]
        P = pred.world_points[i][r, q].astype(np.float64)
        scale = float(np.median(d[ok]))
        frames.append(i)
        pixels.append(int(ok.sum()))
        for name, T in readings.items():
            X = unproject.unproject_pixels(pred.depth[i], K[i], T[i], r, q)
            m = float(np.median(np.linalg.norm(X - P, axis=1)))
            dist[name].append(m)
            rel[name].append(m / scale)
    return ConventionCheck(np.array(frames, np.int64), {k: np.array(v) for k, v in rel.items()},
                           {k: np.array(v) for k, v in dist.items()}, np.array(pixels, np.int64), tolerance)


def _length(units: float, metres_per_unit: float | None) -> str:
    if metres_per_unit:
        return f"{units * metres_per_unit:.3g} m"
    return f"{units:.3g} VGGT units (the metric scale is not known before the import's fit)"


def resolve_convention(pred: vggt.VGGTPredictions, requested: str, metres_per_unit: float | None) -> None:
    """Apply the extrinsic convention to ``pred`` (in place), checking it first when ``requested`` is "auto".

    ``requested``: "world_to_camera" (kept, not checked), "camera_to_world" (inverted, not checked) or "auto";
    the outcome goes to ``pred.report``. PredictionsError (key "extrinsic") when "auto" finds camera-to-world
    poses or poses that neither reading fits; ``metres_per_unit`` (when known) puts the distances in metres."""
    report = pred.report
    if requested == "camera_to_world":
        pred.world_to_camera = cameras.rigid_inverse(pred.world_to_camera)
        report.extrinsic_convention = "camera_to_world"
        report.info.append("extrinsic read as camera-to-world (as given) and inverted; not checked")
        return
    report.extrinsic_convention = "world_to_camera"
    if requested == "world_to_camera":
        report.info.append("extrinsic read as world-to-camera (VGGT's; as given), not checked")
        return
    check = check_extrinsic_convention(pred)
    report.check = check
    redo = ("re-import with the extrinsic convention set explicitly (the import's 'Extrinsic Convention' option, "
            "--extrinsic-convention on the command line)")
    if check is None or not len(check.frames):
        why = ("the file has no world_points" if check is None else
               "no frame has enough confident pixels with a finite point-map value")
        report.warnings.append(f"extrinsic convention not checked ({why}): read as world-to-camera, VGGT's; if "
                               f"the points look scattered and the camera path wrong, {redo}: camera_to_world")
        return
    report.convention_checked = True
    w2c, c2w = vggt.EXTRINSIC_CONVENTIONS
    if check.agrees(w2c):
        k = check.worst(w2c)
        note = (f"extrinsic checked against world_points in {len(check.frames)} frames: world-to-camera agrees "
                f"(median {np.median(check.relative[w2c]):.1%} of the depth, at most {check.relative[w2c][k]:.1%} "
                f"in frame {int(check.frames[k])})")
        if check.agrees(c2w):
            note += "; the cameras barely move, so camera-to-world would fit as well"
        report.info.append(note)
        return
    k = check.worst(w2c)
    f = int(check.frames[k])
    if check.agrees(c2w):
        j = check.worst(c2w)
        raise vggt.PredictionsError(
            pred.path, "extrinsic",
            f"holds camera-to-world poses, not VGGT's world-to-camera: read as world-to-camera, the depth of frame "
            f"{f} lands {_length(check.distance[w2c][k], metres_per_unit)} from the file's world_points (median, "
            f"{check.relative[w2c][k]:.0%} of the depth; tolerance {check.tolerance:.0%}), while the inverted poses "
            f"agree in every frame (at most {check.relative[c2w][j]:.1%}). "
            f"{redo[0].upper() + redo[1:]}: camera_to_world")
    # neither reading fits: name the frame that neither explains
    worst = int(np.argmax(np.minimum(check.relative[w2c], check.relative[c2w])))
    f = int(check.frames[worst])
    raise vggt.PredictionsError(
        pred.path, "extrinsic",
        f"neither reading of the poses fits the file's world_points: in frame {f} the depth lands "
        f"{_length(check.distance[w2c][worst], metres_per_unit)} from them read as world-to-camera "
        f"({check.relative[w2c][worst]:.0%} of the depth) and {_length(check.distance[c2w][worst], metres_per_unit)} "
        f"read as camera-to-world ({check.relative[c2w][worst]:.0%}; tolerance {check.tolerance:.0%}). Check that "
        "extrinsic, intrinsic, depth and world_points come from the same VGGT run and were cropped or resized "
        f"together; to import the poses anyway, {redo}: world_to_camera or camera_to_world (no check)")
