"""core.vggt.predictions: VGGT's K against ours, the refusal every predictions reader raises, the numeric-array rule."""

import numpy as np
import pytest

from scpainter_blender.core import errors
from scpainter_blender.core.vggt import predictions as vggt


def test_K_conversion_moves_the_principal_point_half_a_pixel():
    K = np.array([[[300.0, 0, 259], [0, 310, 147], [0, 0, 1]]] * 2, np.float32)
    ours = vggt.vggt_K_to_ours(K)
    assert ours.dtype == np.float64 and np.array_equal(ours[:, :2, 2], K[:, :2, 2] + 0.5)
    assert np.array_equal(ours[:, :2, :2], K[:, :2, :2]) and np.array_equal(vggt.ours_K_to_vggt(ours), K)
    assert K[0, 0, 2] == 259  # a copy: the argument is untouched


def test_predictions_error_names_file_and_key():
    e = vggt.PredictionsError("/data/clip/predictions.npz", "depth", "holds integers")
    assert isinstance(e, errors.InputError) and isinstance(e, ValueError)
    assert (e.path, e.field, e.key) == ("/data/clip/predictions.npz", "depth", "depth")
    assert str(e) == "predictions.npz: 'depth': holds integers (/data/clip/predictions.npz)"
    whole = vggt.PredictionsError("/data/p.npz", "(file)", "is a directory")
    assert whole.key is None and whole.field == "(file)" and str(whole) == "p.npz: is a directory (/data/p.npz)"


@pytest.mark.parametrize("key, array, ok", [
    ("extrinsic", np.eye(4, dtype=np.int64), True),         # integer poses are numbers
    ("depth", np.ones((2, 2), np.float16), True),
    ("depth", np.ones((2, 2), np.uint16), False),           # millimetres: not VGGT units
    ("world_points_conf", np.ones(3, np.int8), False),
    ("intrinsic", np.ones(3, bool), False),
    ("images", np.array(["a"]), False),
    ("extrinsic", np.ones(2, np.complex64), False),
])
def test_numeric_refuses_what_is_not_a_measurement(key, array, ok):
    if ok:
        assert vggt.numeric(array, "p.npz", key) is not None
    else:
        with pytest.raises(vggt.PredictionsError, match=f"p.npz: '{key}': (is not an array of numbers|holds "
                                                        "integers)") as e:
            vggt.numeric(array, "p.npz", key)
        assert e.value.field == key
