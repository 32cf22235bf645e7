"""core.splats.spz, issue 42: SPZ extension records (nianticlabs/spz extensions/README.md) are read or skipped — after
the attributes in a version 2/3 gzip stream, between the header and the table of contents in version 4 — and a
declared ``SPZ_ADOBE_coordinate_system`` is applied, so one car written with and without a declaration reads back
the same (checked against Niantic's own loader where it is installed); damaged records are refused by name."""

import gzip

import numpy as np
import pytest

from tests.core.splats import splat_fixtures as F
import splat_transform
from scpainter_blender.core.geometry import cameras
from scpainter_blender.core.splats import gaussians as splats, reader as splats_io, spz
from scpainter_blender.core.splats.gltf_splats import sh_rotation

#: A safe-orbit-camera record (type 0xADBE0002, three float32) and a record of a vendor no reader knows.
ORBIT = F.spz_extension(0xADBE0002, np.array([-0.5, 0.5, 1.0], "<f4").tobytes())
UNKNOWN = F.spz_extension(0x12340001, b"vendor data")


def _cloud(n=64, degree=1, seed=0):
    """Raw INRIA values whose positions are exact in 12 fractional bits and whose SH stay inside a byte's range,
    so that a file holding them turned by a signed permutation quantises them the same way."""
    ply = F.random_ply(N=n, degree=degree, seed=seed)
    ply.xyz = (np.rint(np.clip(ply.xyz, -50, 50) * 4096) / 4096).astype(np.float32)
    ply.f_rest = np.clip(ply.f_rest, -0.9, 0.9).astype(np.float32)
    return ply


def _write(path, ply, version, extensions=b"", flags=None):
    flags = (spz.FLAG_EXTENSIONS if extensions else 0) if flags is None else flags
    if version == 4:
        path.write_bytes(F.spz_v4(ply, flags=flags, extensions=extensions))
    else:
        path.write_bytes(gzip.compress(F.spz_body(ply, version, flags=flags, extensions=extensions)))
    return path


def _covariances(ply):
    R = cameras.quaternion_to_rotation(splats.unit_quaternions(ply.rot).astype(np.float64))
    return np.einsum("nij,nj,nkj->nik", R, np.exp(2 * ply.scale.astype(np.float64)), R)


def _assert_same_covariances(got, want, err_msg=""):
    """Per Gaussian, |ΔΣ| within 5 % of its largest variance: a smallest-three quaternion (9 bits of ±√½ per
    component) turns a Gaussian by up to ~0.01 rad, which moves Σ by about twice that share; a wrong frame moves
    it by the whole."""
    a, b = _covariances(got), _covariances(want)
    error = np.abs(a - b).max(axis=(1, 2)) / np.abs(b).max(axis=(1, 2))
    assert error.max() < 0.05, (err_msg, error.max())


def _stored_as(ply, M):
    """``ply`` (RUB) as a file declaring a system with p_RUB = M p stores it, as Niantic's packer converts it."""
    out = F.random_ply(N=len(ply), degree=ply.sh_degree)
    out.xyz = (ply.xyz.astype(np.float64) @ M).astype(np.float32)   # M orthogonal: p = Mᵀ p_RUB
    R = cameras.quaternion_to_rotation(splats.unit_quaternions(ply.rot).astype(np.float64))
    out.rot = cameras.rotation_to_quaternion(np.linalg.det(M) * M.T @ R).astype(np.float32)
    out.scale, out.opacity, out.f_dc = ply.scale, ply.opacity, ply.f_dc
    if ply.sh_degree:
        rest = sh_rotation(M.T, ply.sh_degree)[1:, 1:]
        out.f_rest = np.einsum("kj,ncj->nck", rest, ply.f_rest.astype(np.float64)).astype(np.float32)
    return out


@pytest.mark.parametrize("version", [2, 3, 4])
def test_extension_records_are_skipped_and_the_data_read(tmp_path, version):
    """Before: a version 2/3 stream with records after the attributes was refused as "its gzip stream holds more:
    the count or SH degree is wrong (damaged file)"."""
    ply = _cloud(degree=2)
    plain = splats_io.read(_write(tmp_path / "plain.spz", ply, version))
    got = splats_io.read(_write(tmp_path / "ext.spz", ply, version, ORBIT + UNKNOWN))
    for name in ("xyz", "rot", "scale", "opacity", "f_dc", "f_rest"):
        np.testing.assert_array_equal(getattr(got, name), getattr(plain, name), err_msg=name)


@pytest.mark.parametrize("version", [3, 4])
def test_a_z_up_declaration_reads_the_car_as_the_undeclared_file(tmp_path, version):
    """The field case: one car, 4.6 m long along RUB's -z (its front), 1.5 m high along +y, stored once without a
    declaration and once declaring RFU (x right, y front, z up: value 12) as Niantic's packer stores it,
    (x, y, z) -> (x, -z, y). Before, the second came back with its length along y: turned 90° about x."""
    ply = _cloud(n=200, degree=0, seed=3)
    ply.xyz = (np.rint(ply.xyz * np.array([1.8, 1.5, 4.6]) / 6 * 4096) / 4096).astype(np.float32)
    stored = _stored_as(ply, np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]))
    np.testing.assert_array_equal(stored.xyz, np.stack([ply.xyz[:, 0], -ply.xyz[:, 2], ply.xyz[:, 1]], 1))
    plain = splats_io.read(_write(tmp_path / "plain.spz", ply, version))
    got = splats_io.read(_write(tmp_path / "rfu.spz", stored, version, F.spz_coordinate_system(12)))
    np.testing.assert_array_equal(got.xyz, plain.xyz)
    _assert_same_covariances(got, plain)
    extent = got.xyz.max(0) - got.xyz.min(0)
    assert extent[2] > 2 * extent[1]   # the length where the undeclared file has it


def test_niantics_own_example_reads_back(tmp_path):
    """nianticlabs/spz tests/python/test_coordinate_system.py: (1, 2, 3) packed from RUB into RBD (value 14) is
    stored as (1, 3, -2); read back it is (1, 2, 3) again."""
    ply = _cloud(n=1, degree=0)
    ply.xyz = np.array([[1.0, 3.0, -2.0]], np.float32)
    got = splats_io.read(_write(tmp_path / "rbd.spz", ply, 4, F.spz_coordinate_system(14)))
    np.testing.assert_array_equal(got.xyz, [[1.0, 2.0, 3.0]])


@pytest.mark.parametrize("version", [3, 4])
def test_every_declared_system_reads_back_the_same_car(tmp_path, version):
    """All 16 systems, SH degree 3: positions exact, covariances and view-dependent colours within quantisation;
    UNSPECIFIED (0) and RUB (4) read unchanged."""
    ply = _cloud(n=100, degree=3, seed=5)
    plain = splats_io.read(_write(tmp_path / "plain.spz", ply, version))
    dirs = np.random.default_rng(1).normal(size=(len(ply), 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    want = splats.sh_to_rgb(splats.sh_coefficients(plain.f_dc, plain.f_rest), dirs, 3)
    for value in range(17):
        M = spz.system_matrix(spz.COORDINATE_SYSTEMS[value - 1]) if value else np.eye(3)
        assert np.allclose(np.abs(M).sum(0), 1) and np.allclose(M @ M.T, np.eye(3))  # a signed permutation
        path = _write(tmp_path / f"s{value}.spz", _stored_as(ply, M), version, F.spz_coordinate_system(value))
        got = splats_io.read(path)
        np.testing.assert_array_equal(got.xyz, plain.xyz, err_msg=str(value))
        _assert_same_covariances(got, plain, value)
        rgb = splats.sh_to_rgb(splats.sh_coefficients(got.f_dc, got.f_rest), dirs, 3)
        assert np.abs(rgb - want).max() < 0.1, (value, np.abs(rgb - want).max())  # SH bytes are 1/128 steps
        if value in (0, 4):
            np.testing.assert_array_equal(got.rot, plain.rot)


def test_niantics_loader_returns_what_we_read(tmp_path):
    """Version 4 files declaring each of the 16 systems (and none), read by Niantic's own loader (``@adobe/spz``
    with ``to = RUB``, installed with splat-transform) and by ours: the same positions, covariances and SH. (Its
    WebAssembly build drops version 3's trailing records — "byteLength … exceeds remaining stream bytes" — so
    version 3 is compared by the test above, against the undeclared file.)"""
    ply = _cloud(n=40, degree=3, seed=9)
    paths = [_write(tmp_path / f"s{v}.spz", ply, 4, F.spz_coordinate_system(v) + ORBIT) for v in range(17)]
    theirs = splat_transform.niantic_load(paths)
    for value, path in enumerate(paths):
        got, ref = splats_io.read(path), theirs[str(path)]
        n = ref["numPoints"]
        assert n == len(got) and ref["extensions"] == 2
        np.testing.assert_array_equal(got.xyz, np.reshape(ref["positions"], (n, 3)), err_msg=str(value))
        mine = _covariances(got)
        ref_ply = F.random_ply(N=n, degree=0)
        ref_ply.rot = np.reshape(ref["rotations"], (n, 4))[:, [3, 0, 1, 2]].astype(np.float32)
        ref_ply.scale = np.reshape(ref["scales"], (n, 3)).astype(np.float32)
        np.testing.assert_allclose(mine, _covariances(ref_ply), atol=1e-5 * mine.max(), err_msg=str(value))
        np.testing.assert_allclose(np.swapaxes(got.f_rest, 1, 2), np.reshape(ref["sh"], (n, 15, 3)), atol=1e-5,
                                   err_msg=str(value))


@pytest.mark.parametrize("version", [3, 4])
def test_damaged_extension_records_are_refused_by_name(tmp_path, version):
    ply = _cloud(n=10, degree=0)
    cases = {"overrun.spz": (F.spz_coordinate_system(12)[:4] + np.uint32(99).tobytes() + bytes(4),
                             r"record 0xADBE0003 .* claims 99 bytes, 4 remain: damaged file"),
             "cut.spz": (ORBIT + b"\x01\x02\x03", r"cut after 3 of its 8 header bytes"),
             "value.spz": (F.spz_coordinate_system(17), r"SPZ_ADOBE_coordinate_system record .* holds value 17, not "
                                                        r"one uint32 of 0-16"),
             "short.spz": (F.spz_extension(0xADBE0003, b"\x0c\x00"), r"holds 2 bytes, not one uint32")}
    for name, (records, message) in cases.items():
        with pytest.raises(splats.SplatsError, match=name.replace(".", r"\.") + ": .*" + message) as e:
            splats_io.read(_write(tmp_path / name, ply, version, records))
        assert e.value.field == "extensions"


def test_records_without_the_flag_are_still_damage(tmp_path):
    """Bytes after the attributes of a stream whose header does not flag extensions mean a wrong count or SH
    degree, as before; the message says when records may follow."""
    ply = _cloud(n=10, degree=0)
    with pytest.raises(splats.SplatsError, match=r"holds more: the count or SH degree is wrong .*flags") as e:
        splats_io.read(_write(tmp_path / "noflag.spz", ply, 3, ORBIT, flags=0))
    assert e.value.field == "count"


def test_a_stream_of_records_beyond_the_bound_is_refused(tmp_path):
    ply = _cloud(n=10, degree=0)
    big = F.spz_extension(0x12340002, bytes(spz.MAX_EXTENSION_BYTES))
    with pytest.raises(splats.SplatsError, match=r"extension records after the attributes are 65,537 bytes, more "
                                                 r"than the 65,536 read"):
        splats_io.read(_write(tmp_path / "big.spz", ply, 3, big))
