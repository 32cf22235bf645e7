"""The fixed class table (core/categories.py): ids never move, every format's spelling maps back."""

from scpainter_blender.core import categories


def test_ids_are_places_and_names_unique():
    assert [c.id for c in categories.CATEGORIES] == list(range(1, len(categories.CATEGORIES) + 1))
    assert len(set(categories.NAMES)) == len(categories.NAMES)
    assert categories.IGNORE not in categories.NAMES


def test_the_first_rows_never_move():
    # exports made by earlier versions carry these ids: a change here breaks every dataset made so far
    assert [(c.id, c.name) for c in categories.CATEGORIES[:3]] == [(1, "car"), (2, "truck"), (3, "bus")]
    assert categories.category_id("car") == 1


def test_kitti_types_map_back():
    assert categories.from_kitti("Car") == "car"
    assert categories.from_kitti("Van") == "van"
    assert categories.from_kitti("Person_sitting") == "pedestrian"
    assert categories.from_kitti("DontCare") is None
    for c in categories.CATEGORIES:
        if c.kitti != "Misc":
            assert categories.from_kitti(c.kitti) == c.name


def test_nuscenes_names_map_back():
    assert categories.from_nuscenes("vehicle.car") == "car"
    assert categories.from_nuscenes("human.pedestrian.child") == "pedestrian"
    assert categories.from_nuscenes("vehicle.bus.bendy") == "bus"
    assert categories.from_nuscenes("animal") is None
    for name in ("car", "truck", "bus", "trailer", "pedestrian", "barrier", "traffic_cone"):
        assert categories.from_nuscenes(categories.category(name).nuscenes) == name


def test_the_nuscenes_table_holds_the_devkits_23_categories_and_every_class_maps_into_it():
    from scpainter_blender.core.recording import nuscenes

    names = [n for n, _ in categories.NUSCENES_CATEGORIES]
    assert len(names) == len(set(names)) == 23
    assert {c.nuscenes for c in categories.CATEGORIES} <= set(names)
    assert set(nuscenes.NOT_LABELLED) <= set(names)
    assert all(categories.from_nuscenes(n) is not None or n in nuscenes.NOT_LABELLED for n in names)
