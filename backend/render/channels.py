"""The condition EXR (``conditions/frame_NNNNNN.exr``): its channels, named once, written and read through the ASWF
OpenEXR package. The writer (``render``) and every reader (``generate``, ``evaluate``, training pairs, benchmarks,
tools) go through this module.

In memory a frame's layers are a dict keyed by ``CHANNELS``, float32 (H, W) each (``frames.render_frame`` returns
exactly these keys):

    R G B        the condition image I, display-referred, [0, 1]
    hole         1 where the pixel has no point and the asset mask is below 1/255 (the hole mask M), else 0
    asset_mask   M_a = 1 − the transmittance of the assets' Gaussians, [0, 1]
    Z            depth (metres along the optical axis) of what the pixel shows: where the asset's opacity first
                 reaches 0.5 if nearer than the point, else the point; +inf where empty
    instance     the id of the asset that dominates the pixel (1-based, the job's ``assets`` order), 0 where the
                 scene's point or nothing wins (``gaussians.rasterize``' rule), as float32 (exact below 2^24)

In the file each is a channel named ``layer.channel`` (``FILE_NAMES``), so that compositors show five passes of one
image: Blender's Image node (bpy 5.0.1, measured with the first four) lists the outputs ``image`` (colour),
``hole``, ``asset_mask``, ``depth`` (values) and ``instance``; Nuke reads ``layer.channel`` as a layer of that name
(``depth.Z`` is its own depth layer).

    image.R image.G image.B    I
    hole.Y                     M      (Y: OpenEXR's name for a single grey channel; viewers show it as grey)
    asset_mask.Y               M_a
    depth.Z                    Z
    instance.Y                 instance (always FLOAT: ids stay exact)

I holds display-referred values (what the model sees, like the PNG preview); a compositor takes EXR values as
scene-linear, so it shows ``image`` lighter than the preview unless told they are display values.

A single-part scanline file with lossless ZIP compression (3.5× smaller than raw float32 on the demo's frames,
bench/exr_sizes.py; zlib's checksum also makes damaged pixel data an error rather than wrong values). Every channel
is FLOAT (bit-exact: resume keys and tests compare the layers), or with ``half=True`` I, M and M_a are HALF (their
values lie in [0, 1]: error ≤ 2^-12 ≈ 2.4e-4, 0 and 1 exact; 5.6× smaller than raw) and Z and instance stay FLOAT
(metres to hundreds of metres need float's range and precision; ids must stay exact).

``read`` takes what other tools make of such a file when they re-save it: any compression (lossy ones give
their own values back), any channel order, tiled or scanline, several parts, HALF/UINT channels (converted to
float32), a prefix before the layer (Blender's ``ViewLayer.image.R``), a single-channel layer under another
channel letter (``hole.V``), and the flat names this project wrote before (``R G B hole asset_mask Z``, the asset
mask also as ``asset``: ``FORMER_NAMES``). A file without a layer the caller requires (by default every layer:
files written before the instance pass lack ``instance``) raises ``ConditionsError`` naming it. A file it cannot
use raises ``ExrError`` (an ``InputError``) naming
the file and what is wrong, with the hint to render again; never an exception from inside OpenEXR or numpy.

Only numpy and OpenEXR (imported when a file is read or written): tools that just read the layers do not import
torch.
"""

from __future__ import annotations

import contextlib
import functools
import io
import os

import numpy as np

from scpainter_blender.core import errors, files, outputs

IMAGE = ("R", "G", "B")
HOLE = "hole"
ASSET_MASK = "asset_mask"
DEPTH = "Z"
INSTANCE = "instance"
CHANNELS = (*IMAGE, HOLE, ASSET_MASK, DEPTH, INSTANCE)

#: Each layer's channel name in the file: ``layer.channel`` (see the module's docstring).
FILE_NAMES = {"R": "image.R", "G": "image.G", "B": "image.B", HOLE: "hole.Y", ASSET_MASK: "asset_mask.Y",
              DEPTH: "depth.Z", INSTANCE: "instance.Y"}

#: The layers ``write(..., half=True)`` stores as HALF (values in [0, 1]); the others (depth, instance ids) stay
#: FLOAT.
HALF_LAYERS = (*IMAGE, HOLE, ASSET_MASK)

#: Former flat channel names -> current ones (condition EXRs written before the rename).
FORMER_NAMES = {"asset": ASSET_MASK}

HINT = ("render this frame again: delete the file and run python -m backend render JOB (--force renders "
        "every frame)")

#: More pixels than any condition frame has (an 8K frame is 33 M): a header claiming more is damaged, refused
#: before OpenEXR allocates for it.
MAX_PIXELS = 1 << 27

#: OpenEXR's magic number, the file's first four bytes (little-endian 20000630).
MAGIC = b"\x76\x2f\x31\x01"


class ExrError(errors.InputError):
    """A condition EXR this reader cannot use (not OpenEXR, truncated, damaged, another shape of image): the
    file, the field (``(file)``, ``dataWindow``, ``channels``, ...) and what is wrong; the hint says to render
    again."""


class ConditionsError(ExrError):
    """A condition EXR without the channels this reader needs (``field`` = ``channels``)."""


# ------------------------------------------------------------------------------------------------------- write

#: OpenEXR's camera axes (its standard attributes, "the same as Pixar's RenderMan"): x right, y up, z forward
#: (left-handed); ours are OpenCV's (y down). This maps ours to theirs.
OPENCV_TO_EXR_CAMERA = np.diag([1.0, -1.0, 1.0, 1.0])


def camera_attributes(K, world_to_camera, width: int, height: int) -> dict:
    """OpenEXR's standard ``worldToCamera`` and ``worldToNDC`` header attributes (M44f) of a pinhole camera (our K,
    OpenCV ``world_to_camera``), so compositors and other tools can place the layers in the world.

    Imath matrices multiply row vectors (p' = p · M: the translation in the last row), so each is stored transposed.
    ``worldToCamera`` maps to OpenEXR's camera axes (``OPENCV_TO_EXR_CAMERA``). ``worldToNDC`` maps a world point to
    NDC after the homogeneous divide: x = u / width, y = v / height (0, 0 the display window's upper-left corner,
    (1, 1) its lower-right, y down; u, v in our pixel coordinates, whose pixel edges are integers), z = 1 / depth
    (OpenEXR says to discard it; a finite row keeps the matrix invertible)."""
    K = np.asarray(K, np.float64)
    w2c = np.asarray(world_to_camera, np.float64)
    to_ndc = np.array([[K[0, 0] / width, K[0, 1] / width, K[0, 2] / width, 0.0],
                       [0.0, K[1, 1] / height, K[1, 2] / height, 0.0],
                       [0.0, 0.0, 0.0, 1.0],
                       [0.0, 0.0, 1.0, 0.0]])
    return {"worldToCamera": np.ascontiguousarray((OPENCV_TO_EXR_CAMERA @ w2c).T, np.float32),
            "worldToNDC": np.ascontiguousarray((to_ndc @ w2c).T, np.float32)}


def write(path, layers: dict, half: bool = False, camera: dict | None = None) -> None:
    """One frame's layers (``CHANNELS`` -> (H, W) arrays, as ``frames.render_frame`` returns them) as a condition
    EXR: ZIP-compressed (lossless), channels named ``FILE_NAMES``, FLOAT; with ``half`` the ``HALF_LAYERS`` as
    HALF. ``camera``: header attributes (``camera_attributes``). Written atomically (a temporary file renamed over
    ``path``). ValueError (a programming error, not input) for any other set of keys or unequal shapes."""
    import OpenEXR

    if set(layers) != set(CHANNELS):
        raise ValueError(f"condition layers must be {list(CHANNELS)}, got {sorted(layers)}")
    shapes = {np.shape(layers[c]) for c in CHANNELS}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2 or 0 in next(iter(shapes)):
        raise ValueError(f"condition layers must share one (H, W) shape, got {sorted(shapes)}")
    pixels = {}
    for c in CHANNELS:
        dtype = np.float16 if half and c in HALF_LAYERS else np.float32
        pixels[FILE_NAMES[c]] = np.ascontiguousarray(layers[c], dtype=dtype)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **(camera or {})}
    # (OpenEXR.File replaces the values of the dict it is given with its Channel objects: ``pixels`` is ours)
    image = OpenEXR.File(header, pixels)
    with outputs.atomic_write(path) as f:  # a stream: the temporary file is opened without following links
        image.write(f)


# -------------------------------------------------------------------------------------------------------- read

def read(path, required=CHANNELS) -> dict:
    """The layers {``CHANNELS`` name: (H, W) float32} of a condition EXR, whatever its compression, channel order,
    tiling, parts or pixel types (see the module's docstring), every ``CHANNELS`` layer the file has.
    ``required``: the layers the caller needs; ConditionsError naming the missing ones. ExrError naming the file
    for one that is not a readable OpenEXR image of equal-sized channels."""
    path = os.fspath(path)
    error = functools.partial(ExrError, hint=HINT)
    with files.open_regular(path, error) as f:  # a FIFO or a directory is refused before any read
        data = f.read()
    if data[:4] != MAGIC:
        raise error(path, "(file)", "not an OpenEXR file")
    found = _decode(path, data, error)
    names = _match(path, sorted(found), error)
    layers = {}
    for key, name in names.items():
        layers[key] = found[name].astype(np.float32)  # HALF exactly, UINT up to 2^24; FLOAT copied (ours, writable)
    missing = [c for c in required if c not in layers]
    if missing:
        raise ConditionsError(path, "channels", f"condition layers {missing} are missing (the file has channels "
                                                f"{sorted(found)})", hint=HINT)
    return layers


def _decode(path: str, data: bytes, error) -> dict:
    """{channel name: (H, W) array} of every part of the EXR in ``data``, checked: a flat image (no deep data),
    every pixel of the display window present, one size for all channels. The header is read and checked first,
    so a forged size is refused before anything is allocated for it."""
    import OpenEXR

    header = _open(data, error, path, header_only=True)
    shape = None
    for part in header.parts:
        h = part.header
        if part.type() not in (OpenEXR.scanlineimage, OpenEXR.tiledimage):
            raise error(path, "type", f"part {part.part_index} is {part.type().name}: only flat (scanline or "
                                      "tiled) images are condition layers")
        (x0, y0), (x1, y1) = (tuple(int(v) for v in corner) for corner in h["dataWindow"])
        if not (0 < x1 - x0 + 1 and 0 < y1 - y0 + 1 and (x1 - x0 + 1) * (y1 - y0 + 1) <= MAX_PIXELS):
            raise error(path, "dataWindow", f"({x0}, {y0}) - ({x1}, {y1}) is not a usable size (damaged?)")
        display = tuple(tuple(int(v) for v in corner) for corner in h["displayWindow"])
        if ((x0, y0), (x1, y1)) != display:
            raise error(path, "dataWindow", f"({x0}, {y0}) - ({x1}, {y1}) differs from the display window "
                                            f"{display}: a condition EXR holds every pixel of its frame "
                                            "(save it uncropped)")
        if shape not in (None, (y1 - y0 + 1, x1 - x0 + 1)):
            raise error(path, "dataWindow", "the parts have different sizes")
        shape = (y1 - y0 + 1, x1 - x0 + 1)
    image = _open(data, error, path, header_only=False)
    found = {}
    for part in image.parts:
        for name, channel in part.channels.items():
            if name in found:
                raise error(path, "channels", f"channel {name!r} is in more than one part")
            pixels = channel.pixels
            if pixels is None or pixels.shape != shape:
                what = "has no pixels (damaged)" if pixels is None else (
                    f"is {pixels.shape[1]}x{pixels.shape[0]} (subsampled?), the image {shape[1]}x{shape[0]}")
                raise error(path, "channels", f"channel {name!r} {what}")
            found[name] = pixels
    return found


def _open(data: bytes, error, path: str, header_only: bool):
    """OpenEXR.File on ``data``. OpenEXR raises RuntimeError/ValueError (and UnicodeDecodeError for a damaged
    name) for a damaged file, and for some damage only prints a warning on standard output and returns a file
    without pixels: standard output is the backend's event stream, so it is captured, and a warning is an
    error too. (OpenEXR's core library also writes its diagnosis to standard error: left there, for the log.)"""
    import OpenEXR

    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said):
            image = OpenEXR.File(io.BytesIO(data), separate_channels=True, header_only=header_only)
            image.parts  # noqa: B018 (the parts are read here, inside the capture)
    except Exception as e:  # anything OpenEXR raises on a file's bytes means the file is bad, never our bug
        raise error(path, "(file)", f"damaged or truncated OpenEXR file ({type(e).__name__}: {e})") from None
    warning = said.getvalue().strip()
    if warning:
        warning = warning.removeprefix("Warning: ").splitlines()[0]
        raise error(path, "(file)", f"damaged or truncated OpenEXR file ({warning})")
    if not image.parts:
        raise error(path, "(file)", "an OpenEXR file without any image part (damaged?)")
    return image


#: Each layer's name in the file (its last component, compared case-insensitively) and its channel letters.
_LAYERS = {HOLE: ("hole", "Y"), ASSET_MASK: ("asset_mask", "Y"), DEPTH: ("depth", "Z"), INSTANCE: ("instance", "Y")}
_COLOURS = {"red": "R", "green": "G", "blue": "B"}  # (Nuke's names for a layer's R G B)


def _match(path: str, names: list, error) -> dict:
    """{``CHANNELS`` key: file channel name} for the channel ``names`` of a file: ``layer.channel`` names first
    (the layer may carry a prefix, ``ViewLayer.image.R``; a one-channel layer may use any letter), else the flat
    names of former files (``R G B hole asset_mask Z``, ``asset``)."""
    found, flat = {}, {}  # {layer's last component, lower case: {layer: {letter: name}}}; {flat name: name}
    for n in names:
        layer, _, letter = n.rpartition(".")
        if layer:
            found.setdefault(layer.rpartition(".")[2].lower(), {}).setdefault(layer, {})[letter] = n
        else:
            flat[letter] = n
    layers = {}  # {pass: (layer, {letter: name})} for this module's passes
    for name in ("image", *(p for p, _ in _LAYERS.values())):
        if len(found.get(name, ())) > 1:
            raise error(path, "channels", f"layers {sorted(found[name])} could each be the {name} pass: keep one")
        if name in found:
            layers[name] = next(iter(found[name].items()))
    for old, new in FORMER_NAMES.items():
        if old in flat and new not in flat:
            flat[new] = flat.pop(old)
    out = {c: flat[c] for c in CHANNELS if c in flat}
    if "image" in layers:
        letters = {_COLOURS.get(k.lower(), k.upper()): v for k, v in layers["image"][1].items()}
        out.update({c: letters[c] for c in IMAGE if c in letters})
    for key, (name, wanted) in _LAYERS.items():
        if name not in layers:
            continue
        layer, letters = layers[name]
        if wanted in letters or len(letters) == 1:
            out[key] = letters.get(wanted) or next(iter(letters.values()))
        else:
            raise error(path, "channels", f"layer {layer!r} has channels {sorted(letters)}: expected one "
                                          f"({wanted})")
    return out
