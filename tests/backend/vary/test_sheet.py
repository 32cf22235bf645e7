"""backend/vary/sheet.py: ``contact-sheet`` on hostile manifests and variant folders (issue 42: 10 of 11 cases
failed, one by allocating 17.8 GiB for vary's own maximum of 100,000 variants). Every field the sheet reads is
checked by name (exit 2), what a manifest can make it allocate is bounded (``MAX_TILES``, ``MAX_TILE_HEIGHT``, a
preview's size from its header), only files inside the folder are read (no links out, no FIFO waited on, no
non-image decoded), and the sheet is written whole or not at all. In-process, on tiny synthetic folders."""

import json
import os

import numpy as np
import pytest

from backend.__main__ import main
from backend.png import write_png
from backend.vary import sheet as S
from scpainter_blender.core import backend_protocol as protocol
from scpainter_blender.core.output_layout import CONDITION_PREVIEW, OutputLayout, VariationLayout
from scpainter_blender.core.variation.spec import MAX_VARIANTS


def entry(i, outcome="placed", **edit):
    e = {"id": VariationLayout.variant_name(i), "outcome": outcome, "seed": [0, i],
         "camera": {"shift_m": -2.0, "lane_change": {"shift_m": 3.5}},
         "cars": [{"mode": "parked", "rejections": {}}],
         "unplaced": {"car": None, "rejections": {"gap": 3}} if outcome == "unplaced" else None}
    e.update(edit)
    return e


def rendered_variant(root, i, rgb):
    """A variant folder as vary and a render leave it: its job, then its render record and a preview."""
    layout = OutputLayout(os.path.join(root, VariationLayout.variant_name(i)))
    os.makedirs(layout.conditions)
    with open(layout.job, "w") as f:
        f.write("{}")
    with open(layout.record, "w") as f:
        f.write("{}")
    os.utime(layout.job, ns=(1, 1))
    write_png(os.path.join(layout.conditions, CONDITION_PREVIEW.name(1)), rgb)
    return layout


def folder(tmp_path, entries, name="v"):
    root = tmp_path / name
    root.mkdir()
    (root / VariationLayout.MANIFEST).write_text(json.dumps(entries if not isinstance(entries, list)
                                                            else {"variants": entries}))
    return root


def run(root, capsys):
    code = main(["contact-sheet", str(root)])
    evs = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.strip()]
    return code, evs


@pytest.mark.parametrize("manifest,field", [
    ("a string", "(top level)"),                                                    # wrong types
    ({"variant": []}, "variants"),                                                  # a missing field
    ([], "variants"),
    (["v0000"], "variants[0]"),
    ([entry(0, id=5)], "variants[0].id"),
    ([entry(0, id="../../etc")], "variants[0].id"),                                 # a path out of the folder
    ([entry(0, id="/tmp")], "variants[0].id"),
    ([entry(0, outcome=None)], "variants[0].outcome"),
    ([entry(0, camera={"shift_m": "left"})], "variants[0].camera.shift_m"),
    ([entry(0, camera={"shift_m": 10 ** 310})], "variants[0].camera.shift_m"),
    ([entry(0, camera={"shift_m": 1.0, "lane_change": 7})], "variants[0].camera.lane_change"),
    ([entry(0, cars={"mode": "parked"})], "variants[0].cars"),
    ([entry(0, cars=[{"mode": 3}])], "variants[0].cars[0].mode"),
    ([entry(0, cars=[{"mode": "parked"}] * 65)], "variants[0].cars"),
    ([entry(0, "unplaced", unplaced={"rejections": {"gap": "many"}})], "variants[0].unplaced.rejections.gap"),
    ([entry(0, "unplaced", unplaced=[])], "variants[0].unplaced"),
])
def test_a_hostile_manifest_is_refused_by_field_and_nothing_is_written(tmp_path, capsys, manifest, field):
    root = folder(tmp_path, manifest)
    code, evs = run(root, capsys)
    assert code == protocol.EXIT_BAD_INPUT, evs
    assert evs[-1]["field"] == field and evs[-1]["file"].endswith(VariationLayout.MANIFEST), evs[-1]
    assert sorted(os.listdir(root)) == [VariationLayout.MANIFEST]            # no sheet, no temporary


def test_more_variants_than_vary_makes_are_refused(tmp_path, capsys):
    root = folder(tmp_path, [0] * (MAX_VARIANTS + 1))          # counted before any entry is read
    code, evs = run(root, capsys)
    assert code == protocol.EXIT_BAD_INPUT and evs[-1]["field"] == "variants"


def test_vary_s_maximum_of_variants_makes_a_bounded_sheet_of_the_first_ones(tmp_path, capsys):
    """100,000 variants (vary's maximum) allocated 17.8 GiB: now the first MAX_TILES, and a warning."""
    root = tmp_path / "v"                                     # small entries: 8 MB, written as text, read in a second
    root.mkdir()
    (root / VariationLayout.MANIFEST).write_text('{"variants": [' + ", ".join(
        f'{{"id": "{VariationLayout.variant_name(i)}", "outcome": "unplaced", "camera": {{"shift_m": 0}}, "cars": []}}'
        for i in range(MAX_VARIANTS)) + "]}")
    code, evs = run(root, capsys)
    assert code == protocol.EXIT_OK, evs
    warning, done = evs[-3], evs[-1]
    assert warning["event"] == protocol.WARNING and warning["code"] == S.TRUNCATED and "100,000" in warning["message"]
    assert done["variants"] == MAX_VARIANTS and done["shown"] == S.MAX_TILES == done["unplaced"]
    import cv2

    img = cv2.imread(done["path"])
    assert img.shape == (S.MAX_TILES // S.MAX_COLUMNS * (round(S.TILE_WIDTH * 9 / 16) + S.CAPTION_PX + 2),
                         S.MAX_COLUMNS * (S.TILE_WIDTH + 2), 3)
    assert not [n for n in os.listdir(root) if n.endswith(".tmp")]


def test_only_regular_images_inside_the_folder_are_read(tmp_path, capsys):
    """A rendered variant is shown; a preview that is a link out of the folder, a variant folder that is a link
    out, a FIFO, a text file named .png and a PNG whose header claims 100,000² pixels are each a grey tile (never
    read, waited on or decoded); a very tall preview is cut to MAX_TILE_HEIGHT."""
    root = folder(tmp_path, [entry(i) for i in range(7)])
    red = np.zeros((9, 16, 3), np.uint8)
    red[..., 0] = 255
    rendered_variant(root, 0, red)
    outside = tmp_path / "outside"
    outside.mkdir()
    write_png(str(outside / "secret.png"), np.full((9, 16, 3), 7, np.uint8))
    linked = rendered_variant(root, 1, red)
    preview = os.path.join(linked.conditions, CONDITION_PREVIEW.name(1))
    os.remove(preview)
    os.symlink(outside / "secret.png", preview)
    away = rendered_variant(outside, 2, red)                      # v0002 is a link to a folder elsewhere
    os.symlink(os.path.dirname(away.job), root / "v0002")
    fifo = rendered_variant(root, 3, red)
    fifo_path = os.path.join(fifo.conditions, CONDITION_PREVIEW.name(1))
    os.remove(fifo_path)
    os.mkfifo(fifo_path)
    text = rendered_variant(root, 4, red)
    with open(os.path.join(text.conditions, CONDITION_PREVIEW.name(1)), "w") as f:
        f.write("not an image")
    huge = rendered_variant(root, 5, red)
    with open(os.path.join(huge.conditions, CONDITION_PREVIEW.name(1)), "r+b") as f:
        f.seek(16)
        f.write((100_000).to_bytes(4, "big") * 2)                 # IHDR: 100,000 x 100,000
    rendered_variant(root, 6, np.zeros((4000, 8, 3), np.uint8))   # 1:500, a very tall tile
    code, evs = run(root, capsys)
    assert code == protocol.EXIT_OK, evs
    done = evs[-1]
    assert done["rendered"] == 2 and done["not_rendered"] == 5 and done["shown"] == done["variants"] == 7
    import cv2

    img = cv2.cvtColor(cv2.imread(done["path"]), cv2.COLOR_BGR2RGB)
    th = round(9 * S.TILE_WIDTH / 16)
    assert img.shape[0] == th + S.CAPTION_PX + 2                  # one row, the first rendered tile's height
    tile = img[S.CAPTION_PX:S.CAPTION_PX + th, :S.TILE_WIDTH]
    assert tile[..., 0].min() == 255 and tile[..., 1].max() == 0  # v0000's red preview
    secret = img[S.CAPTION_PX:S.CAPTION_PX + th, S.TILE_WIDTH + 2:2 * S.TILE_WIDTH + 2]
    assert (secret != 7).any() and not (secret == 7).all()        # the linked file's grey 7 is not shown


def test_a_users_file_at_the_destination_is_never_replaced_the_commands_own_sheet_is(tmp_path, capsys):
    """Issue 42 (h3's leftover): contact-sheet replaced whatever was at ``contact_sheet.png`` or ``--out``. Now only
    a sheet it wrote itself (its ``tEXt`` mark, ``S.SHEET_MARK``) is replaced; a user's file, even a PNG, is
    refused by name and left as it was."""
    root = folder(tmp_path, [entry(0, "unplaced")])
    users = tmp_path / "v" / VariationLayout.SHEET
    write_png(str(users), np.full((4, 4, 3), 9, np.uint8))        # a PNG of the user's (no mark)
    before = users.read_bytes()
    code, evs = run(root, capsys)
    assert code == protocol.EXIT_BAD_INPUT and evs[-1]["field"] == "--out" and evs[-1]["file"] == str(users)
    assert users.read_bytes() == before
    users.unlink()
    assert run(root, capsys)[0] == protocol.EXIT_OK                # its own sheet: written, then replaced
    assert run(root, capsys)[0] == protocol.EXIT_OK
    other = tmp_path / "notes.txt"
    other.write_text("mine")
    assert main(["contact-sheet", str(root), "--out", str(other)]) == protocol.EXIT_BAD_INPUT
    assert other.read_text() == "mine"


def test_a_folder_whose_vary_run_has_not_finished_says_so(tmp_path, capsys):
    """A vary run killed midway leaves its manifest ``state: running`` (``variants.make_variants``): the sheet
    says the run did not finish, not that the folder 'lists no variants'."""
    root = folder(tmp_path, {"schema": "scpainter.variation-manifest/1", "state": "running", "variants": []})
    code, evs = run(root, capsys)
    assert code == protocol.EXIT_BAD_INPUT and evs[-1]["field"] == "state" and "not finished" in evs[-1]["message"]


def test_a_rig_variant_shows_its_first_cameras_frame(tmp_path, capsys):
    """A variant of a rig job (docs/design.md §17) renders into <variant>/<camera>/: the sheet shows its first
    camera's first frame."""
    root = folder(tmp_path, [entry(0), entry(1)])
    green = np.zeros((18, 32, 3), np.uint8)
    green[..., 1] = 255
    for i in (0, 1):
        variant = OutputLayout(os.path.join(root, VariationLayout.variant_name(i)))
        os.makedirs(variant.root)
        with open(variant.job, "w") as f:
            json.dump({"rig": {"cameras": [{"name": "CAM_FRONT"}, {"name": "CAM_BACK"}]}}, f)
        os.utime(variant.job, ns=(1, 1))
        if i == 0:   # rendered: CAM_FRONT's folder holds its record and preview
            cam = variant.camera("CAM_FRONT")
            os.makedirs(cam.conditions)
            with open(cam.record, "w") as f:
                f.write("{}")
            write_png(os.path.join(cam.conditions, CONDITION_PREVIEW.name(1)), green)
    code, evs = run(root, capsys)
    assert code == 0
    assert evs[-1]["rendered"] == 1 and evs[-1]["not_rendered"] == 1
