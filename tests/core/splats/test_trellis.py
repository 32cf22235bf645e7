"""core.splats.trellis: TRELLIS/Amodal3R files (their axes, the decoder's bound) and detect_axes, both ways."""

import numpy as np

from tests.core.splats import splat_fixtures as F
from scpainter_blender.core import shapes
from scpainter_blender.core.splats import gaussians as splats, inria as splats_inria, reader as splats_io, trellis


def test_trellis_amodal3r_file(tmp_path):
    zup, arr = F.trellis_like_file(tmp_path / "amodal3r.ply")
    ply = splats_io.read_ply(tmp_path / "amodal3r.ply")
    assert ply.sh_degree == 0 and set(ply.extra) == {"nx", "ny", "nz"}
    g = splats.decode(ply)
    assert len(g) == 40 and g.dropped == {}
    back_to_zup = g.means.astype(np.float64) @ trellis.ZUP_TO_TRELLIS_FILE  # p = T^T p_file
    assert np.allclose(back_to_zup, zup, atol=1e-6)
    assert np.all(np.abs(back_to_zup) <= 0.5 + 1e-6)  # TRELLIS's unit cube


def test_trellis_bound_from_the_decoder():
    # 64^3 voxels, Gaussians up to 0.75 voxel (0.5 · voxel_size 1.5) from their voxel centre; checked against
    # microsoft/TRELLIS trellis/models/structured_latent_vae/decoder_gs.py
    assert abs(trellis.TRELLIS_MEAN_BOUND - (0.5 + 0.75 / 64)) < 1e-4
    assert trellis.TRELLIS_MEAN_BOUND > 0.5 - 0.5 / 64 + 0.75 / 64  # the farthest a real TRELLIS mean can be


def test_detect_axes_trellis_car_touching_the_cube(tmp_path):
    """A car filling the cube, some means 0.504 from the origin (the decoder's voxel offset): TRELLIS."""
    path = tmp_path / "car.ply"
    shapes.save_as_amodal3r(path, shapes.procedural_car_gaussians(count=3000, seed=1))
    ply = splats_io.read(path)
    ply.xyz *= np.float32(0.504 / np.abs(ply.xyz).max())
    splats_inria.write_ply(path, ply)
    ply = splats_io.read(path)
    assert 0.5 < np.abs(ply.xyz).max() <= 0.5041
    axes, reason = trellis.detect_axes(ply, splats.valid_rows(ply)[0])
    assert axes == "TRELLIS", reason
    assert reason == ("TRELLIS/Amodal3R layout (17 properties, zero normals, SH 0) and all means within ±0.5117 "
                      "(the decoder's unit cube)")
    # the same object scaled past the decoder's reach is not TRELLIS
    ply.xyz *= np.float32(0.73 / 0.504)
    assert trellis.detect_axes(ply) == ("NONE", "not TRELLIS: means reach 0.73, outside the unit cube (TRELLIS "
                                                "stays within ±0.5117)")
    zup, _ = F.trellis_like_file(tmp_path / "t.ply")
    assert trellis.detect_axes(splats_io.read(tmp_path / "t.ply"))[0] == "TRELLIS"


def test_detect_axes_not_trellis(tmp_path):
    splats_inria.write_ply(tmp_path / "scene.ply", F.random_ply(N=50, degree=3))
    assert trellis.detect_axes(splats_io.read(tmp_path / "scene.ply")) == ("NONE", "not TRELLIS: has f_rest (SH 3)")
    small = F.random_ply(N=50, degree=0, extras=False)
    small.xyz *= np.float32(0.1)
    splats_inria.write_ply(tmp_path / "sh0.ply", small)
    axes, reason = trellis.detect_axes(splats_io.read(tmp_path / "sh0.ply"))
    assert axes == "NONE" and reason.startswith("not TRELLIS: no normals")
    labelled = F.random_ply(N=50, degree=0)  # normals plus a 'label' property
    labelled.xyz *= np.float32(0.1)
    assert trellis.detect_axes(labelled) == ("NONE", "not TRELLIS: extra properties ['label']")
    F.trellis_like_file(tmp_path / "t.ply")
    ply = splats_io.read(tmp_path / "t.ply")
    ply.extra["nx"][3] = 1.0
    assert trellis.detect_axes(ply) == ("NONE", "not TRELLIS: normals are not all zero")
    # same properties, another order
    cols = F.inria_columns(splats_io.read(tmp_path / "t.ply"))
    cols = cols[:3] + [(n, "float", np.zeros(40, np.float32)) for n in ("nx", "ny", "nz")][::-1] + cols[3:]
    F.write_typed_ply(tmp_path / "order.ply", cols)
    assert trellis.detect_axes(splats_io.read(tmp_path / "order.ply"))[1] == ("not TRELLIS: the properties are "
                                                                              "not in TRELLIS's save_ply order")
    F.write_compressed(tmp_path / "c.ply", F.random_gaussians(30, 0, seed=2))
    assert trellis.detect_axes(splats_io.read(tmp_path / "c.ply"))[1] == ("not TRELLIS: its layout is SuperSplat "
                                                                           "compressed PLY")
