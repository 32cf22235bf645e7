"""The object classes every label and export uses: one fixed table, ``CATEGORIES`` (docs/design.md §15).

A class is a lower-case name (``car``). Its COCO ``category_id`` is its place in the table and never changes: the
table only grows at its end, so a train export made today and a val export made next month agree, whatever classes
each happens to show. Each row also says how the class is spelled by the formats that have their own names:

* ``kitti``: the object devkit's ``type`` (``Car``, ``Van``, ``Truck``, ``Pedestrian``, ``Person_sitting``,
  ``Cyclist``, ``Tram``, ``Misc``; readme.txt of the KITTI object devkit). Classes KITTI has no type for are ``Misc``.
* ``nuscenes``: the nuScenes ``category.name`` (the devkit's 23 classes, e.g. ``vehicle.car``), the one written by
  a nuScenes export and the one a nuScenes import maps back (``from_nuscenes`` also reads the other names of the
  same general class: ``vehicle.bus.bendy`` -> ``bus``).

``IGNORE`` is not a class: it names what stays unlabelled but visible (an ignore region: COCO ``iscrowd 1``,
KITTI ``DontCare``, an OpenLABEL object of type ``ignore``).

stdlib only.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Category:
    """One class: its ``id`` (COCO ``category_id``, 1-based, fixed), ``name`` (ours), ``supercategory`` (COCO's),
    ``kitti`` type and ``nuscenes`` category name."""
    id: int
    name: str
    supercategory: str
    kitti: str
    nuscenes: str


#: The table. Append only: a row's id is its place, and exports made by other versions must keep agreeing.
CATEGORIES = (
    Category(1, "car", "vehicle", "Car", "vehicle.car"),
    Category(2, "truck", "vehicle", "Truck", "vehicle.truck"),
    Category(3, "bus", "vehicle", "Misc", "vehicle.bus.rigid"),
    Category(4, "trailer", "vehicle", "Misc", "vehicle.trailer"),
    Category(5, "construction_vehicle", "vehicle", "Misc", "vehicle.construction"),
    Category(6, "pedestrian", "person", "Pedestrian", "human.pedestrian.adult"),
    Category(7, "motorcycle", "vehicle", "Misc", "vehicle.motorcycle"),
    Category(8, "bicycle", "vehicle", "Misc", "vehicle.bicycle"),
    Category(9, "traffic_cone", "object", "Misc", "movable_object.trafficcone"),
    Category(10, "barrier", "object", "Misc", "movable_object.barrier"),
    Category(11, "van", "vehicle", "Van", "vehicle.car"),
    Category(12, "cyclist", "person", "Cyclist", "vehicle.bicycle"),
    Category(13, "tram", "vehicle", "Tram", "vehicle.bus.rigid"),
    Category(14, "misc", "object", "Misc", "movable_object.debris"),
)
#: The nuScenes devkit's 23 detection-benchmark categories (v1.0 ``category.json``; the names of its ``category``
#: table and of ``Category.nuscenes``), in the devkit's order, with a short description each: a nuScenes export
#: writes all of them, whatever classes it shows, as nuScenes' own tables do.
NUSCENES_CATEGORIES = (
    ("human.pedestrian.adult", "Adult subcategory."),
    ("human.pedestrian.child", "Child subcategory."),
    ("human.pedestrian.wheelchair", "Wheelchairs."),
    ("human.pedestrian.stroller", "Strollers."),
    ("human.pedestrian.personal_mobility", "A small electric or self-propelled vehicle ridden by a person."),
    ("human.pedestrian.police_officer", "Police officer."),
    ("human.pedestrian.construction_worker", "Construction worker."),
    ("animal", "All animals."),
    ("vehicle.car", "Vehicle designed primarily for personal use."),
    ("vehicle.motorcycle", "Gasoline or electric powered 2-wheeled vehicle."),
    ("vehicle.bicycle", "Human or electric powered 2-wheeled vehicle."),
    ("vehicle.bus.bendy", "Bendy bus subcategory."),
    ("vehicle.bus.rigid", "Rigid bus subcategory."),
    ("vehicle.truck", "Vehicles primarily designed to haul cargo."),
    ("vehicle.construction", "Vehicles primarily designed for construction."),
    ("vehicle.emergency.ambulance", "All types of ambulances."),
    ("vehicle.emergency.police", "All types of police vehicles."),
    ("vehicle.trailer", "Any vehicle trailer."),
    ("movable_object.barrier", "Temporary road barrier placed in the scene in order to redirect traffic."),
    ("movable_object.trafficcone", "All types of traffic cone."),
    ("movable_object.pushable_pullable", "Objects that a pedestrian may push or pull."),
    ("movable_object.debris", "Movable object that is left on the driveable surface."),
    ("static_object.bicycle_rack", "Area or device intended to park or secure the bicycles in a row."),
)
BY_NAME = {c.name: c for c in CATEGORIES}
NAMES = tuple(c.name for c in CATEGORIES)
#: What an unlabelled-but-visible region is called in the labels and the exports (not a class).
IGNORE = "ignore"


def category(name: str) -> Category:
    """The row of class ``name``; KeyError when the table has none (callers name their file and field)."""
    return BY_NAME[name]


def category_id(name: str) -> int:
    """The COCO ``category_id`` of class ``name`` (fixed: its place in ``CATEGORIES``)."""
    return BY_NAME[name].id


def from_kitti(kitti_type: str) -> str | None:
    """Our class for a KITTI ``type`` (``Car`` -> ``car``, ``Person_sitting`` -> ``pedestrian``); None for
    ``DontCare`` and types the table does not know."""
    special = {"Person_sitting": "pedestrian", "Misc": "misc"}
    if kitti_type in special:
        return special[kitti_type]
    name = kitti_type.lower()
    return name if name in BY_NAME and BY_NAME[name].kitti == kitti_type else None


def from_nuscenes(category_name: str) -> str | None:
    """Our class for a nuScenes ``category.name`` (``vehicle.car`` -> ``car``; every ``human.pedestrian.*`` ->
    ``pedestrian``, ``vehicle.bus.*`` -> ``bus``, ``vehicle.emergency.*`` -> ``car``); None for the classes that are
    not objects to label (``animal``, ``static_object.bicycle_rack``, ``movable_object.pushable_pullable``, …)."""
    prefixes = (("human.pedestrian.", "pedestrian"), ("vehicle.bus.", "bus"), ("vehicle.emergency.", "car"))
    for prefix, name in prefixes:
        if category_name.startswith(prefix):
            return name
    exact = {c.nuscenes: c.name for c in reversed(CATEGORIES)}  # first row wins: vehicle.car -> car, not van
    return exact.get(category_name)
