"""core.splats.ksplat: GaussianSplats3D .ksplat files written here from the format's description (mkkellogg/
GaussianSplats3D ``src/loaders/SplatBuffer.js``: levels 0, 1 and 2, several sections, full and partial buckets,
spare slots) read back within each level's quantisation, and read by the real reader, splat-transform (which reads
.ksplat but does not write it), to the same values: our file converted by it to .ply and read with our PLY reader
equals our read of the file. A .ksplat saved as .splat is read as a .ksplat; a damaged one is refused."""

import numpy as np
import pytest

from tests.core.splats import splat_fixtures as F
import splat_transform
from scpainter_blender.core.splats import gaussians as splats, ksplat, reader as splats_io
from scpainter_blender.core.splats.sh import SH_C0

# Bounds (each the level's quantisation plus float32 rounding):
#: level 0 stores float32 positions, σ, rotations, SH: only the log of exp(log σ) in float32 differs.
F32_BOUND = 1e-5
#: colour and alpha are bytes at every level: half a step, in f_dc units (1/255/2/SH_C0) and after the sigmoid.
DC_BOUND = 0.5 / 255 / SH_C0 + 1e-6
OPACITY_BOUND = 0.5 / 255 + 1e-6
#: levels 1-2: σ and rotation as half floats: relative error 2^-11 (so log σ within 2^-11 / (1 - 2^-11)); a unit
#: quaternion's components within 2^-12 absolute (|q| <= 1, spacing of halves below 1 is at most 2^-11).
HALF_LOG_BOUND = 2.0 ** -11 * 1.001
HALF_QUAT_BOUND = 2.0 ** -12 + 1e-6
#: level 2 SH: a byte over [-1.5, 1.5] (SplatBuffer's default range): half a step 3/255/2.
SH_BYTE_BOUND = 3.0 / 255 / 2 + 1e-6
#: our read against splat-transform's read of the same file (both decode in double and store float32; the PLY
#: splat-transform writes holds those float32 values): equal to float32 rounding.
SAME_READ_BOUND = 1e-5


def source(degree, n=1000, seed=0):
    src = F.random_ply(N=n, degree=degree, seed=seed)
    src.scale = np.clip(src.scale, -7, 1)    # within half floats' normal range (σ > 6e-5)
    src.f_rest = np.clip(src.f_rest, -1.5, 1.5)
    return src


def assert_close(got, src, level):
    q = splats.unit_quaternions(src.rot)
    assert got.format == "ksplat" and len(got) == len(src) and got.sh_degree == src.sh_degree
    o = lambda p: splats.opacities_from_logits(p.opacity)  # noqa: E731
    assert np.abs(o(got) - o(src)).max() <= OPACITY_BOUND
    lo, hi = -0.5 / SH_C0, 0.5 / SH_C0
    assert np.abs(got.f_dc - np.clip(src.f_dc, lo, hi)).max() <= DC_BOUND
    if level == 0:
        assert np.abs(got.xyz - src.xyz).max() <= F32_BOUND
        assert np.abs(got.scale - src.scale).max() <= F32_BOUND
        assert np.abs(got.rot - q).max() <= F32_BOUND
        assert np.abs(got.f_rest - src.f_rest).max(initial=0.0) <= F32_BOUND
        return
    assert np.abs(got.scale - src.scale).max() <= HALF_LOG_BOUND
    assert np.abs(got.rot - q).max() <= HALF_QUAT_BOUND
    if src.sh_degree:
        bound = SH_BYTE_BOUND if level == 2 else 1.5 * 2.0 ** -11
        assert np.abs(got.f_rest - src.f_rest).max() <= bound


@pytest.mark.parametrize("level", [0, 1, 2])
@pytest.mark.parametrize("degree", [0, 1, 2])
def test_written_ksplat_reads_back_within_quantisation(tmp_path, level, degree):
    src = source(degree, seed=level * 3 + degree)
    F.write_ksplat(tmp_path / "car.ksplat", src, level)
    got = splats_io.read(tmp_path / "car.ksplat")
    assert_close(got, src, level)
    if level:  # positions: half a step of the block, block / 2 / 32767 / 2, plus the float32 centre
        data = (tmp_path / "car.ksplat").read_bytes()
        blocks = [np.frombuffer(data, "<f4", 1, ksplat.MAIN_HEADER + i * ksplat.SECTION_HEADER + 16)[0]
                  for i in range(2)]
        assert np.abs(got.xyz - src.xyz).max() <= max(blocks) / 2 / 32767 / 2 + 1e-5


@pytest.mark.parametrize("level", [0, 1, 2])
def test_splat_transform_reads_our_ksplat_to_the_same_values(tmp_path, level):
    src = source(2, n=600, seed=40 + level)
    F.write_ksplat(tmp_path / "car.ksplat", src, level)
    ours = splats_io.read(tmp_path / "car.ksplat")
    theirs = splats_io.read(splat_transform.convert(tmp_path / "car.ksplat", tmp_path / "car.ply"))
    assert len(theirs) == len(ours) and theirs.sh_degree == 2
    for name in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot"):
        assert np.abs(getattr(theirs, name) - getattr(ours, name)).max() <= SAME_READ_BOUND, name


def test_ksplat_saved_as_splat_is_read_as_ksplat(tmp_path):
    """GaussianSplats3D's files were once named .splat: read as .splat they were a few garbage Gaussians."""
    src = source(1, n=300, seed=7)
    F.write_ksplat(tmp_path / "old.splat", src, 1)
    assert splats_io.detect(tmp_path / "old.splat") == "ksplat"
    assert_close(splats_io.read(tmp_path / "old.splat"), src, 1)
    # its header damaged (the Gaussian count no longer matches the sections): no .ksplat, and as 32-byte .splat
    # records it is mostly invalid: refused, saying what it probably is
    data = bytearray((tmp_path / "old.splat").read_bytes())
    data[16:20] = (10 ** 6).to_bytes(4, "little")
    (tmp_path / "broken.splat").write_bytes(bytes(data[:len(data) // 32 * 32]))
    with pytest.raises(splats.SplatsError, match=r"broken\.splat: .* of its .* 32-byte records are no valid "
                                                 r"Gaussians .*more than 50%.*\.ksplat header"):
        splats_io.read(tmp_path / "broken.splat")
    (tmp_path / "broken.ksplat").write_bytes(bytes(data))
    with pytest.raises(splats.SplatsError, match=r"broken\.ksplat: not a GaussianSplats3D \.ksplat file: the "
                                                 r"sections hold 300 Gaussians, the main header says 1,000,000"):
        splats_io.read(tmp_path / "broken.ksplat")


def test_ksplat_with_impossible_buckets_or_cut_short_is_refused(tmp_path):
    """Fuzz findings (tests/fuzz_splat_formats.py, issue 31): full buckets of a capacity beyond the section's
    Gaussians put every Gaussian in the first bucket (accepted, positions wrong); a file cut inside its main header
    was called "not that format"."""
    src = source(1, n=40)
    F.write_ksplat(tmp_path / "car.ksplat", src, 1, capacity=4, partial=(4, 3))
    data = bytearray((tmp_path / "car.ksplat").read_bytes())
    data[ksplat.MAIN_HEADER + 8:ksplat.MAIN_HEADER + 12] = (10 ** 9).to_bytes(4, "little")  # bucket capacity
    (tmp_path / "cap.ksplat").write_bytes(bytes(data))
    with pytest.raises(splats.SplatsError, match=r"cap\.ksplat: a section's buckets are inconsistent") as e:
        splats_io.read(tmp_path / "cap.ksplat")
    assert e.value.field == "section"
    (tmp_path / "cut.ksplat").write_bytes(bytes(data[:1000]))
    with pytest.raises(splats.SplatsError, match=r"cut\.ksplat: not a GaussianSplats3D \.ksplat file: shorter than "
                                                 r"the 4096-byte main header: truncated"):
        splats_io.read(tmp_path / "cut.ksplat")
