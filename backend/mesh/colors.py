"""Colours of mesh surface samples for the ``mesh-asset`` command: textures, vertex and face colours, material
base colours, as sRGB values in [0, 1] (the values 3DGS renders and the condition images hold).

Colours (``colour_source``): "texture" (base-colour texture, bilinear at the sample's UV, glTF conventions: texel
centres at (i + 0.5) / size, V as trimesh stores it, i.e. v = 1 at the top row; the wrap modes of the texture's
sampler (glTF ``samplers[].wrapS`` / ``wrapT``, ``WRAP_MODES``; REPEAT unless the file says otherwise, an MTL
``-clamp on`` CLAMP_TO_EDGE) applied, as OpenGL does, to the texel indices of each sample's interpolated UV), "vertex" (vertex
colours interpolated barycentrically), "face" (face colours, or the material's base colour when it has no
texture), "none" (nothing in the file: ``NEUTRAL_GREY``). glTF's baseColorFactor and COLOR_0 are linear by the
specification: they are applied in linear light and re-encoded to sRGB; textures and every other format's
colours are taken as sRGB values. Alpha is ignored: car assets are drawn opaque.
trimesh 5.2.0's own ``sample_surface(sample_color=True)`` is not used: it reads ``material.image``, which a
``PBRMaterial`` (every GLB, TRELLIS's included) does not have, and it takes face colours for vertex colours.

No bpy, no torch.
"""

from __future__ import annotations

import numpy as np

from scpainter_blender.core.colors import linear_to_srgb, srgb_to_linear

NEUTRAL_GREY = 0.5       # sRGB value for meshes without any colour (f_dc = 0)
#: glTF 2.0 sampler wrap modes (the OpenGL enums a glTF file stores); REPEAT is the default
REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT = 10497, 33071, 33648
WRAP_MODES = {REPEAT: "REPEAT", CLAMP_TO_EDGE: "CLAMP_TO_EDGE", MIRRORED_REPEAT: "MIRRORED_REPEAT"}
#: (wrapS, wrapT) where nothing says otherwise
DEFAULT_WRAP = (REPEAT, REPEAT)


def _bands(image, channels: int) -> np.ndarray:
    """(H, W, channels) uint8 of an 8-bit PIL image's first ``channels`` bands, filled a band of rows at a time:
    ``np.asarray(image)`` of the whole image goes through ``tobytes``, which holds its chunks and their join (twice
    the array), and RGBA would keep its alpha."""
    W, H = image.size
    out = np.empty((H, W, channels), np.uint8)
    rows = max(1, (1 << 18) // max(1, W))
    for y in range(0, H, rows):
        band = np.asarray(image.crop((0, y, W, min(H, y + rows))))
        out[y:y + rows] = band[..., None] if band.ndim == 2 else band[..., :channels]
    return out


def _texels(image) -> np.ndarray:
    """(H, W, 3) texels of a PIL image or an (H, W[, C]) array, in their own integer type (8 or 16 bit) or float:
    no float copy of the whole image (a 64 Mpx texture is 192 MB as 8-bit RGB, 1.5 GB as float64)."""
    if hasattr(image, "convert"):
        if image.mode in ("I;16", "I;16B", "I;16L", "I"):
            img = np.asarray(image)
            img = img.astype(np.uint16) if img.dtype != np.uint16 else img
        elif image.mode in ("RGB", "RGBA", "RGBX", "L", "LA"):
            img = _bands(image, 3 if image.mode.startswith("RGB") else 1)
        else:
            img = np.asarray(image.convert("RGB"))
    else:
        img = np.asarray(image)
    if img.ndim == 2:
        img = img[..., None]
    return img if img.shape[2] == 3 else img[..., :1] if img.shape[2] < 3 else img[..., :3]  # views, no copies


def _wrap(i, size: int, mode: int) -> np.ndarray:
    """Texel indices ``i`` (int64, any integers) wrapped into [0, size) as OpenGL's wrap ``mode`` does (the glTF
    2.0 sampler's): REPEAT i mod size; CLAMP_TO_EDGE clamped to the edge texels; MIRRORED_REPEAT i mod 2 size,
    the second half mirrored (2 size - 1 - i)."""
    if mode == CLAMP_TO_EDGE:
        return np.clip(i, 0, size - 1)
    if mode == MIRRORED_REPEAT:
        m = i % (2 * size)
        return np.where(m < size, m, 2 * size - 1 - m)
    return i % size


def sample_texture(image, uv, wrap=DEFAULT_WRAP) -> np.ndarray:
    """Bilinear RGB in [0, 1] (n, 3) of an image (PIL image or (H, W[, C]) array, 8 or 16 bit) at trimesh UVs (n, 2).

    glTF sampling: texel (i, j) has its centre at u = (i + 0.5) / W, and trimesh stores v flipped (v = 1 at the
    top row: row = (1 - v) H - 0.5); the four texel indices of each sample are wrapped by ``wrap`` = (wrapS for
    columns, wrapT for rows) (``WRAP_MODES``, default REPEAT). Non-finite UVs give NaN. Only the four texels of
    each sample are converted to float (memory O(n), not O(H W)).
    """
    img = _texels(image)
    scale = 65535.0 if img.dtype == np.uint16 else 255.0 if np.issubdtype(img.dtype, np.integer) else 1.0
    H, W = img.shape[:2]
    uv = np.asarray(uv, np.float64)
    ok = np.isfinite(uv).all(axis=1)
    x = np.where(ok, uv[:, 0], 0.0) * W - 0.5
    y = (1.0 - np.where(ok, uv[:, 1], 0.0)) * H - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    x0, x1 = _wrap(x0, W, wrap[0]), _wrap(x0 + 1, W, wrap[0])
    y0, y1 = _wrap(y0, H, wrap[1]), _wrap(y0 + 1, H, wrap[1])

    def at(r, c):  # (n, 3) float64 of the texels at rows r, columns c
        t = img[r, c].astype(np.float64) / scale
        return np.repeat(t, 3, axis=1) if t.shape[1] == 1 else t

    out = ((1 - fx) * (1 - fy) * at(y0, x0) + fx * (1 - fy) * at(y0, x1)
           + (1 - fx) * fy * at(y1, x0) + fx * fy * at(y1, x1))
    out[~ok] = np.nan
    return out


def _factor(value, default=(255, 255, 255, 255)) -> np.ndarray:
    """A material colour (uint8 0..255 or float 0..1, RGB or RGBA) as RGB floats in [0, 1]."""
    c = np.asarray(default if value is None else value)
    c = c.astype(np.float64) / 255.0 if np.issubdtype(c.dtype, np.integer) or c.max() > 1.0 else c.astype(np.float64)
    return np.clip(c.reshape(-1)[:3], 0.0, 1.0)


def material_image(material):
    """The base-colour texture (PIL image) of a trimesh material, or None."""
    return _material_colour(material)[0]


def _material_colour(material):
    """(base-colour texture or None, base colour factor RGB [0, 1]) of a trimesh material."""
    from trimesh.visual import material as mat

    if isinstance(material, mat.PBRMaterial):
        return material.baseColorTexture, _factor(material.baseColorFactor)
    if isinstance(material, mat.SimpleMaterial):
        return material.image, _factor(material.diffuse)
    image = getattr(material, "image", None) or getattr(material, "baseColorTexture", None)
    try:
        main = material.main_color
    except Exception:
        main = None
    return image, _factor(main)


def part_colours(part, local_faces, bary, gltf: bool, wrap=DEFAULT_WRAP):
    """sRGB RGB (n, 3) in [0, 1] at samples on ``part`` (face indices (n,), barycentric (n, 3)), and the source.
    ``wrap``: (wrapS, wrapT) of the part's base-colour texture (``MeshAsset.wraps``), applied to each sample's
    interpolated UV."""
    from trimesh.visual import ColorVisuals, TextureVisuals

    n = len(local_faces)
    vis = part.visual
    faces = np.asarray(part.faces)[local_faces]
    if isinstance(vis, TextureVisuals):
        image, factor = _material_colour(vis.material)
        uv = None if vis.uv is None else np.asarray(vis.uv, np.float64)
        if image is not None and uv is not None and len(uv) == len(part.vertices):
            tex = sample_texture(image, np.einsum("nk,nkc->nc", bary, uv[faces]), wrap)
            # glTF: base colour = texture (sRGB-decoded) x factor (linear); OBJ/MTL: the map replaces Kd
            rgb = linear_to_srgb(srgb_to_linear(tex) * factor) if gltf else tex
            return rgb, "texture"
        rgb = linear_to_srgb(factor) if gltf else factor
        return np.tile(rgb, (n, 1)), "face"
    if isinstance(vis, ColorVisuals) and vis.kind == "vertex":
        vc = np.asarray(vis.vertex_colors, np.float64)[:, :3] / 255.0
        rgb = np.einsum("nk,nkc->nc", bary, vc[faces])
        return (linear_to_srgb(rgb) if gltf else rgb), "vertex"
    if isinstance(vis, ColorVisuals) and vis.kind == "face":
        rgb = np.asarray(vis.face_colors, np.float64)[local_faces, :3] / 255.0
        return (linear_to_srgb(rgb) if gltf else rgb), "face"
    return np.full((n, 3), NEUTRAL_GREY), "none"
