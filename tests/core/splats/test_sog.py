"""core.splats.sog (PlayCanvas SOG): the formulas on hand-made texels, files broken on purpose, and the real writer
(splat-transform 3.7.0, tests/splat_transform.py) on the real PLYs: read back as splat-transform itself decodes them,
and within SOG's quantisation of the source."""

import json
import math
import os
import zipfile

import numpy as np
import pytest

import sog_fixtures as S
from backend import webp as backend_webp
import splat_transform
from tests_support import realdata
from scpainter_blender.core.splats import gaussians as splats, reader as splats_io, sog, webp
from scpainter_blender.core.splats.gaussians import SplatsError
from scpainter_blender.core.splats.sh import SH_C0

REAL = ["3dgs/loadersgl_train-1000.ply", "3dgs/supersplat_fruit_drops_minimal.ply", "3dgs/gshairlod_donut_fused.ply"]

# Error bounds against the source PLY, measured on the three real files above (splat-transform 3.7.0, -g cpu):
#: positions: the writer truncates u = 65535 (t - min) / (max - min) to 16 bits, t = sign(x) ln(|x| + 1): at most one
#: step of the log-transformed range per axis; measured 1.033 steps (the rest is float32 rounding of x).
POSITION_STEPS = 1.05
#: opacity: stored as trunc(255 sigmoid(logit)), so less than 1/255 below; measured 0.0039214 (< 1/255 = 0.0039216).
OPACITY_ERROR = 1 / 255 + 1e-6
#: rotations: three components truncated to 8 bits of [-1/√2, 1/√2]; measured at most 1.74° between the unit
#: quaternions (2 arccos |q·q'|).
ROTATION_DEGREES = 2.0
#: scales and DC colours go through 256-entry codebooks, and the writer picks the nearest entry: the value read is
#: the codebook entry nearest the source's, within float32 rounding of the codebook.
CODEBOOK_ROUNDING = 1e-6
#: measured: log-scale error at most 0.040 (4 % in σ); DC colour (C0 f_dc) at most 0.034, at the sparse tail of the
#: donut's f_dc (up to 14.9), 0.005 on the others.
LOG_SCALE_ERROR, DC_COLOUR_ERROR = 0.05, 0.04
#: SH degree 1-3 through a k-means palette (lossy): measured RMS error of f_rest 0.0048 and 0.0078 (the two files
#: with SH 3; |f_rest| up to 0.44 and 0.15).
F_REST_RMS = 0.01
#: splat-transform's own decode (`splat-transform X.sog X.ply`) and ours: the same formulas in float64 rounded to
#: float32; measured bit-identical.
SAME_DECODE = dict(rtol=1e-6, atol=1e-7)


def _read(path):
    return sog.read(path, backend_webp.decode)


# -- the formulas ---------------------------------------------------------------------------------------------------

def test_values_follow_the_format_on_hand_made_texels():
    """Every field decoded from chosen bytes by the spec's formulas (module docstring), computed here per Gaussian
    with scalar math."""
    meta, images = S.tiny(n=10, bands=2)
    meta = sog.parse_meta(json.dumps(meta).encode(), "x.sog")
    ply = sog.from_images(meta, images, "x.sog")
    assert ply.format == "sog" and len(ply) == 10 and ply.sh_degree == 2 and ply.f_rest.shape == (10, 3, 8)
    px = {k: v.reshape(-1, 4) for k, v in images.items()}
    for i in range(10):
        for a in range(3):
            u = int(px["means_l.webp"][i, a]) + 256 * int(px["means_u.webp"][i, a])
            lo, hi = meta["means"]["mins"][a], meta["means"]["maxs"][a]
            t = lo + ((hi - lo) or 1.0) * u / 65535
            assert ply.xyz[i, a] == pytest.approx(math.copysign(math.exp(abs(t)) - 1, t), rel=1e-6, abs=1e-7)
            assert ply.scale[i, a] == np.float32(meta["scales"]["codebook"][px["scales.webp"][i, a]])
            assert ply.f_dc[i, a] == np.float32(meta["sh0"]["codebook"][px["sh0.webp"][i, a]])
        r, g, b, tag = (int(v) for v in px["quats.webp"][i])
        largest = tag - 252
        others = [j for j in range(4) if j != largest]
        q = [0.0] * 4
        for j, byte in zip(others, (r, g, b)):
            q[j] = (byte / 255 * 2 - 1) / math.sqrt(2)
        q[largest] = math.sqrt(max(0.0, 1 - sum(v * v for v in q)))
        np.testing.assert_allclose(ply.rot[i], q, atol=1e-7)
        alpha = min(max(px["sh0.webp"][i, 3] / 255, 1e-6), 1 - 1e-6)
        assert ply.opacity[i] == pytest.approx(math.log(alpha / (1 - alpha)), rel=1e-6)
        label = int(px["shN_labels.webp"][i, 0]) + 256 * int(px["shN_labels.webp"][i, 1])
        for j in range(8):
            texel = images["shN_centroids.webp"][label // 64, (label % 64) * 8 + j]
            for c in range(3):
                assert ply.f_rest[i, c, j] == np.float32(meta["shN"]["codebook"][texel[c]])
    assert sog.parse_meta(json.dumps({**meta, "shN": {"bands": 0}}).encode(), "x")["count"] == 10  # no higher SH


def test_bundle_and_folder_read_the_same_and_the_reader_dispatches(tmp_path):
    meta, images = S.tiny(n=13, bands=3, side=4)
    bundle = S.write_bundle(tmp_path / "car.sog", meta, images)
    folder = S.write_folder(tmp_path / "car", meta, images)
    a, b = _read(bundle), _read(folder)
    want = sog.from_images(sog.parse_meta(json.dumps(meta).encode(), "x"), images, "x")
    for k in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot"):
        assert np.array_equal(getattr(a, k), getattr(want, k)) and np.array_equal(getattr(b, k), getattr(want, k))
    os.rename(bundle, tmp_path / "renamed.zip")  # a bundle is known by its content
    assert len(splats_io.read(tmp_path / "renamed.zip")) == 13  # (the process's decoder: the backend's, imported)
    assert splats_io.read(folder).format == "sog" and len(splats_io.load(folder)) == 13
    zipped = tmp_path / "nested.sog"  # a folder zipped whole: meta.json one level down
    with zipfile.ZipFile(zipped, "w") as z:
        for name in os.listdir(tmp_path / "car"):
            z.write(tmp_path / "car" / name, f"car/{name}")
    assert np.array_equal(_read(zipped).xyz, want.xyz)


def test_webp_header_sizes_and_kinds():
    data = S.encode_webp(np.zeros((3, 7, 4), np.uint8) + 9)
    assert webp.header(data) == (7, 3, "lossless")
    with pytest.raises(ValueError, match="not a WebP"):
        webp.header(b"\x89PNG\r\n\x1a\n" + bytes(40))


# -- hostile and broken files -----------------------------------------------------------------------------------------

def _error(path, match):
    with pytest.raises(SplatsError, match=match) as e:
        _read(path)
    return e.value


def test_meta_json_that_lies_is_refused_naming_the_field_or_image(tmp_path):
    meta, images = S.tiny(n=10)
    cases = {
        "count": ({**meta, "count": 17}, "means_l.webp is 4 x 4 = 16 texels, fewer than meta.json's count 17"),
        "neg": ({**meta, "count": -1}, r"meta.json: count is -1, expected an integer"),
        "book": ({**meta, "scales": {**meta["scales"], "codebook": [0.1] * 300}}, r"scales.codebook is .*1 to 256"),
        "nan": (None, "NaN is not a JSON number"),
        "v1": ({k: v for k, v in meta.items() if k != "version"}, "version 1"),
        "v3": ({**meta, "version": 3}, "version 3 is not read"),
        "path": ({**meta, "quats": {"files": ["../quats.webp"]}}, r"quats.files is .*no path separators"),
        "lod": ({"version": 1, "lodLevels": 2, "tree": {}}, "streamed SOG"),
        "mins": ({**meta, "means": {**meta["means"], "mins": [0, 0]}}, r"means.mins is \[0, 0\], expected a list of 3"),
    }
    for name, (bad, match) in cases.items():
        raw = json.dumps(meta).replace("-2.0", "NaN").encode() if bad is None else None
        path = S.write_bundle(tmp_path / f"{name}.sog", bad, images, raw=raw)
        err = _error(path, match)
        assert err.path == path and ("meta.json" in err.field or err.field.endswith(".webp")), (name, err.field)
    small = dict(images, **{"sh0.webp": images["sh0.webp"][:2]})  # an image smaller than the others, and than count
    err = _error(S.write_bundle(tmp_path / "small.sog", meta, small), "sh0.webp is 4 x 2 = 8 texels")
    assert err.field == "sh0.webp"


def test_missing_entries_and_bad_images_are_named(tmp_path):
    meta, images = S.tiny(n=10)
    err = _error(S.write_bundle(tmp_path / "a.sog", meta, images, leave_out=["quats.webp"]),
                 "the bundle has no entry 'quats.webp', which meta.json names")
    assert err.field == "quats.webp"
    folder = S.write_folder(tmp_path / "f", meta, images)
    os.remove(tmp_path / "f" / "scales.webp")
    assert _error(folder, "file not found").path.endswith("scales.webp")
    bad_tag = dict(images)
    bad_tag["quats.webp"] = images["quats.webp"].copy()
    bad_tag["quats.webp"][0, 0, 3] = 7
    _error(S.write_bundle(tmp_path / "q.sog", meta, bad_tag), "quats.webp: 1 of 10 texels have an alpha outside")
    meta1, images1 = S.tiny(n=10, bands=1)
    labels = images1["shN_labels.webp"].copy()
    labels[0, 0, :2] = (200, 1)  # label 456, past the 70 entries
    _error(S.write_bundle(tmp_path / "l.sog", meta1, dict(images1, **{"shN_labels.webp": labels})),
           "shN_labels.webp: 1 labels are past the palette of shN.count = 70")
    import cv2

    with zipfile.ZipFile(tmp_path / "lossy.sog", "w") as z:
        for name, im in images.items():
            data = S.encode_webp(im) if name != "sh0.webp" else cv2.imencode(
                ".webp", im[:, :, [2, 1, 0, 3]], [cv2.IMWRITE_WEBP_QUALITY, 90])[1].tobytes()
            z.writestr(name, data)
        z.writestr("meta.json", json.dumps(meta))
    assert _error(str(tmp_path / "lossy.sog"), "sh0.webp is a lossy WebP").field == "sh0.webp"
    with zipfile.ZipFile(tmp_path / "junk.sog", "w") as z:
        for name, im in images.items():
            z.writestr(name, b"RIFF" if name == "means_u.webp" else S.encode_webp(im))
        z.writestr("meta.json", json.dumps(meta))
    _error(str(tmp_path / "junk.sog"), "means_u.webp: not a WebP image")


def test_not_a_bundle_and_no_decoder(tmp_path):
    with zipfile.ZipFile(tmp_path / "other.zip", "w") as z:
        z.writestr("readme.txt", "hi")
    _error(str(tmp_path / "other.zip"), r"a zip archive without meta.json at its root: not a SOG bundle \(entries: "
                                        r"readme.txt\)")
    (tmp_path / "fake.sog").write_bytes(b"\x00" * 64)
    with pytest.raises(SplatsError, match="named .sog but its content is not that format"):
        splats_io.read(tmp_path / "fake.sog")
    (tmp_path / "cut.sog").write_bytes(b"PK\x03\x04" + b"\x00" * 40)
    _error(str(tmp_path / "cut.sog"), "not a readable SOG bundle")
    meta, images = S.tiny(n=4)
    path = S.write_bundle(tmp_path / "ok.sog", meta, images)
    saved = webp.decoder()
    webp.set_decoder(None)  # as in Blender: no WebP decoder in this Python
    try:
        with pytest.raises(SplatsError, match="WebP, which this Python cannot decode") as e:
            splats_io.read(path)
        assert "python -m backend splat-asset" in e.value.hint
    finally:
        webp.set_decoder(saved)


# -- the real writer ---------------------------------------------------------------------------------------------------

def _convert(src, dst):
    return splat_transform.convert(src, dst)


@pytest.fixture(scope="module")
def real_sogs(tmp_path_factory):
    """{source PLY: (bundle, splat-transform's decode of it as a PLY)} and one unbundled SOG with its decode."""
    out = {}
    folder = tmp_path_factory.mktemp("sog")
    for rel in REAL:
        src = realdata(rel)
        stem = os.path.splitext(os.path.basename(src))[0]
        bundle = _convert(src, folder / f"{stem}.sog")
        out[src] = (bundle, _convert(bundle, folder / f"{stem}.back.ply"))
    src = realdata(REAL[0])
    meta = _convert(src, folder / "unbundled" / "meta.json")
    out["unbundled"] = (src, meta, _convert(meta, folder / "unbundled.back.ply"))
    return out


def _same(a, b):
    assert len(a) == len(b) and a.sh_degree == b.sh_degree
    for k in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot"):
        np.testing.assert_allclose(getattr(a, k), getattr(b, k), **SAME_DECODE, err_msg=k)


def test_real_writer_reads_back_as_splat_transform_decodes_it(real_sogs):
    for src, (bundle, back) in ((s, v) for s, v in real_sogs.items() if s != "unbundled"):
        ours = _read(bundle)
        assert ours.format == "sog" and len(ours) == len(splats_io.read(src))
        _same(ours, splats_io.read(back))
    _, meta, back = real_sogs["unbundled"]
    assert splats_io.read(meta).format == "sog"
    _same(_read(meta), splats_io.read(back))


def test_writer_on_a_generated_ply_reads_back_as_splat_transform_decodes_it(tmp_path):
    """The same check from a generated PLY (SH degree 3), so the real writer is tested without ../shared/realdata."""
    from tests.core.splats import splat_fixtures as F

    bundle = _convert(F.source_ply(F.GENERATED, tmp_path), tmp_path / "generated.sog")
    ours = _read(bundle)
    assert ours.format == "sog" and len(ours) == 500 and ours.sh_degree == 3
    _same(ours, splats_io.read(_convert(bundle, tmp_path / "generated.back.ply")))


def _log(x):
    """The writer's position transform t = sign(x) ln(|x| + 1)."""
    return np.sign(x) * np.log1p(np.abs(x.astype(np.float64)))


def _match(src, got, step):
    """Index of each row of ``got`` (the writer's Morton order) in ``src``: among the 16 nearest source positions
    within ``POSITION_STEPS`` steps of the log-transformed range (``step`` per axis), the one closest in scale and
    opacity (not colour: a transparent texel's is not kept)."""
    from scipy.spatial import cKDTree

    _, cand = cKDTree(src.xyz.astype(np.float64)).query(got.xyz.astype(np.float64), k=min(16, len(src)))
    within = (np.abs(_log(src.xyz[cand]) - _log(got.xyz)[:, None]) <= POSITION_STEPS * step).all(-1)
    assert within.any(1).all()  # every row has a source Gaussian within the position bound
    cost = np.abs(src.scale[cand] - got.scale[:, None]).sum(-1) + np.abs(src.opacity[cand] - got.opacity[:, None])
    cost[~within] = np.inf
    idx = cand[np.arange(len(got)), cost.argmin(1)]
    assert len(np.unique(idx)) == len(got)  # a permutation
    return idx


def _nearest_entry_error(values, codebook):
    book = np.asarray(codebook, np.float32)
    return np.abs(values[..., None] - book).min(-1)


@pytest.mark.parametrize("rel", REAL)
def test_real_writer_within_its_quantisation_of_the_source(real_sogs, rel):
    src_path = realdata(rel)
    bundle, _ = real_sogs[src_path]
    src, got = splats_io.read(src_path), _read(bundle)
    with zipfile.ZipFile(bundle) as z:
        meta = json.loads(z.read("meta.json"))
    s = src
    step = (np.array(meta["means"]["maxs"]) - meta["means"]["mins"]) / 65535
    idx = _match(src, got, step)  # (every row's position within POSITION_STEPS of its source's)
    o_src, o_got = splats.opacities_from_logits(s.opacity[idx]), splats.opacities_from_logits(got.opacity)
    assert np.abs(o_src - o_got).max() <= OPACITY_ERROR
    dot = np.abs(np.sum(splats.unit_quaternions(s.rot[idx]) * splats.unit_quaternions(got.rot), 1))
    assert np.degrees(2 * np.arccos(np.minimum(dot, 1.0))).max() <= ROTATION_DEGREES
    scale_err = np.abs(s.scale[idx] - got.scale)
    assert (scale_err <= _nearest_entry_error(s.scale[idx], meta["scales"]["codebook"]) + CODEBOOK_ROUNDING).all()
    assert scale_err.max() <= LOG_SCALE_ERROR
    # the writer's lossless WebP drops the colour of fully transparent texels (alpha byte 0: opacity below 1/255,
    # which the renderer never draws): colours are compared where the alpha byte is not 0
    seen = o_got > 2e-6
    dc_err = np.abs(s.f_dc[idx] - got.f_dc)[seen]
    assert (dc_err <= _nearest_entry_error(s.f_dc[idx][seen], meta["sh0"]["codebook"]) + CODEBOOK_ROUNDING).all()
    assert SH_C0 * dc_err.max() <= DC_COLOUR_ERROR
    assert got.sh_degree == s.sh_degree
    if s.sh_degree:
        assert np.sqrt(np.mean((s.f_rest[idx] - got.f_rest) ** 2)) <= F_REST_RMS
