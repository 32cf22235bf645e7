"""Variants of the street's drive (core/variation/variants.py), checked against the street's ground truth: the
parked cars' true boxes, the kerbs at |x| = 7.25 m, the true road plane z = 0."""

import json
import os

import numpy as np
import pytest

from scpainter_blender.core import job as J, shapes
from scpainter_blender.core.geometry import boxes, cameras
from scpainter_blender.core.batch_items import DATA_ROOT_DIRECTIVE
from scpainter_blender.core.output_layout import VariationLayout
from scpainter_blender.core.variation import placement, spec as spec_mod, variants
from tests_support import street_base_job, street_parked_cars

ROAD_HALF_WIDTH = 7.25  # street/build.py PARKING_HALF: the kerbs' inner faces


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    d = tmp_path_factory.mktemp("library")
    shapes.save_as_amodal3r(str(d / "blue.ply"), shapes.procedural_car_gaussians(count=8000, seed=7,
                                                                                paint=(0.1, 0.3, 0.8)))
    shapes.save_as_amodal3r(str(d / "red.ply"), shapes.procedural_car_gaussians(count=8000, seed=8,
                                                                               paint=(0.8, 0.1, 0.1)))
    return str(d)


@pytest.fixture(scope="module")
def bases(street, tmp_path_factory):
    d = tmp_path_factory.mktemp("bases")
    return (street_base_job(street, str(d / "plain" / "job.json")) and str(d / "plain" / "job.json"),
            street_base_job(street, str(d / "recorded" / "job.json"), recorded_cars=True)
            and str(d / "recorded" / "job.json"))


def make(base, sp, out, **kw):
    """``make_variants`` with the base's paths allowed anywhere: these bases read the street's cache and cars
    beside their folders (confinement has its own tests, test_variants_confinement.py)."""
    return variants.make_variants(base, sp, out, allow_outside=True, **kw)


def spec(library, **kw):
    base = dict(variants=12, seed=5, library=library, shifts_m=(-2.0, 0.0, 2.0), resolution=(128, 72),
                lane_change_probability=0.3, car_count=(1, 3))
    base.update(kw)
    return spec_mod.VariationSpec(**base)


@pytest.fixture(scope="module")
def run(bases, library, tmp_path_factory):
    out = str(tmp_path_factory.mktemp("vary") / "out")
    return out, make(bases[0], spec(library), out)


def _jobs(out, manifest):
    return {e["id"]: J.load(os.path.join(out, e["job"])) for e in manifest["variants"] if e["job"]}


def test_same_seed_same_jobs_and_variant_i_independent_of_the_count(run, bases, library, tmp_path):
    out, manifest = run
    again = make(bases[0], spec(library), str(tmp_path / "again"))
    fewer = make(bases[0], spec(library, variants=5), str(tmp_path / "fewer"))
    assert again["variants"] == manifest["variants"]
    assert fewer["variants"] == manifest["variants"][:5]
    for e in manifest["variants"]:
        if e["job"]:
            with open(os.path.join(out, e["job"]), "rb") as a, open(tmp_path / "again" / e["job"], "rb") as b:
                assert a.read() == b.read()
    other = make(bases[0], spec(library, seed=6), str(tmp_path / "other"))
    assert other["variants"] != manifest["variants"]


def test_manifest_list_and_jobs_agree(run, bases):
    out, manifest = run
    base = J.load(bases[0])
    layout = VariationLayout(out)
    s = manifest["summary"]
    assert s["variants"] == 12 and s["placed"] + s["unplaced"] == 12 and s["placed"] >= 9
    with open(layout.list) as f:
        lines = [line.strip() for line in f if line.strip() and not line.startswith("#")]
    roots = [line.split(":", 1)[1].strip() for line in lines if line.startswith(DATA_ROOT_DIRECTIVE)]
    listed = [line for line in lines if not line.startswith(DATA_ROOT_DIRECTIVE)]
    assert listed == [e["job"] for e in manifest["variants"] if e["outcome"] == "placed"]
    assert "." in roots                         # the run's own folder, relative: the folder moves as a whole
    jobs = _jobs(out, manifest)
    assert sum(len(j.assets) for j in jobs.values()) == s["cars"] == sum(s["per_asset"].values())
    for e in manifest["variants"]:
        if e["outcome"] != "placed":
            continue
        job = jobs[e["id"]]
        assert job.resolution == (128, 72) and job.output_dir == "."
        assert [a.name for a in job.assets] == [c["name"] for c in e["cars"]]
        assert all(a.box is not None and a.category == "car" for a in job.assets)   # labelled
        # frame 1 (before any lane change) is the drive moved by the shift to the left (the street runs along +y,
        # left is -x), at the same height
        moved = cameras.camera_centers(job.frames[0].world_to_camera) - \
            cameras.camera_centers(base.frames[0].world_to_camera)
        assert -moved[0] == pytest.approx(e["camera"]["shift_m"], abs=0.02) and abs(moved[2]) < 1e-9


def test_no_placed_car_breaks_a_rule(run, street):
    """Against the street's truth: every car on the road surface (inside the kerbs, on z = 0), clear of the
    parked cars (found from the points alone: no boxes in this base), of the other cars and of the ego path (its
    2.0 x 4.8 m rectangle around each camera)."""
    out, manifest = run
    parked = street_parked_cars(street)
    for e in manifest["variants"]:
        if e["outcome"] != "placed":
            continue
        job = J.load(os.path.join(out, e["job"]))
        ego = np.stack([placement.rectangle(cameras.camera_centers(f.world_to_camera)[:2], np.array([0.0, 1.0]),
                                            4.8, 2.0) for f in job.frames])
        # the camera path itself: inside the kerbs, clear of the parked cars, lane change included
        assert np.abs(ego[..., 0]).max() < ROAD_HALF_WIDTH + 0.05, e["id"]
        for T, size in parked:
            assert not placement.rectangles_overlap(ego, placement.box_footprint(T, size)).any(), e["id"]
        feet, mode = {}, {c["name"]: c["mode"] for c in e["cars"]}
        for a in job.assets:
            for f in job.frames:
                T, size = boxes.place_box(a.box.box_to_file, a.box.size, a.object_to_world[f.frame])
                c = boxes.corners(T, size)
                assert np.abs(c[:, 0]).max() < ROAD_HALF_WIDTH + 0.05, (e["id"], a.name)
                assert c[:, 2].min() == pytest.approx(0.0, abs=0.05)          # on the road plane
                feet[(a.name, f.frame)] = placement.box_footprint(T, size)
        for (name, frame), foot in feet.items():
            for T, size in parked:
                assert not placement.rectangles_overlap(foot, placement.box_footprint(T, size)), (e["id"], name)
            # parked: clear of the whole swept ego path; moving: of the ego at that frame and a second after
            near = ego if mode[name] == "parked" else ego[frame - 1:frame + int(job.fps)]
            assert not placement.rectangles_overlap(foot, near).any(), (e["id"], name)
            for (other, f2), foot2 in feet.items():
                if f2 == frame and other != name:
                    assert not placement.rectangles_overlap(foot, foot2), (e["id"], name, other)


def test_camera_paths_that_leave_the_road_are_drawn_again(bases, library, tmp_path):
    """Shifts of ±6 m put the ego on the kerb or into the parked cars: each such path is drawn again and counted;
    a variant whose every draw fails is reported as the camera's."""
    m = make(bases[0], spec(library, variants=6, shifts_m=(-6.0, -6.5, 0.0)), str(tmp_path / "c"))
    rej = m["summary"]["rejections"]
    assert rej["camera_off_road"] + rej["camera_blocked"] > 0
    assert all(e["camera"]["shift_m"] == 0.0 for e in m["variants"] if e["outcome"] == "placed")
    m = make(bases[0], spec(library, variants=2, shifts_m=(-6.5,), tries=3), str(tmp_path / "d"))
    assert [e["outcome"] for e in m["variants"]] == ["unplaced", "unplaced"]
    assert m["variants"][0]["unplaced"]["what"] == "camera" and "the camera path" in \
        variants.unplaced_text(m["variants"][0])
    assert m["warnings"] == ["no variant could be placed (2 tried)"]


def test_moving_cars_stay_on_the_road_every_frame(run):
    out, manifest = run
    moving = 0
    for e in manifest["variants"]:
        if e["outcome"] != "placed":
            continue
        job = J.load(os.path.join(out, e["job"]))
        for a, car in zip(job.assets, e["cars"]):
            if car["mode"] != "moving":
                continue
            moving += 1
            centres = []
            for f in job.frames:
                T, size = boxes.place_box(a.box.box_to_file, a.box.size, a.object_to_world[f.frame])
                bottom = T[:3, 3] - T[:3, 2] * size[2] / 2
                assert bottom[2] == pytest.approx(0.0, abs=0.03)
                assert abs(bottom[0]) + size[0] / 2 < ROAD_HALF_WIDTH + 0.05
                centres.append(T[:3, 3])
            step = np.linalg.norm(np.diff(np.array(centres)[:, :2], axis=0), axis=1)
            assert step.mean() * job.fps == pytest.approx(car["speed_mps"], rel=0.05)  # at its drawn speed
    assert moving >= 3


def test_every_car_is_placement_drive(run, bases, library, tmp_path):
    """The variants' cars are ``placement.drive``'s poses (the one function *Drive Along Lane* keys too): from
    each car's drawn lane and speed and where it stands at the first frame, on the run's road and path."""
    out, manifest = run
    v = variants.Variation(bases[0], spec(library), str(tmp_path / "v"), allow_outside=True)
    checked = 0
    for e in manifest["variants"]:
        if e["outcome"] != "placed":
            continue
        job = J.load(os.path.join(out, e["job"]))
        t = (np.array([f.frame for f in job.frames], np.float64) - job.frames[0].frame) / job.fps
        for a, car in zip(job.assets, e["cars"]):
            moving = car["mode"] == "moving"
            lane, speed = (car["lane_offset_m"], car["speed_mps"]) if moving else (car["offset_m"], 0.0)
            start = v.path.project(car["position_m"][:2])[0]
            size = np.array(car["size_m"])
            _, poses = placement.drive(v.road, v.path, size, lane, speed, start, t if moving else t[:1])
            for f, T in zip(job.frames, poses if moving else poses * len(job.frames)):
                got, _ = boxes.place_box(a.box.box_to_file, a.box.size, a.object_to_world[f.frame])
                assert np.abs(got - T).max() < 0.01   # the start projected back: mm on the path's bends
            checked += 1
    assert checked >= 6


def test_recorded_boxes_are_avoided_and_counted(bases, library, street, tmp_path):
    m = make(bases[1], spec(library, variants=8, car_count=(2, 3)), str(tmp_path / "r"))
    assert m["summary"]["rejections"]["recorded_box"] > 0
    parked = street_parked_cars(street)
    for e in m["variants"]:
        if e["job"]:
            job = J.load(os.path.join(str(tmp_path / "r"), e["job"]))
            for a in job.assets:
                T, size = boxes.place_box(a.box.box_to_file, a.box.size, a.object_to_world[1])
                grown = placement.box_footprint(T, size, grow=0.45)
                assert not any(placement.rectangles_overlap(grown, placement.box_footprint(P, s)) for P, s in parked)


def test_a_variant_that_cannot_be_placed_is_reported(bases, library, tmp_path):
    """Eight cars with one try each do not fit: each such variant is in the manifest with its reasons, not in
    the list, and no job of an earlier run stays in its folder."""
    out = str(tmp_path / "u")
    first = make(bases[0], spec(library, variants=4, car_count=(1, 1)), out)
    assert all(e["job"] for e in first["variants"])
    job0 = VariationLayout(out).variant(0).job
    mtime = os.stat(job0).st_mtime_ns
    again = make(bases[0], spec(library, variants=4, car_count=(1, 1)), out)
    assert again["variants"] == first["variants"] and os.stat(job0).st_mtime_ns == mtime   # unchanged: not rewritten
    m = make(bases[0], spec(library, variants=3, car_count=(8, 8), tries=1), out)
    bad = [e for e in m["variants"] if e["outcome"] == "unplaced"]
    assert bad and m["summary"]["unplaced"] == len(bad)
    for e in bad:
        assert e["job"] is None and e["unplaced"]["tries"] == 1 and e["unplaced"]["what"] == "car"
        assert sum(e["unplaced"]["rejections"].values()) == 1
        assert not os.path.exists(VariationLayout(out).variant(int(e["id"][1:])).root)   # the earlier run's folder
    assert "v0003" in m["removed"] and not os.path.exists(VariationLayout(out).variant(3).root)  # beyond the count
    with open(VariationLayout(out).list) as f:
        assert not any(e["id"] in line for e in bad for line in f)
    # the summary counts what the jobs hold
    placed = [e for e in m["variants"] if e["outcome"] == "placed"]
    assert m["summary"]["cars"] == sum(len(e["cars"]) for e in placed)
    assert sum(m["summary"]["per_shift"].values()) == len(placed)


def test_spec_file_errors_name_the_field(tmp_path):
    def bad(content, field):
        p = tmp_path / "spec.json"
        p.write_text(json.dumps(content))
        with pytest.raises(spec_mod.VariationError) as e:
            spec_mod.load(p)
        assert e.value.field == field and e.value.path == str(p)

    bad({"variants": 0}, "variants")
    bad({"camera": {"shifts_m": []}}, "camera.shifts_m")
    bad({"cars": {"count": [3, 1]}}, "cars.count")
    bad({"cars": {"speed_mps": [1, "fast"]}}, "cars.speed_mps[1]")
    bad({"cars": {"colour": 1}}, "cars.colour")
    bad({"placement": {"tries": 0}}, "placement.tries")
    bad({"schema": "scpainter.job/2"}, "schema")
    (tmp_path / "ok.json").write_text(json.dumps({"cars": {"library": "lib"}, "camera": {"shifts_m": {"min": -3,
                                                                                                     "max": 3}}}))
    s = spec_mod.load(tmp_path / "ok.json")
    assert s.library == str(tmp_path / "lib") and s.shift_range_m == (-3.0, 3.0)


def test_a_base_without_points_or_library_is_refused(bases, library, tmp_path):
    job = J.load(bases[0])
    job.scene = None
    J.save(tmp_path / "none" / "job.json", job)
    with pytest.raises(spec_mod.VariationError) as e:
        make(str(tmp_path / "none" / "job.json"), spec(library), str(tmp_path / "o"))
    assert e.value.field == "scene"
    with pytest.raises(spec_mod.VariationError) as e:
        make(bases[0], spec(None), str(tmp_path / "o"))
    assert e.value.field == "cars.library"


def test_every_setting_has_its_file_field():
    import dataclasses

    attrs = {f.name for f in dataclasses.fields(spec_mod.VariationSpec)}
    assert {attr for _, attr, *_ in spec_mod.FIELDS} | {"shift_range_m"} == attrs   # (the range: shifts_m's form)


def test_the_manifest_spec_is_a_spec_file(run, library, tmp_path):
    """The manifest records the run's settings as a spec file (the file's names, every field): fed back, the same
    settings."""
    out, manifest = run
    (tmp_path / "again.json").write_text(json.dumps(manifest["spec"]))
    assert spec_mod.load(tmp_path / "again.json") == spec(library)
    ranged = spec_mod.VariationSpec(shift_range_m=(-3.0, 3.0), library=str(tmp_path))
    assert spec_mod.from_dict(spec_mod.to_file(ranged), str(tmp_path / "s.json")) == ranged


def test_a_library_object_that_is_no_car_is_refused(tmp_path):
    """A car stood on its end (taller than long), and one in millimetres."""
    from scpainter_blender.core.splats import inria, gaussians as splats
    from scpainter_blender.core.variation import library as library_mod

    g = shapes.procedural_car_gaussians(count=3000, seed=1)
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])     # its length (y) turned up (z)
    tall = shapes.transform_gaussians(g, np.block([[R, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]))
    inria.write_ply(tmp_path / "tall.ply", splats.encode(tall))
    with pytest.raises(spec_mod.VariationError, match="not shaped like a road vehicle") as e:
        library_mod.load_asset(tmp_path / "tall.ply", str(tmp_path / "cache"))
    assert e.value.path == str(tmp_path / "tall.ply")
    mm = shapes.transform_gaussians(g, np.diag([1000.0, 1000.0, 1000.0, 1.0]))
    inria.write_ply(tmp_path / "mm.ply", splats.encode(mm))
    with pytest.raises(spec_mod.VariationError, match="millimetres"):
        library_mod.load_asset(tmp_path / "mm.ply", str(tmp_path / "cache"))


def _wide_cloud(path, size=(5.8, 9.2, 1.5)):
    """The field case (issue 42): a splat cloud 9.2 m long and 5.8 m wide (a car captured with the ground around
    it), metric and Z up: the procedural car stretched to that box."""
    from scpainter_blender.core.splats import inria, gaussians as splats

    g = shapes.procedural_car_gaussians(count=3000, seed=1)
    k = (np.array(size) / (g.means.max(0) - g.means.min(0))).astype(np.float32)
    inria.write_ply(path, splats.encode(splats.Gaussians(g.means * k, g.scales, g.quats, g.opacities, g.sh)))
    return path


def test_a_library_object_wider_or_flatter_than_any_vehicle_is_refused(tmp_path):
    """The stated rule (library.vehicle_shape_problem): a 9.2 x 5.8 m cloud was accepted as a car; now refused
    naming its width and the bound. Real vehicles pass: a city car, a bus, a Formula 1 car."""
    from scpainter_blender.core.variation import library as library_mod

    with pytest.raises(spec_mod.VariationError, match=r"5\.80 m wide \(9\.20 m long, 1\.50 m high\), wider than the "
                                                      r"3 m any road vehicle is") as e:
        library_mod.load_asset(_wide_cloud(tmp_path / "wide.ply"), str(tmp_path / "cache"))
    assert e.value.path == str(tmp_path / "wide.ply") and e.value.hint == library_mod.SHAPE_HINT
    for width, length, height in ((1.66, 2.7, 1.55), (2.55, 12.0, 3.2), (2.0, 5.6, 0.95), (2.5, 16.5, 4.0)):
        assert library_mod.vehicle_shape_problem(width, length, height) is None, (width, length, height)
    for box, says in (((2.0, 4.5, 5.0), "taller than the 4.5 m"), ((2.0, 4.5, 0.3), "flatter than a tenth"),
                      ((1.8, 4.4, 4.41), "4.41 m high for 4.40 m long"), ((1.8, 4400, 1500), "millimetres")):
        assert says in library_mod.vehicle_shape_problem(*box), box


def test_a_bad_library_file_names_itself_and_skip_bad_leaves_it_out(tmp_path):
    """Issue 42: one unreadable library file aborted the run. Without --skip-bad its error still stops it, naming
    the file and suggesting --skip-bad; with it (``skipped``) the bad files are left out, each with its reason."""
    from scpainter_blender.core import errors
    from scpainter_blender.core.variation import library as library_mod

    lib = tmp_path / "cars"
    lib.mkdir()
    shapes.save_as_amodal3r(str(lib / "blue.ply"), shapes.procedural_car_gaussians(count=2000, seed=7))
    (lib / "broken.ply").write_bytes((lib / "blue.ply").read_bytes()[:700])   # cut mid-data
    _wide_cloud(lib / "wide.ply")
    with pytest.raises(errors.InputError) as e:
        library_mod.load_library(str(lib), str(tmp_path / "cache"))
    assert e.value.path == str(lib / "broken.ply") and "--skip-bad" in e.value.hint
    skipped = []
    cars = library_mod.load_library(str(lib), str(tmp_path / "cache"), skipped=skipped)
    assert [c.name for c in cars] == ["blue.ply"]
    assert [s["file"] for s in skipped] == [str(lib / "broken.ply"), str(lib / "wide.ply")]
    assert "broken.ply" in skipped[0]["reason"] and "5.80 m wide" in skipped[1]["reason"]
    assert library_mod.skipped_text(skipped[1]).startswith("library file wide.ply left out (--skip-bad): ")
    (lib / "blue.ply").unlink()
    with pytest.raises(spec_mod.VariationError, match="none of its 2 car files can be used") as e:
        library_mod.load_library(str(lib), str(tmp_path / "cache"), skipped=[])
    assert e.value.field == "cars.library"


def test_the_base_jobs_own_cars_are_obstacles(bases, library, tmp_path):
    """A car the base already holds, without a box (estimated, whatever its shape: the user placed it), is never
    overlapped; here it stands across the right lane, in every parked car's and moving car's way."""
    from scpainter_blender.core.splats import gaussians as splats, inria

    job = J.load(bases[0])
    g = shapes.procedural_car_gaussians(count=3000, seed=2)
    inria.write_ply(tmp_path / "base_car.ply", splats.encode(g))
    at = np.eye(4)
    at[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])   # turned across the road
    at[:3, 3] = [3.5, 18.0, 0.0]
    job.assets = [J.Asset("parked_base", str(tmp_path / "base_car.ply"), {f.frame: at for f in job.frames})]
    J.save(tmp_path / "b" / "job.json", job)
    m = make(str(tmp_path / "b" / "job.json"), spec(library, variants=6), str(tmp_path / "o"))
    assert m["summary"]["rejections"]["recorded_box"] > 0          # it was in the way, and kept out of it
    foot = placement.box_footprint(*boxes.rigid_box(at @ np.diag([1.8, 4.4, 1.6, 1.0]) @
                                                   np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.5],
                                                             [0, 0, 0, 1.0]])))
    for e in m["variants"]:
        if e["job"]:
            v = J.load(tmp_path / "o" / e["job"])
            assert v.assets[0].name == "parked_base"
            for a in v.assets[1:]:
                for f in v.frames:
                    T, size = boxes.place_box(a.box.box_to_file, a.box.size, a.object_to_world[f.frame])
                    assert not placement.rectangles_overlap(placement.box_footprint(T, size), foot), e["id"]


def test_variant_cars_never_take_a_name_of_the_bases_cars(bases, library, tmp_path):
    """The base's own cars (here ``car_01`` and ``car_03``, labelled: class and box) are kept in every variant as
    they are, and the drawn cars take the free names: the variant jobs load (asset names are unique in a job)."""
    from scpainter_blender.core.splats import gaussians as splats, inria

    job = J.load(bases[0])
    g = shapes.procedural_car_gaussians(count=3000, seed=2)
    inria.write_ply(tmp_path / "base_car.ply", splats.encode(g))
    box = J.AssetBox(np.eye(4), np.array([1.8, 4.4, 1.6]))
    at = [np.eye(4), np.eye(4)]
    at[0][:3, 3], at[1][:3, 3] = [5.5, 30.0, 0.8], [-5.5, 40.0, 0.8]   # parked at the kerbs, out of the way
    job.assets = [J.Asset(name, str(tmp_path / "base_car.ply"), {f.frame: T for f in job.frames}, "car", box)
                  for name, T in zip(("car_01", "car_03"), at)]
    J.save(tmp_path / "b" / "job.json", job)
    m = make(str(tmp_path / "b" / "job.json"), spec(library, variants=3, car_count=(2, 2)),
                               str(tmp_path / "o"))
    placed = [e for e in m["variants"] if e["job"]]
    assert placed
    for e in placed:
        v = J.load(tmp_path / "o" / e["job"])                      # validates: no name twice
        assert [c["name"] for c in e["cars"]] == ["car_02", "car_04"]
        assert [a.name for a in v.assets] == ["car_01", "car_03", "car_02", "car_04"]
        for mine, theirs in zip(v.assets[:2], job.assets):        # the base's cars, labelled as in the base
            assert mine.category == theirs.category == "car"
            assert np.array_equal(mine.box.box_to_file, theirs.box.box_to_file)
            assert np.array_equal(mine.box.size, theirs.box.size)
            assert all(np.array_equal(mine.object_to_world[f], theirs.object_to_world[f]) for f in mine.object_to_world)


def test_car_names_skip_the_taken_ones():
    assert variants.car_names(3, []) == ["car_01", "car_02", "car_03"]
    assert variants.car_names(3, ["car_01", "car_03", "truck"]) == ["car_02", "car_04", "car_05"]
    assert variants.car_names(0, ["car_01"]) == []


def test_recolouring_removes_the_temporaries_a_killed_run_left_for_its_file(tmp_path):
    """Issue 42 (fuzz varykill 4, 9): a run killed before renaming a recoloured car left
    `library/.car.ply.<key>.hue+019.ply.<random>.tmp`, which the re-run kept. Now writing that file first removes
    the temporaries left for its name, and only those."""
    from scpainter_blender.core.variation import library as library_mod

    shapes.save_as_amodal3r(str(tmp_path / "car.ply"), shapes.procedural_car_gaussians(count=2000, seed=7))
    asset = library_mod.load_asset(tmp_path / "car.ply", str(tmp_path / "library"))
    folder = tmp_path / "library"
    folder.mkdir()
    name = os.path.basename(asset.recoloured(19, str(tmp_path / "elsewhere")))   # the name it writes
    (folder / f".{name}.0f2c2660.tmp").write_bytes(b"ply\nhalf")               # killed before its rename
    (folder / f".{name[:-4]}.other.ply.0f2c2660.tmp").write_bytes(b"not ours")  # another name's: stays
    out = asset.recoloured(19, str(folder))
    assert sorted(os.listdir(folder)) == sorted([name, f".{name[:-4]}.other.ply.0f2c2660.tmp"])
    assert os.path.basename(out) == name
