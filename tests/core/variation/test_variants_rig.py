"""``vary`` of a rig job (docs/design.md §17): the whole rig moves, every camera by the same shift."""

import os

import numpy as np

from scpainter_blender.core import job as J, rig as R, rig_convert
from scpainter_blender.core.geometry import cameras
from scpainter_blender.core.variation import spec as spec_mod, variants
from tests_support import street_base_job


def test_a_variant_of_a_rig_job_moves_every_camera_by_one_shift(street, tmp_path):
    base_path = str(tmp_path / "base" / "job.json")
    street_base_job(street, base_path)
    rig = R.preset("nuscenes", scale=0.02)
    rig_path = str(tmp_path / "rig" / "job.json")
    rig_convert.make(base_path, rig, rig_path, allow_outside=True)
    sp = spec_mod.VariationSpec(variants=2, seed=3, shifts_m=(2.0,), car_count=(0, 0),
                                lane_change_probability=0.0, resolution=(64, 36))
    out = str(tmp_path / "vary")
    manifest = variants.make_variants(rig_path, sp, out, allow_outside=True)
    placed = [e for e in manifest["variants"] if e["job"]]
    assert placed, manifest["variants"]
    base = J.load(rig_path)
    before = {c.name: j for c, j in base.camera_jobs()}
    for e in placed:
        job = J.load(os.path.join(out, e["job"]))
        assert job.rig is not None and job.resolution is None and job.frames[0].K is None
        assert [c.resolution for c in job.rig.cameras] == [(64, 36)] * 6    # 32 x 18 scaled to the spec's width
        shifts = []
        for cam, cj in job.camera_jobs():
            old = np.stack([f.world_to_camera for f in before[cam.name].frames])
            new = np.stack([f.world_to_camera for f in cj.frames])
            np.testing.assert_allclose(new[:, :3, :3], old[:, :3, :3], atol=1e-12)   # orientation kept
            shifts.append(cameras.camera_centers(new) - cameras.camera_centers(old))
        for s in shifts[1:]:
            np.testing.assert_allclose(s, shifts[0], atol=1e-9)                    # one shift for every camera
        d = shifts[0]
        np.testing.assert_allclose(np.linalg.norm(d[:, :2], axis=1), 2.0, atol=1e-6)   # the drawn 2 m, sideways
        np.testing.assert_allclose(d[:, 2], 0.0, atol=1e-9)
        # and it is the ego's own shift
        e2w_old = np.stack([f.ego_to_world for f in base.frames])
        e2w_new = np.stack([f.ego_to_world for f in job.frames])
        np.testing.assert_allclose(e2w_new[:, :3, 3] - e2w_old[:, :3, 3], d, atol=1e-9)
