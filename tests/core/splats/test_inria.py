"""core.splats.inria: the INRIA layout written and read back bit-exact (both byte orders, SH 0-3, extras), missing
and misnumbered properties named, half floats in ushort slots, integer Gaussian properties refused."""

import numpy as np
import pytest

from tests.core.splats import splat_fixtures as F
from scpainter_blender.core.splats import gaussians as splats, inria as splats_inria, reader as splats_io


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("order", ["<", ">"])
def test_write_read_round_trip_bit_exact(tmp_path, degree, order):
    ply = F.random_ply(degree=degree, seed=degree)
    ply.xyz[3, 1] = np.nan  # bad values survive the raw round trip too
    p = tmp_path / "g.ply"
    splats_inria.write_ply(p, ply, byte_order=order)
    back = splats_io.read_ply(p)
    assert back.sh_degree == degree
    F.assert_raw_equal(ply, back)
    splats_inria.write_ply(tmp_path / "again.ply", back, byte_order=order)
    assert (tmp_path / "again.ply").read_bytes() == p.read_bytes()
    assert not list(tmp_path.glob("*.tmp"))


def test_big_and_little_endian_decode_the_same(tmp_path):
    ply = F.random_ply(degree=3)
    splats_inria.write_ply(tmp_path / "le.ply", ply, "<")
    splats_inria.write_ply(tmp_path / "be.ply", ply, ">")
    a, b = splats_io.load(tmp_path / "le.ply"), splats_io.load(tmp_path / "be.ply")
    assert np.array_equal(a.means, b.means) and np.array_equal(a.sh, b.sh)


def test_one_gaussian_and_empty(tmp_path):
    one = F.random_ply(N=1, degree=3, extras=False)
    splats_inria.write_ply(tmp_path / "one.ply", one)
    assert len(splats_io.load(tmp_path / "one.ply")) == 1
    empty = F.random_ply(N=0, degree=0, extras=False)
    splats_inria.write_ply(tmp_path / "empty.ply", empty)
    g = splats_io.load(tmp_path / "empty.ply")
    assert len(g) == 0 and g.sh.shape == (0, 1, 3)


def test_missing_and_bad_properties_are_named(tmp_path):
    ply = F.random_ply(degree=0, extras=False)
    splats_inria.write_ply(tmp_path / "ok.ply", ply)
    text = (tmp_path / "ok.ply").read_bytes()
    head, body = text.split(b"end_header\n", 1)
    # drop 'opacity' and 'rot_2' from the header (and their bytes, so the file is otherwise consistent)
    cut = head.replace(b"property float opacity\n", b"").replace(b"property float rot_2\n", b"")
    (tmp_path / "missing.ply").write_bytes(cut + b"end_header\n" + body)
    with pytest.raises(splats.SplatsError, match=r"missing.ply.*missing required properties \['opacity', 'rot_2'\]"):
        splats_io.read_ply(tmp_path / "missing.ply")
    bad_rest = head.replace(b"property float opacity\n", b"property float f_rest_0\nproperty float opacity\n")
    (tmp_path / "rest.ply").write_bytes(bad_rest + b"end_header\n" + body + b"\0" * 4 * 50)
    with pytest.raises(splats.SplatsError, match="1 f_rest properties"):
        splats_io.read_ply(tmp_path / "rest.ply")
    ascii_ = head.replace(b"binary_little_endian", b"ascii")
    (tmp_path / "ascii.ply").write_bytes(ascii_ + b"end_header\n" + body)
    with pytest.raises(splats.SplatsError, match="'ascii' is not supported"):
        splats_io.read_ply(tmp_path / "ascii.ply")
    (tmp_path / "short.ply").write_bytes(text[: len(text) - 7])
    with pytest.raises(splats.SplatsError, match="truncated.*50 Gaussians"):
        splats_io.read_ply(tmp_path / "short.ply")
    with pytest.raises(splats.SplatsError, match="not found"):
        splats_io.read_ply(tmp_path / "nope.ply")


def test_extra_properties_are_ignored(tmp_path):
    ply = F.random_ply(degree=1)
    splats_inria.write_ply(tmp_path / "x.ply", ply)
    g = splats_io.load(tmp_path / "x.ply")
    plain = splats.decode(splats.GaussianPly(ply.xyz, ply.f_dc, ply.f_rest, ply.opacity, ply.scale, ply.rot))
    assert np.array_equal(g.means, plain.means) and np.array_equal(g.sh, plain.sh)


def test_comment_written_by_write_ply_is_one_safe_line(tmp_path):
    ply = F.random_ply(N=5, extras=False)
    splats_inria.write_ply(tmp_path / "c.ply", ply, comment="from end_header.glb\nelement vertex 99\r\ncafé")
    head = (tmp_path / "c.ply").read_bytes().split(b"\nend_header\n")[0].decode("ascii")
    assert "comment from end_header.glb?element vertex 99??caf?" in head.splitlines()
    F.assert_raw_equal(ply, splats_io.read_ply(tmp_path / "c.ply"))


# -- property types: half floats and integers ----------------------------------------------------------------------

@pytest.mark.parametrize("order", ["<", ">"])
def test_half_float_ply(tmp_path, order):
    """Every Gaussian property in ushort slots: the bits are IEEE half floats in the file's byte order."""
    src = F.random_ply(N=60, degree=1, extras=False)
    half = {k: getattr(src, k).astype(np.float16) for k in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot")}
    src16 = splats.GaussianPly(**half)
    cols = F.inria_columns(src16, "ushort", cast=lambda v: v.view(np.uint16))
    cols.insert(3, ("label", "ushort", np.arange(60, dtype=np.uint16)))  # an extra keeps its own type
    F.write_typed_ply(tmp_path / "h.ply", cols, byte_order=order)
    ply = splats_io.read(tmp_path / "h.ply")
    assert ply.format == "inria_half"
    for k in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot"):
        assert np.array_equal(getattr(ply, k), half[k].astype(np.float32)), k
    assert ply.extra["label"].dtype == np.uint16 and np.array_equal(ply.extra["label"], np.arange(60))
    g = splats_io.load(tmp_path / "h.ply")
    assert len(g) == 60 and np.allclose(g.scales, np.exp(half["scale"].astype(np.float64)), rtol=1e-6)


def test_integer_gaussian_properties_are_refused_by_name(tmp_path):
    src = F.random_ply(N=20, degree=0, extras=False)
    cols = F.inria_columns(src, "float")
    mixed = [(n, "ushort", np.float16(v).view(np.uint16)) if n.startswith("scale_") else (n, t, v)
             for n, t, v in cols]
    F.write_typed_ply(tmp_path / "mixed.ply", mixed)
    with pytest.raises(splats.SplatsError, match=r"mixed\.ply: property 'scale_0' \(and 2 more\) is stored as "
                                                 r"ushort \(uint16\).*re-export the file as float32") as e:
        splats_io.load(tmp_path / "mixed.ply")
    assert "scale_overflow" not in str(e.value)
    as_bytes = [(n, "uchar", np.zeros(20, np.uint8)) for n, _, _ in cols]
    F.write_typed_ply(tmp_path / "bytes.ply", as_bytes)
    with pytest.raises(splats.SplatsError, match=r"property 'x' \(and 13 more\) is stored as uchar \(uint8\).*float32"):
        splats_io.read(tmp_path / "bytes.ply")
    ints = [(n, "int", np.ones(20, np.int32)) if n == "opacity" else (n, t, v) for n, t, v in cols]
    F.write_typed_ply(tmp_path / "int.ply", ints)
    with pytest.raises(splats.SplatsError, match=r"property 'opacity' is stored as int \(int32\)"):
        splats_io.read(tmp_path / "int.ply")
    doubles = [(n, "double", v) for n, t, v in cols]
    F.write_typed_ply(tmp_path / "double.ply", doubles)
    ply = splats_io.read(tmp_path / "double.ply")
    assert ply.format == "inria" and np.array_equal(ply.xyz, src.xyz)
