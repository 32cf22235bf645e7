"""core.vggt.crop: VGGT's white pad borders found and cut like the unpadded file, explicit crops, bad crops."""

import numpy as np
import pytest

from scpainter_blender.core.geometry import point_cloud
from scpainter_blender.core.vggt import predictions as vggt, crop as vggt_crop, npz as vggt_io
from vggt_cases import drive, pad, write


@pytest.mark.parametrize("top,bottom", [(4, 4), (3, 4)])
def test_padded_file_cropped_like_the_original(tmp_path, top, bottom):
    arrays, _, _ = drive(H=32 - top - bottom, W=32)
    orig = vggt_io.load_predictions(write(tmp_path, arrays, "orig.npz"))
    padded = write(tmp_path, pad(arrays, top, bottom))
    uncropped = vggt_io.load_predictions(padded)
    assert (uncropped.width, uncropped.height) == (32, 32)
    auto = vggt_io.load_predictions(padded, crop="auto", extrinsic_convention="auto")
    explicit = vggt_io.load_predictions(padded, crop=f"0 {top} 0 {bottom}")
    as_list = vggt_io.load_predictions(padded, crop=[0, top, 0, bottom])
    assert auto.report.crop == explicit.report.crop == (0, top, 0, bottom)
    assert auto.report.crop_requested == "auto" and explicit.report.crop_requested == "explicit"
    assert f"cropped left 0, top {top}, right 0, bottom {bottom} px (VGGT's white padding detected): " \
           f"32 x 32 -> 32 x {32 - top - bottom}" in auto.report.info[0]
    assert auto.report.original_size == (32, 32)
    ref = point_cloud.point_cloud(orig, 50.0)
    for pred in (auto, explicit, as_list):
        assert (pred.width, pred.height) == (orig.width, orig.height)
        assert np.array_equal(pred.K, orig.K) and np.array_equal(pred.images, orig.images)
        pts = point_cloud.point_cloud(pred, 50.0)
        assert np.array_equal(pts.positions, ref.positions) and np.array_equal(pts.frame, ref.frame)
    # not padded: auto finds nothing
    assert vggt_io.load_predictions(write(tmp_path, arrays, "orig.npz"), crop="auto").report.crop == (0, 0, 0, 0)


def test_left_right_padding_and_white_sky_not_cropped(tmp_path):
    arrays, _, _ = drive(H=24, W=16)
    p = write(tmp_path, pad(arrays, 0, 0, left=4, right=4))
    assert vggt_io.load_predictions(p, crop="auto").report.crop == (4, 0, 4, 0)
    # a sky of pure white at the top of every frame: top band only, not cropped
    sky = dict(arrays)
    sky["images"] = arrays["images"].copy()
    sky["images"][:, :3] = 1.0
    pred = vggt_io.load_predictions(write(tmp_path, sky, "sky.npz"), crop="auto")
    assert pred.report.crop == (0, 0, 0, 0) and pred.height == 24
    assert "white borders (left 0, top 3, right 0, bottom 0 px)" in pred.report.info[0]
    # padding plus a white sky row: the bands are not symmetric, nothing is guessed
    both = pad(sky, 4, 4)
    assert vggt_io.load_predictions(write(tmp_path, both, "both.npz"), crop="auto").report.crop == (0, 0, 0, 0)
    # one frame with a non-white border pixel is enough: not padding
    one = pad(arrays, 4, 4)
    one["images"][2, 1, 5, 0] = 0.999
    assert vggt_io.load_predictions(write(tmp_path, one, "one.npz"), crop="auto").report.crop == (0, 0, 0, 0)
    white = dict(arrays, images=np.ones_like(arrays["images"]))
    assert vggt_io.load_predictions(write(tmp_path, white, "white.npz"), crop="auto").report.crop == (0, 0, 0, 0)


def test_bad_crops(tmp_path):
    """A crop that is not one, or leaves nothing, is a CropError naming the file and the field "crop"."""
    arrays, _, _ = drive(H=10, W=12)
    p = write(tmp_path, arrays)
    with pytest.raises(vggt_crop.CropError, match="predictions.npz: crop left 6 top 0 right 6 bottom 0 leaves") as e:
        vggt_io.load_predictions(p, crop="6 0 6 0")
    assert e.value.field == "crop" and e.value.path == p and isinstance(e.value, vggt.PredictionsError)
    for bad in ("1 2 3", "a b c d", "-1 0 0 0", "1.5 0 0 0", [1, 2]):
        with pytest.raises(vggt_crop.CropError, match="predictions.npz: crop .*'auto', 'none' or four") as e:
            vggt_io.load_predictions(p, crop=bad)
        assert e.value.field == "crop" and e.value.path == p
    with pytest.raises(vggt_crop.CropError, match=r"clip\.npz: crop '0 1': expected"):
        vggt_crop.parse_crop("0 1", "clip.npz")
    assert vggt_crop.parse_crop(None) == vggt_crop.parse_crop("") == vggt_crop.parse_crop(" None ") == "none"
    assert vggt_crop.parse_crop("1,2, 3 4") == (1, 2, 3, 4) and vggt_crop.parse_crop(" AUTO") == "auto"


def test_detect_padding_needs_both_sides():
    """Only VGGT's symmetric pad bands (differing by at most a pixel) count; white_borders reports any band."""
    images = np.zeros((2, 20, 10, 3), np.float32)
    images[:, :3] = 1.0
    images[:, -4:] = 1.0
    assert vggt_crop.white_borders(images) == (0, 3, 0, 4)
    assert vggt_crop.detect_padding(images) == (0, 3, 0, 4)
    images[:, -4] = 0.5  # 3 rows at the bottom, 3 at the top
    assert vggt_crop.detect_padding(images) == (0, 3, 0, 3)
    images[:, -3:-1] = 0.5  # bottom band 1 row against 3 at the top: a white sky, not padding
    assert vggt_crop.white_borders(images) == (0, 3, 0, 1) and vggt_crop.detect_padding(images) == (0, 0, 0, 0)
