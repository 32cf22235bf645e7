"""A variation run reads only what a render of its base may read, trusts no more in its list, takes its folder's
lock, never overwrites a user's files, and a killed run's folder is never taken as whole (issue 42;
``core/variation/variants.py``). Refusals come before the road is found (cheap); the runs use the street's drive
with no cars (no library)."""

import json
import os

import pytest

from scpainter_blender.core import batch_items, errors, job as J, locking
from scpainter_blender.core.output_layout import VariationLayout
from scpainter_blender.core.variation import spec as spec_mod, variants
from tests_support import street_base_job


def spec(**kw):
    base = dict(variants=2, seed=3, shifts_m=(0.0,), resolution=(64, 36), car_count=(0, 0))
    base.update(kw)
    return spec_mod.VariationSpec(**base)


def test_a_base_reading_outside_its_folder_is_refused_as_render_refuses_it(street, tmp_path):
    """vary read a base job's ../secret/… recording and wrote `data-root: …/secret` into variants.txt, so `batch
    --list` read it with no flag. Now: refused naming the field, unless the folder is a --data-root (or
    --allow-outside), and nothing is written."""
    base = str(tmp_path / "base" / "job.json")
    street_base_job(street, base)                       # it reads the street's recording, outside its folder
    out = tmp_path / "out"
    with pytest.raises(J.JobError) as e:
        variants.make_variants(base, spec(), str(out))
    assert e.value.path == base and e.value.field == "scene.predictions" and "outside" in e.value.message
    assert not out.exists()
    from backend.__main__ import main
    assert main(["vary", base, "--out", str(out), "--variants", "1"]) == 2 and not out.exists()


def test_a_folder_name_that_would_inject_list_lines_is_refused(street, tmp_path):
    """A base job whose folder name held a newline put a `data-root: /` line and another job into variants.txt."""
    folder = tmp_path / "rec\ndata-root: " / "etc"       # read back: "data-root: …/rec", "data-root: /etc"
    folder.mkdir(parents=True)
    try:
        os.link(street.predictions_path, folder / "predictions.npz")
    except OSError:
        pytest.skip("no hard links here")
    base = str(folder / "job.json")
    job = street_base_job(street, base)
    job.scene.predictions = "predictions.npz"             # inside its own folder: confinement passes
    J.save(base, job)
    out = tmp_path / "out"
    with pytest.raises(errors.InputError) as e:
        variants.make_variants(base, spec(), str(out))
    assert e.value.field == "scene.predictions" and "control character" in e.value.message
    assert not os.path.exists(out / VariationLayout.LIST)


def test_vary_takes_the_folders_lock_and_never_overwrites_a_users_files(street, tmp_path):
    base = str(tmp_path / "base" / "job.json")
    street_base_job(street, base)
    out = tmp_path / "out"
    out.mkdir()
    with locking.OutputLock(str(out), "vary"):              # another run holds it: refused, nothing written
        with pytest.raises(errors.InputError) as e:
            variants.make_variants(base, spec(), str(out), data_roots=(street.root,))
        assert "another run" in e.value.message and e.value.path == str(out) and os.listdir(out) == [".scpainter.lock"]
    (out / "variants.txt").write_text("my own list\n")     # a user's files with vary's names: never overwritten
    (out / "v0001").mkdir()
    (out / "v0001" / "job.json").write_text("{}")
    (out / "notes.md").write_text("mine")
    with pytest.raises(errors.InputError) as e:
        variants.make_variants(base, spec(), str(out), data_roots=(street.root,))
    assert e.value.path == str(out / "v0001") and e.value.field == "--out"
    assert (out / "variants.txt").read_text() == "my own list\n" and (out / "v0001" / "job.json").read_text() == "{}"
    assert sorted(os.listdir(out)) == ["notes.md", "v0001", "variants.txt"]
    os.remove(out / "variants.txt")
    os.symlink(tmp_path, out / "library")                   # a planted link where vary writes: refused
    (tmp_path / "other").mkdir()
    os.rename(out / "v0001", tmp_path / "other" / "v0001")
    outputs_manifest = {"schema": variants.MANIFEST_SCHEMA, "files": ["library"], "variants": []}
    (out / "variation.json").write_text(json.dumps(outputs_manifest))
    with pytest.raises(errors.InputError) as e:
        variants.make_variants(base, spec(), str(out), data_roots=(street.root,))
    assert e.value.path == str(out / "library") and "symbolic link" in e.value.message


class Killed(BaseException):
    """What SIGKILL does to the run, at a chosen point (here: after the first variant)."""


def test_a_killed_run_leaves_no_list_and_its_next_run_cleans_up(street, tmp_path):
    """A vary killed mid-run left its folder mixed (4 of 8): the old list named jobs the new run had rewritten."""
    base = str(tmp_path / "base" / "job.json")
    street_base_job(street, base)
    out = tmp_path / "out"
    layout = VariationLayout(str(out))
    first = variants.make_variants(base, spec(variants=3), str(out), data_roots=(street.root,))
    assert first["state"] == "complete" and first["summary"]["placed"] == 3
    listed = batch_items.read_job_list(layout.list)
    # the list trusts the run's folder and what the user trusted, nothing more
    assert all(r == str(out) or r.startswith(os.path.realpath(street.root)) for r in listed.data_roots)

    def kill_after_first(done, total):
        if done == 1:
            raise Killed

    with pytest.raises(Killed):
        variants.make_variants(base, spec(variants=3, seed=9), str(out), data_roots=(street.root,),
                               progress=kill_after_first)
    assert not os.path.exists(layout.list)                  # batch finds no list to take as whole
    with pytest.raises(errors.InputError):
        batch_items.read_job_list(layout.list)
    os.mkdir(out / ".v0002.half.tmp")                       # killed while variant 2's folder was built
    running = json.loads(open(layout.manifest).read())
    assert running["state"] == "running" and {"v0000", "v0001", "v0002"} <= set(running["files"])
    again = variants.make_variants(base, spec(variants=1, seed=9), str(out), data_roots=(street.root,))
    assert again["state"] == "complete" and again["removed"] == ["v0001", "v0002"]
    assert sorted(os.listdir(out)) == ["v0000", "variants.txt", "variation.json"]
    assert batch_items.read_job_list(layout.list).paths == [str(out / "v0000" / "job.json")]
    # a link planted where a variant of this run goes is refused, never written through
    outside = tmp_path / "outside"
    outside.mkdir()
    os.rename(out / "v0000", tmp_path / "v0000.moved")
    os.symlink(outside, out / "v0000")
    with pytest.raises(errors.InputError) as e:
        variants.make_variants(base, spec(variants=1, seed=9), str(out), data_roots=(street.root,))
    assert e.value.path == str(out / "v0000") and "symbolic link" in e.value.message
    assert os.listdir(outside) == []


def test_a_rerun_removes_the_temporaries_a_killed_run_left_in_its_variant_folders(street, tmp_path):
    """Issue 42 (fuzz varykill 8): a run killed before renaming a variant's job.json left `v0001/.job.json.….tmp`,
    which the next run kept. Now the next run removes the temporaries of the names it writes there, and only
    those (a render's temporary of another name in the folder stays)."""
    base = str(tmp_path / "base" / "job.json")
    street_base_job(street, base)
    out = tmp_path / "out"
    first = variants.make_variants(base, spec(), str(out), data_roots=(street.root,))
    assert first["summary"]["placed"] == 2
    (out / "v0001" / ".job.json.0f2c2660.tmp").write_text('{"half')       # killed before its rename
    (out / "v0001" / ".frames.json.0f2c2660.tmp").write_text("a render's")  # not a name vary writes
    again = variants.make_variants(base, spec(), str(out), data_roots=(street.root,))
    assert again["summary"]["placed"] == 2
    assert sorted(os.listdir(out / "v0001")) == [".frames.json.0f2c2660.tmp", "job.json"]
