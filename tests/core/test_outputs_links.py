"""Writes that a link, a swap or a user's file must not redirect (issue 42): a folder of the output tree swapped for
a link after it was made, a link planted where a command's own folder goes, a log hard-linked to a user's file, and
a destination a command replaces whole holding a user's files (``core/outputs.py``)."""

import os

import pytest

from scpainter_blender.core import outputs
from scpainter_blender.core.errors import InputError


def _swap_for_link(folder, target):
    """``folder`` renamed away and a symbolic link to ``target`` put in its place (what an attacker with write
    access to the output folder does between a check and a write)."""
    os.rename(folder, str(folder) + ".moved")
    os.symlink(target, folder)


def test_a_folder_swapped_for_a_link_after_it_was_made_receives_nothing(tmp_path):
    """conditions/ swapped for a link after render made it received frames (7 of 8 trials). The writes now
    happen relative to the folder opened and checked once: a swap is refused by name, nothing lands outside."""
    out, outside = tmp_path / "out", tmp_path / "outside"
    out.mkdir()
    outside.mkdir()
    (outside / "000001.exr").write_bytes(b"a user's file")
    cond = outputs.output_folder(str(out), "conditions")
    with outputs.atomic_write(os.path.join(cond, "000000.exr")) as f:   # before the swap: written
        f.write(b"frame")
    _swap_for_link(cond, outside)
    for write in (lambda: outputs.write_json(os.path.join(cond, "record.json"), {}),
                  lambda: outputs.atomic_write(os.path.join(cond, "000002.exr")).__enter__()):
        with pytest.raises(InputError) as e:
            write()
        assert e.value.path == cond and "replaced" in e.value.message
    with pytest.raises(InputError):   # nor are files deleted through it
        outputs.remove_listed(cond, ["000001.exr"])
    assert outputs.remove_temporaries(cond, ["000001.exr"]) == 0
    assert sorted(os.listdir(outside)) == ["000001.exr"] and (outside / "000001.exr").read_bytes() == b"a user's file"
    assert os.listdir(str(cond) + ".moved") == ["000000.exr"]


@pytest.mark.skipif(not outputs._AT, reason="no *at calls here (Windows): the folder is checked by path")
def test_a_swap_between_the_folder_check_and_the_rename_changes_nothing(tmp_path):
    """The temporary is opened in the folder's descriptor, renamed within it: swapping the folder while a writer
    holds the temporary (here, inside the block) still puts the file in the folder that was checked."""
    out, outside = tmp_path / "out", tmp_path / "outside"
    out.mkdir()
    outside.mkdir()
    cond = outputs.output_folder(str(out), "conditions")
    with outputs.atomic_path(os.path.join(cond, "video.mp4")) as tmp:
        _swap_for_link(cond, outside)
        with open(tmp, "wb") as f:   # a writer that opens by name (PyAV)
            f.write(b"frames")
    assert os.listdir(outside) == [] and os.listdir(str(cond) + ".moved") == ["video.mp4"]


def test_own_folder_never_follows_a_planted_link(tmp_path):
    """vary followed a link at out/v0000 and out/library, export at out/export."""
    out, outside = tmp_path / "out", tmp_path / "outside"
    out.mkdir()
    outside.mkdir()
    os.symlink(outside, out / "library")
    with pytest.raises(InputError) as e:
        outputs.own_folder(str(out), "library")
    assert e.value.path == str(out / "library") and "symbolic link" in e.value.message
    (out / "v0000").write_text("a file")
    with pytest.raises(InputError):
        outputs.own_folder(str(out), "v0000")
    made = outputs.own_folder(str(out), "v0001")
    assert os.path.isdir(made) and not os.path.islink(made) and os.listdir(outside) == []


def test_a_log_hard_linked_to_a_users_file_is_refused(tmp_path):
    """backend.log appended through a hard link to a user's file (a symbolic link was refused already)."""
    mine = tmp_path / "notes.txt"
    mine.write_text("mine\n")
    out = tmp_path / "out"
    out.mkdir()
    os.link(mine, out / "backend.log")
    with pytest.raises(InputError) as e:
        outputs.check_log(str(out / "backend.log"))
    assert "hard link" in e.value.message
    with pytest.raises(InputError):
        outputs.append_text(str(out / "backend.log"), "a line\n")
    assert mine.read_text() == "mine\n"
    fresh = out / "fresh.log"
    outputs.append_text(str(fresh), "a\n")
    outputs.append_text(str(fresh), "b\n")
    assert fresh.read_text() == "a\nb\n"


def _export(path, content, record="export.json"):
    """A folder written whole as an export writes its destination (``replace`` with its record)."""
    with outputs.atomic_folder(path, replace=True, record=record) as tmp:
        for name, text in content.items():
            os.makedirs(os.path.dirname(os.path.join(tmp, name)), exist_ok=True)
            with open(os.path.join(tmp, name), "w") as f:
                f.write(text)
        outputs.write_json(os.path.join(tmp, record), {"format": "test"})


def test_replace_never_deletes_a_file_put_in_the_destination_while_the_command_ran(tmp_path):
    """export --out deleted a user's file created in the destination while the missing frames rendered (2 of 2)."""
    dest = tmp_path / "dest"
    with pytest.raises(InputError) as e:
        with outputs.atomic_folder(str(dest), replace=True, record="export.json") as tmp:
            outputs.write_json(os.path.join(tmp, "export.json"), {})
            dest.mkdir()                                    # meanwhile, the user makes the folder and writes there
            (dest / "thesis.tex").write_text("keep me")
    assert e.value.path == str(dest) and "thesis.tex" in e.value.message
    assert os.listdir(dest) == ["thesis.tex"] and (dest / "thesis.tex").read_text() == "keep me"
    assert sorted(os.listdir(tmp_path)) == ["dest"]     # no temporary left


def test_replace_keeps_a_users_folder_with_a_planted_record(tmp_path):
    """A user's folder holding a planted export.json had its files replaced."""
    dest = tmp_path / "dest"
    dest.mkdir()
    (dest / "export.json").write_text('{"format": "test"}')
    (dest / "thesis.tex").write_text("keep me")
    with pytest.raises(InputError):
        _export(str(dest), {"a.txt": "new"})
    assert sorted(os.listdir(dest)) == ["export.json", "thesis.tex"]
    assert outputs.foreign_files(str(dest), "export.json") == ["thesis.tex"]


def test_replace_takes_its_own_folder_and_fills_an_empty_one(tmp_path):
    dest = tmp_path / "dest"
    dest.mkdir()                                             # the user made it, empty: filled, not replaced
    _export(str(dest), {"a.txt": "one", "sub/b.txt": "two"})
    assert sorted(outputs.created_files(str(dest), "export.json")) == ["a.txt", "sub/b.txt"]
    _export(str(dest), {"c.txt": "three"})                   # its own: replaced whole
    assert sorted(os.listdir(dest)) == ["c.txt", "export.json"]
    (dest / "thesis.tex").write_text("mine")                 # once a user adds a file, it is theirs too
    with pytest.raises(InputError):
        _export(str(dest), {"d.txt": "four"})
    assert sorted(os.listdir(dest)) == ["c.txt", "export.json", "thesis.tex"]
    assert sorted(os.listdir(tmp_path)) == ["dest"]


# ------------------------------------------- issue 42 round 3: an output root or a staging folder swapped later on

def test_an_output_root_swapped_after_its_first_file_gets_no_folder_log_or_file(tmp_path):
    """render: job/out swapped for a link after its first file, then backend.log, conditions/ and frames were
    created in the link's target (fuzz races 7/21/35). The root is registered (``make_folder(root=True)``): its
    subfolders are made name by name from it, the log and every file relative to it, and a swap is refused."""
    out, outside = tmp_path / "out", tmp_path / "outside"
    outside.mkdir()
    root = outputs.make_folder(str(out), "output_dir", root=True)
    outputs.append_text(os.path.join(root, "backend.log"), "first line\n")   # before the swap: written
    _swap_for_link(root, outside)
    for write in (lambda: outputs.make_folder(os.path.join(root, "conditions")),
                  lambda: outputs.output_folder(root, "conditions"),
                  lambda: outputs.append_text(os.path.join(root, "backend.log"), "more\n"),
                  lambda: outputs.write_json(os.path.join(root, "a", "record.json"), {}),
                  lambda: outputs.make_folder(root, "output_dir", root=True)):   # a second check of the root
        with pytest.raises(InputError) as e:
            write()
        assert e.value.path == root and "replaced" in e.value.message
    assert os.listdir(outside) == []
    assert os.listdir(str(out) + ".moved") == ["backend.log"]


def test_a_folder_below_a_registered_one_swapped_later_is_refused(tmp_path):
    """A subfolder made by ``make_folder`` under a registered root (an export writer's ``calib/``) is registered in
    turn: swapped for a link afterwards, a file written into it (``atomic_write``, ``link_or_copy``) is refused."""
    out, outside = tmp_path / "out", tmp_path / "outside"
    outside.mkdir()
    root = outputs.make_folder(str(out), root=True)
    calib = outputs.make_folder(os.path.join(root, "x", "calib"))
    src = tmp_path / "frame.png"
    src.write_bytes(b"png")
    _swap_for_link(calib, outside)
    for write in (lambda: outputs.atomic_write(os.path.join(calib, "000000.txt"), "w").__enter__(),
                  lambda: outputs.link_or_copy(str(src), os.path.join(calib, "000000.png"))):
        with pytest.raises(InputError) as e:
            write()
        assert e.value.path == calib
    assert os.listdir(outside) == []


def test_a_staging_folder_swapped_after_it_was_made_receives_nothing(tmp_path):
    """export: its staging folder ``.kitti.*.tmp`` swapped for a link after it was made, the KITTI writer created
    calib/ and its files in the link's target (fuzz races 4/18/32). The staging folder is made relative to its
    checked parent and registered: the writer's folders and files are refused, and it is never renamed into
    place."""
    out, outside = tmp_path / "out", tmp_path / "outside"
    outside.mkdir()
    root = outputs.make_folder(str(out), root=True)
    dest = os.path.join(root, "kitti")
    with pytest.raises(InputError) as e:
        with outputs.atomic_folder(dest, replace=True, record="export.json") as tmp:
            _swap_for_link(tmp, outside)
            outputs.make_folder(os.path.join(tmp, "calib"))
    assert e.value.path == tmp and "replaced" in e.value.message
    with pytest.raises(InputError):   # nor is a staging folder swapped just before the rename put in place
        with outputs.atomic_folder(dest) as tmp2:
            outputs.write_json(os.path.join(tmp2, "export.json"), {})
            _swap_for_link(tmp2, outside)
    assert os.listdir(outside) == [] and not os.path.lexists(dest)


def test_an_output_root_removed_and_made_again_between_runs_is_taken_anew(tmp_path):
    """One process runs commands one after another (the add-on, the tests): a registered root deleted and made
    again (a real folder, not a link) is the next run's root, and its old subfolders' identities are forgotten;
    a link in its place is still refused."""
    out = tmp_path / "out"
    root = outputs.make_folder(str(out), root=True)
    outputs.output_folder(root, "conditions")
    os.rename(root, str(out) + ".old")
    os.mkdir(root)
    assert outputs.make_folder(root, root=True) == root
    cond = outputs.output_folder(root, "conditions")
    outputs.write_json(os.path.join(cond, "record.json"), {})
    assert os.listdir(cond) == ["record.json"]
    _swap_for_link(root, tmp_path)
    with pytest.raises(InputError):
        outputs.make_folder(root, root=True)


def test_a_write_error_names_the_output_not_the_folders_descriptor_alias(tmp_path):
    """In a registered folder ``atomic_path`` yields ``/proc/self/fd/N/<temporary>``; an error a writer raised
    naming that alias (a copy's ``filename2``, as shutil sets it, or a full disk naming no file) names the output
    instead, so the full-disk error names the user's folder (fuzz diskfull 27 named ``/proc/self/fd/3``)."""
    import errno
    import shutil

    root = outputs.make_folder(str(tmp_path / "out"), "output_dir", root=True)
    target = os.path.join(root, "frame.png")
    for raised in (lambda where: OSError(errno.ENOSPC, "No space left on device", "src.png", None, where),
                   lambda where: OSError(errno.ENOSPC, "No space left on device")):
        with pytest.raises(OSError) as e:
            with outputs.atomic_path(target) as where:
                if os.path.isdir("/proc/self/fd"):
                    assert where.startswith("/proc/self/fd/")
                raise raised(where)
        assert e.value.filename2 in (None, target) and e.value.filename in ("src.png", target)
        assert "/proc/self/fd" not in str(e.value)
    assert os.listdir(root) == []
    shutil.rmtree(root)
