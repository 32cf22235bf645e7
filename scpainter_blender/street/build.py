"""The procedural street in bpy: road, kerbs, sidewalks, poles, facades, parked cars, the sun and the sky, and the
recorded drive's camera path.

World: Blender's (Z up, metres); the road runs along +Y and the drive starts near the origin. Geometry is built
as arrays by ``core.shapes`` and made Blender objects here; materials are in ``materials.py``. Building resets
the running Blender session: run it in its own process (``python -m scpainter_blender.street``, see
``render.py``).
"""

from __future__ import annotations

import math

import bpy
import numpy as np

from ..core.shapes import MeshBuilder, add_car
from .dataset import StreetParams
from .materials import asphalt, facade, plain, sky_world


# Street cross-section along x (metres): three lanes, parking strips, kerbs, sidewalks, building line.
ROAD_HALF = 5.25
PARKING_HALF = 7.25
KERB_HALF = 7.45
SIDEWALK_HALF = 10.5
KERB_HEIGHT = 0.15
BEND_LENGTH = 20.0  # metres over which the path drifts curve_m sideways


def to_object(builder: MeshBuilder, name, collection, pass_index=0):
    """One mesh object from a MeshBuilder whose material keys are Blender materials."""
    verts, faces, mats = builder.arrays()
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts.tolist(), [], faces)
    for m in builder.materials:
        mesh.materials.append(m)
    mesh.polygons.foreach_set("material_index", mats)
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    obj.pass_index = pass_index
    collection.objects.link(obj)
    return obj

def build_scene(params: StreetParams) -> dict:
    """Reset Blender and build the street; returns the parked cars' boxes (world metres) and the path length."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    rng = np.random.default_rng(params.seed)
    scene = bpy.context.scene
    coll = scene.collection
    length = params.num_frames * params.frame_spacing_m + 80.0
    y0, y1 = -30.0, length

    mats = {
        "road": asphalt("road", params.seed), "paint": plain("lane paint", (0.85, 0.85, 0.82), 0.5),
        "kerb": plain("kerb", (0.42, 0.42, 0.4), 0.8), "sidewalk": plain("sidewalk", (0.55, 0.53, 0.5), 0.85),
        "pole": plain("pole", (0.3, 0.32, 0.33), 0.4, 0.6), "glass": plain("car glass", (0.02, 0.025, 0.03), 0.1),
        "tyre": plain("tyre", (0.02, 0.02, 0.02), 0.9),
    }
    ground = MeshBuilder()
    ground.box((0, (y0 + y1) / 2, -0.05), (2 * PARKING_HALF, y1 - y0, 0.1), mats["road"])
    for side in (-1, 1):
        ground.box((side * (PARKING_HALF + KERB_HALF) / 2, (y0 + y1) / 2, KERB_HEIGHT / 2 - 0.05),
                   (KERB_HALF - PARKING_HALF, y1 - y0, KERB_HEIGHT + 0.1), mats["kerb"])
        ground.box((side * (KERB_HALF + SIDEWALK_HALF) / 2, (y0 + y1) / 2, KERB_HEIGHT / 2 - 0.05),
                   (SIDEWALK_HALF - KERB_HALF, y1 - y0, KERB_HEIGHT + 0.1), mats["sidewalk"])
        ground.box((side * (ROAD_HALF - 0.2), (y0 + y1) / 2, 0.002), (0.15, y1 - y0, 0.004), mats["paint"])
        for y in np.arange(y0 + rng.uniform(0, 6), y1, 15.0):
            ground.cylinder((side * (KERB_HALF + 0.5), y, KERB_HEIGHT + 2.5), 0.08, 5.0, 2, mats["pole"], 10)
    for lane_x in (-1.75, 1.75):  # dashed lane marks, 3 m on, 6 m off
        for y in np.arange(y0, y1, 9.0):
            ground.box((lane_x, y + 1.5, 0.002), (0.15, 3.0, 0.004), mats["paint"])
    to_object(ground, "street ground", coll)

    buildings = MeshBuilder()
    for side in (-1, 1):
        y = y0
        while y < y1:
            w = rng.uniform(7.0, 15.0)
            h = rng.uniform(6.0, 20.0)
            d = 10.0
            wall = tuple(rng.uniform([0.25, 0.2, 0.15], [0.75, 0.65, 0.55]))
            mat = facade(f"facade {side} {y:.0f}", wall, window=(rng.uniform(1.3, 2.2), rng.uniform(1.2, 1.6)))
            buildings.box((side * (SIDEWALK_HALF + d / 2), y + w / 2, h / 2), (d, w - 0.3, h), mat)
            y += w
    to_object(buildings, "street buildings", coll)

    cars = []
    drive_len = params.num_frames * params.frame_spacing_m
    slots = np.linspace(6.0, drive_len + 30.0, params.num_parked_cars)
    for k, y in enumerate(slots):
        side = 1 if k % 2 == 0 else -1
        builder = MeshBuilder()
        paint = plain(f"car paint {k}", tuple(rng.uniform(0.05, 0.8, 3)), 0.35, 0.2)
        add_car(builder, rng, paint, mats["glass"], mats["tyre"])
        obj = to_object(builder, f"parked car {k + 1}", coll, pass_index=k + 1)
        x = side * (ROAD_HALF + PARKING_HALF) / 2
        yaw = float(rng.uniform(-0.04, 0.04))
        obj.location = (x, float(y + rng.uniform(-2, 2)), 0.0)
        obj.rotation_euler = (0.0, 0.0, yaw)
        lo, hi = builder.bounds()  # the box that holds every part, wheels included
        M = np.array(obj.matrix_basis, dtype=np.float64)
        box = M.copy()
        box[:3, 3] = M[:3, :3] @ ((lo + hi) / 2) + M[:3, 3]
        cars.append({"name": obj.name, "instance": k + 1, "box_to_world": box.tolist(),
                     "size": (hi - lo).tolist()})

    sun = bpy.data.lights.new("sun", "SUN")
    sun.energy = 4.0
    sun.angle = math.radians(0.5)
    sun_obj = bpy.data.objects.new("sun", sun)
    sun_obj.rotation_euler = (math.radians(48), 0.0, math.radians(35))
    coll.objects.link(sun_obj)
    scene.world = sky_world()

    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    coll.objects.link(cam)
    scene.camera = cam
    return {"cars": cars}


def recorded_path(params: StreetParams) -> np.ndarray:
    """OpenCV world_to_camera (S, 4, 4) of the recorded drive: along +Y in the ego lane, a gentle bend."""
    S = params.num_frames
    y = np.arange(S) * params.frame_spacing_m
    x = params.lane_x_m + params.curve_m * (y / BEND_LENGTH) ** 2  # the same bend whatever the frame count
    dxdy = 2 * params.curve_m * y / BEND_LENGTH ** 2
    heading = np.stack([dxdy, np.ones(S), np.zeros(S)], axis=1)
    heading /= np.linalg.norm(heading, axis=1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0])
    p = math.radians(params.pitch_deg)
    z_ax = math.cos(p) * heading + math.sin(p) * up
    x_ax = np.cross(heading, up)
    x_ax /= np.linalg.norm(x_ax, axis=1, keepdims=True)
    y_ax = np.cross(z_ax, x_ax)
    T = np.tile(np.eye(4), (S, 1, 1))
    T[:, :3, :3] = np.stack([x_ax, y_ax, z_ax], axis=1)
    centres = np.stack([x, y, np.full(S, params.camera_height_m)], axis=1)
    T[:, :3, 3] = -np.einsum("nij,nj->ni", T[:, :3, :3], centres)
    return T
