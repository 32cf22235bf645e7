"""Hand-made PlayCanvas SOG files for tests: chosen texel bytes and codebooks (``tiny``), written as a bundle (zip)
or a folder with lossless WebP images from OpenCV (``write_bundle``, ``write_folder``), so the reader is tested on
values known in advance and on files broken on purpose, without Node. The real writer's files are made with
tests/splat_transform.py."""

import json
import os
import zipfile

import numpy as np

#: The image names splat-transform writes.
NAMES = {"means": ["means_l.webp", "means_u.webp"], "scales": ["scales.webp"], "quats": ["quats.webp"],
         "sh0": ["sh0.webp"], "shN": ["shN_centroids.webp", "shN_labels.webp"]}


def encode_webp(rgba: np.ndarray) -> bytes:
    """Lossless WebP of an (H, W, 4) uint8 RGBA image (OpenCV: quality above 100 is lossless)."""
    import cv2

    ok, data = cv2.imencode(".webp", np.ascontiguousarray(rgba[:, :, [2, 1, 0, 3]]), [cv2.IMWRITE_WEBP_QUALITY, 101])
    assert ok
    return data.tobytes()


def tiny(n: int = 10, bands: int = 1, side: int = 4, seed: int = 0):
    """(meta, images) of ``n`` Gaussians in ``side`` x ``side`` images (texels past ``n`` zero), random bytes
    within the format's rules (quaternion tags 252-255, labels below the palette of 70 entries), alpha never 0 in
    the colour image (a lossless encoder may change the colour of transparent texels)."""
    rng = np.random.default_rng(seed)
    img = lambda: np.zeros((side, side, 4), np.uint8)  # noqa: E731
    images = {k: img() for k in ("means_l.webp", "means_u.webp", "quats.webp", "scales.webp", "sh0.webp")}
    for k, im in images.items():
        flat = im.reshape(-1, 4)
        flat[:n] = rng.integers(0, 256, (n, 4))
        flat[:n, 3] = 255
    images["quats.webp"].reshape(-1, 4)[:n, 3] = 252 + np.arange(n) % 4
    images["sh0.webp"].reshape(-1, 4)[:n, 3] = rng.integers(1, 256, n)
    meta = {"version": 2, "asset": {"generator": "tests/sog_fixtures.py"}, "count": n,
            "means": {"mins": [-2.0, -0.5, 0.0], "maxs": [1.5, 0.5, 0.0], "files": NAMES["means"]},
            "scales": {"codebook": np.linspace(-9, -1, 256).tolist(), "files": NAMES["scales"]},
            "quats": {"files": NAMES["quats"]},
            "sh0": {"codebook": np.linspace(-2, 3, 256).tolist(), "files": NAMES["sh0"]}}
    if bands:
        coeffs, palette = {1: 3, 2: 8, 3: 15}[bands], 70
        centroids = np.zeros((-(-palette // 64), 64 * coeffs, 4), np.uint8)
        centroids[..., :3] = rng.integers(0, 256, centroids[..., :3].shape)
        centroids[..., 3] = 255
        labels = img()
        lab = rng.integers(0, palette, n)
        labels.reshape(-1, 4)[:n] = np.stack([lab & 255, lab >> 8, np.zeros(n), np.full(n, 255)], 1)
        images["shN_centroids.webp"], images["shN_labels.webp"] = centroids, labels
        meta["shN"] = {"count": palette, "bands": bands, "codebook": np.linspace(-0.5, 0.5, 256).tolist(),
                       "files": NAMES["shN"]}
    return meta, images


def write_bundle(path, meta, images, leave_out=(), raw=None) -> str:
    """A .sog zip: meta.json (``raw`` bytes instead, when given) and the images but ``leave_out``."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        for name, im in images.items():
            if name not in leave_out:
                z.writestr(name, encode_webp(im))
        z.writestr("meta.json", raw if raw is not None else json.dumps(meta))
    return str(path)


def write_folder(folder, meta, images) -> str:
    """An unbundled SOG in ``folder``; returns its meta.json's path."""
    os.makedirs(folder, exist_ok=True)
    for name, im in images.items():
        with open(os.path.join(folder, name), "wb") as f:
            f.write(encode_webp(im))
    path = os.path.join(folder, "meta.json")
    with open(path, "w") as f:
        json.dump(meta, f)
    return path
