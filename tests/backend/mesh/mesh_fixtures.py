"""Test helpers for the mesh-asset tests (tests/backend/test_mesh_*.py): small meshes made here (an asymmetric
car-like object, a cell texture), the glTF axes, and the colour and normal of Gaussians as the sampler makes them."""

import json
import os
import struct

import numpy as np
import trimesh
from PIL import Image

from backend.mesh import load as mesh_load
from scpainter_blender.core.geometry import cameras
from scpainter_blender.core.splats.sh import SH_C0

R_GLTF = mesh_load.Y_UP_TO_Z_UP            # p_zup = R_GLTF @ p_gltf
TRELLIS_GLB = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # to_glb: vertices @ TRELLIS_GLB


def rgb_of(g):
    """sRGB colours (N, 3) of degree-0 Gaussians: 0.5 + C0 f_dc."""
    return SH_C0 * g.sh[:, 0].astype(np.float64) + 0.5


def normals_of(g):
    """Unit normals (N, 3) of flat Gaussians: the local z axis of their rotations."""
    return cameras.quaternion_to_rotation(g.quats.astype(np.float64))[:, :, 2]


def split_triangles(vertices, faces):
    """Every triangle with its own three vertices (so per-triangle UVs and colours are free)."""
    tri = np.asarray(vertices, float)[np.asarray(faces)]
    return tri.reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3)


def car_like_zup():
    """An asymmetric test object, Z up: a 4 x 2 x 1 body on z = 0 and a mast at its (+x, +y) corner."""
    body = trimesh.creation.box((4.0, 2.0, 1.0), trimesh.transformations.translation_matrix((0, 0, 0.5)))
    mast = trimesh.creation.box((0.4, 0.4, 1.0), trimesh.transformations.translation_matrix((1.6, 0.7, 1.5)))
    return trimesh.util.concatenate([body, mast])


def cell_texture(colours, cell=16):
    """A 3 x 2 grid of uniform cells (uint8 RGB colours (6, 3)), and a function giving UVs inside cell k."""
    img = np.zeros((2 * cell, 3 * cell, 3), np.uint8)
    for k, c in enumerate(colours):
        i, j = k % 3, k // 3
        img[j * cell:(j + 1) * cell, i * cell:(i + 1) * cell] = c

    def uv_in_cell(k, n):  # n points well inside cell k (trimesh's V: v = 1 is the image's top row)
        i, j = k % 3, k // 3
        centre = np.array([(i + 0.5) / 3, 1 - (j + 0.5) / 2])
        ring = np.array([[-0.3, -0.3], [0.3, -0.3], [0.0, 0.3]])[:n]
        return centre + ring * np.array([1 / 3, 1 / 2])

    return Image.fromarray(img), uv_in_cell


def export(mesh, path):
    """``mesh`` exported by trimesh to ``path`` (format by extension); returns the path as a string."""
    mesh.export(os.fspath(path))
    return os.fspath(path)


def triangle_gltf(folder, name="tri.gltf", buffer_uri="tri.bin", image_uri=None, indices=(0, 1, 2),
                  uv=((0, 0), (1, 0), (0, 1)), accessors=(), images=None, write_buffer=True, image_bytes=None):
    """A one-triangle glTF written by hand (so it can be broken): POSITION, TEXCOORD_0 and uint32 ``indices`` in
    one buffer, the file ``buffer_uri`` (written unless ``write_buffer`` is False) or, for a ``name`` ending in
    .glb, the GLB's BIN chunk (``buffer_uri`` None). ``image_uri``: a base-colour texture named by URI;
    ``images``: the ``images`` list itself (then ``image_uri`` is not used); ``accessors``: more accessors appended;
    ``image_bytes``: an image stored in the buffer (``bufferViews[3]``) as the base-colour texture. Returns the
    path."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    idx = np.array(indices, np.uint32)
    blob = positions.tobytes() + np.asarray(uv, np.float32).tobytes() + idx.tobytes()
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 24},
             {"buffer": 0, "byteOffset": 60, "byteLength": 4 * len(idx)}]
    if image_bytes is not None:
        blob += b"\0" * (-len(blob) % 4)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(image_bytes)})
        blob += image_bytes
        images = [{"bufferView": 3, "mimeType": "image/png"}]
    buffer = {"byteLength": len(blob)} if buffer_uri is None else {"uri": buffer_uri, "byteLength": len(blob)}
    gltf = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "buffers": [buffer],
            "bufferViews": views,
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                           "min": [0, 0, 0], "max": [1, 1, 0]},
                          {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"},
                          {"bufferView": 2, "componentType": 5125, "count": len(idx), "type": "SCALAR"},
                          *accessors],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2}]}]}
    if image_uri is not None or images is not None:
        gltf["meshes"][0]["primitives"][0]["material"] = 0
        gltf["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
        gltf["textures"] = [{"source": 0}]
        gltf["images"] = images if images is not None else [{"uri": image_uri}]
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, name)
    if buffer_uri is not None and write_buffer:
        with open(os.path.join(folder, buffer_uri), "wb") as f:
            f.write(blob)
    if name.endswith(".glb"):
        with open(path, "wb") as f:
            f.write(glb_bytes(gltf, blob if buffer_uri is None else None))
    else:
        with open(path, "w") as f:
            json.dump(gltf, f)
    return path


def glb_bytes(gltf: dict, bin_chunk: bytes | None = None) -> bytes:
    """A GLB container (glTF 2.0): header, the JSON chunk (space-padded) and the BIN chunk (zero-padded)."""
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text
    if bin_chunk is not None:
        bin_chunk += b"\0" * (-len(bin_chunk) % 4)
        body += struct.pack("<II", len(bin_chunk), 0x004E4942) + bin_chunk
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body
