"""Phone videos and frame sizes: a video's display matrix is applied as players apply it (every orientation, and
the matrix a phone writes for a video filmed upright), and frames whose aspect differs from the predictions'
beyond a resize's rounding are refused naming both sizes."""

import shutil

import av
import numpy as np
import pytest
from PIL import Image

from backend.train import camera_frames as cf
from backend.train import clip as clip_mod
from scpainter_blender.core.job import JobError
from tests_support import copy_clip

#: The MP4 track matrix of a phone video filmed upright (a portrait picture coded landscape): a = 0, b = 1,
#: c = -1, d = 0 in 16.16 fixed point, w = 1 in 2.30 (ISO/IEC 14496-12's matrix, as FFmpeg's display.h lays it
#: out): (p, q) -> (-q, p), which takes the coded picture's right edge to the bottom — a quarter turn clockwise
PHONE_MATRIX = [0, 65536, 0, -65536, 0, 0, 0, 0, 1 << 30]


def write_video(path, frames, matrix=None, rotation=None):
    """frames (F, H, W, 3) uint8 -> a lossless H.264 MP4 (libx264rgb, crf 0) whose track carries the display
    ``matrix`` (nine ints) or ``rotation`` ((degrees counter-clockwise, hflip, vflip), PyAV's convention)."""
    with av.open(str(path), "w", format="mp4") as container:
        stream = container.add_stream("libx264rgb", rate=10)
        stream.width, stream.height, stream.pix_fmt = frames.shape[2], frames.shape[1], "rgb24"
        stream.options = {"crf": "0"}
        if matrix is not None:
            stream.set_display_matrix(matrix)
        if rotation is not None:
            stream.set_display_rotation(rotation[0], hflip=rotation[1], vflip=rotation[2])
        for f in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def _decoded(path, n):
    def error(m):
        return ValueError(m)
    return np.stack([rgb for _, rgb in cf.decode_video(str(path), n, error)]), cf.probe_video(str(path), error)


def test_the_phone_matrix_shows_the_top_left_corner_at_the_top_right(tmp_path):
    """A marker in the coded picture's top-left corner is where a player shows it: top right, the picture
    turned a quarter clockwise (64 x 32 coded, 32 x 64 shown)."""
    coded = np.zeros((1, 32, 64, 3), np.uint8)
    coded[0, :4, :6] = 255
    write_video(tmp_path / "phone.mp4", coded, matrix=PHONE_MATRIX)
    with av.open(str(tmp_path / "phone.mp4")) as c:  # the file holds the matrix: FFmpeg reads it back
        assert next(c.decode(video=0)).rotation == -90
    frames, (count, size) = _decoded(tmp_path / "phone.mp4", 1)
    assert count == 1 and size == (32, 64) and frames.shape == (1, 64, 32, 3)
    shown = frames[0, ..., 0] > 128
    ys, xs = np.nonzero(shown)
    assert (ys.min(), ys.max(), xs.min(), xs.max()) == (0, 5, 28, 31)  # 6 rows down the right edge, 4 wide


# every orientation: (degrees counter-clockwise, hflip, vflip) as PyAV writes them; what a player shows is the
# coded picture turned by np.rot90 (counter-clockwise, PyAV's VideoFrame.rotation), then mirrored
ORIENTATIONS = [(0, False, False), (90, False, False), (180, False, False), (-90, False, False),
                (0, True, False), (0, False, True), (90, True, False), (-90, True, False)]


@pytest.mark.parametrize("rotation", ORIENTATIONS, ids=[f"{d}{'h' if h else ''}{'v' if v else ''}"
                                                        for d, h, v in ORIENTATIONS])
def test_every_display_orientation_is_applied(tmp_path, rotation):
    rng = np.random.default_rng(0)
    coded = rng.integers(0, 256, (3, 24, 40, 3), dtype=np.uint8)
    write_video(tmp_path / "v.mp4", coded, rotation=rotation)
    degrees, hflip, vflip = rotation
    expected = np.rot90(coded, degrees // 90, axes=(1, 2))
    expected = expected[:, :, ::-1] if hflip else expected
    expected = expected[:, ::-1] if vflip else expected
    frames, (count, size) = _decoded(tmp_path / "v.mp4", 3)
    assert count == 3 and size == (expected.shape[2], expected.shape[1])
    assert np.array_equal(frames, expected)  # lossless: exactly the turned picture


def test_a_matrix_no_player_shows_alike_is_refused(tmp_path):
    write_video(tmp_path / "v.mp4", np.zeros((1, 24, 40, 3), np.uint8), rotation=(30, False, False))
    with pytest.raises(ValueError, match="no quarter-turn rotation or flip"):
        _decoded(tmp_path / "v.mp4", 1)


# -- clips -------------------------------------------------------------------------------------------------------

def _no_poses(d):
    """The issue's case: without poses the frames' K is VGGT's scaled to the frames' size."""
    d.pop("poses")
    d.pop("views")


@pytest.fixture(scope="module")
def street_frames(street_clip_path):
    c = clip_mod.load(street_clip_path)
    return np.stack([np.asarray(Image.open(p).convert("RGB")) for p in c.frame_paths])


def _video_clip(street_clip_path, tmp_path, coded, matrix, name):
    def edit(d, folder):
        write_video(folder / "drive.mp4", coded, matrix=matrix)
        shutil.rmtree(folder / "frames")
        d["frames"] = "drive.mp4"
        _no_poses(d)
    return copy_clip(street_clip_path, tmp_path, edit, name)


def test_a_video_filmed_upright_gives_the_frames_and_K_of_the_images(street_clip_path, tmp_path, street_frames):
    """The street's frames coded sideways (294 x 518, turned a quarter counter-clockwise) with the phone's matrix:
    the clip's frames are the street's exactly, at 518 x 294, with the same K (before: 294 x 518 frames and K
    stretched, fx 170 / fy 528 from 300, and no error)."""
    images = clip_mod.load(copy_clip(street_clip_path, tmp_path, lambda d, f: _no_poses(d), "images"))
    coded = np.rot90(street_frames, 1, axes=(1, 2))
    c = clip_mod.load(_video_clip(street_clip_path, tmp_path, coded, PHONE_MATRIX, "phone"))
    assert c.image_size == images.image_size == (518, 294)
    np.testing.assert_array_equal(c.K, images.K)
    assert c.K[0, 0, 0] == c.K[0, 1, 1] == 300.0
    assert np.array_equal(c.load_frames(518, 294), street_frames)
    assert np.array_equal(c.load_frames(259, 147, [3, 9]), images.load_frames(259, 147, [3, 9]))


def test_a_video_coded_sideways_without_a_matrix_is_refused(street_clip_path, tmp_path, street_frames):
    """Frames turned with nothing saying so (a converter that dropped the matrix): refused, naming both sizes and
    both files, instead of a K stretched threefold."""
    coded = np.rot90(street_frames, 1, axes=(1, 2))
    folder = _video_clip(street_clip_path, tmp_path, coded, None, "sideways")
    with pytest.raises(JobError) as info:
        clip_mod.load(folder)
    e = info.value
    assert e.field == "frames" and "the frames are 294x518" in e.message and "the predictions 518x294" in e.message
    assert "drive.mp4" in e.message and "predictions.npz" in e.message and "upright" in e.hint, str(e)


def test_phone_photos_are_turned_by_their_exif_orientation(street_clip_path, tmp_path, street_frames):
    """Image frames stored sideways with EXIF Orientation 6 (a phone photo taken upright): read upright, as viewers
    show them, with the images' size and K (the same rule as a video's display matrix)."""
    images = clip_mod.load(copy_clip(street_clip_path, tmp_path, lambda d, f: _no_poses(d), "images"))

    def edit(d, folder):
        for t, p in enumerate(sorted((folder / "frames").iterdir())):
            coded = Image.fromarray(np.ascontiguousarray(np.rot90(street_frames[t], 1)))  # stored turned a quarter
            exif = Image.Exif()
            exif[0x0112] = 6  # "rotate 90 CW to display": undoes the counter-clockwise quarter above
            p.unlink()  # the copy's own file, never one it might share with the cached street
            coded.save(p, exif=exif, compress_level=1)  # lossless either way; the default level is slow
        _no_poses(d)

    c = clip_mod.load(copy_clip(street_clip_path, tmp_path, edit, "exif"))
    assert c.image_size == images.image_size == (518, 294)
    np.testing.assert_array_equal(c.K, images.K)
    assert np.array_equal(c.load_frames(518, 294), street_frames)


def _resized_frames(size):
    def edit(d, folder):
        for p in sorted((folder / "frames").iterdir()):
            im = Image.open(p).convert("RGB").resize(size, Image.LANCZOS)
            p.unlink()  # the copy's own file, never one it might share with the cached street
            im.save(p, compress_level=1)  # the same pixels, written fast (zlib's default level was most of the test)
        _no_poses(d)
    return edit


# VGGT makes 518 x 294 of frames whose height is 1036 x 287/518 .. 1036 x 301/518 = 574 .. 602 at 1036 wide
@pytest.mark.parametrize("size, ok", [((1036, 588), True), ((1036, 576), True), ((1036, 600), True),
                                      ((1036, 640), False), ((1036, 540), False), ((294, 518), False)])
def test_frames_of_another_aspect_than_the_predictions_are_refused(street_clip_path, tmp_path, size, ok):
    folder = copy_clip(street_clip_path, tmp_path, _resized_frames(size))
    if ok:
        c = clip_mod.load(folder)
        assert c.image_size == size
        return
    with pytest.raises(JobError) as info:
        clip_mod.load(folder)
    e = info.value
    assert e.field == "frames" and f"the frames are {size[0]}x{size[1]}" in e.message, str(e)
    assert "the predictions 518x294" in e.message and "frame_000000.png" in e.message, str(e)


def test_the_aspect_tolerance_is_vggts_rounding():
    """The bound follows from VGGT's preprocessing (width 518, height rounded to a multiple of 14): every frame
    size it maps to 518 x h passes, for the heights VGGT makes."""
    for h in range(154, 519, 14):
        lo, hi = (h - 7) / 518, (h + 7) / 518  # frame aspect H/W VGGT rounds to h
        for W in (1280, 1920, 4032):
            for H in (int(np.ceil(lo * W)) + 1, int(np.floor(hi * W)) - 1):
                assert cf.aspect_problem((W, H), (518, h)) is None, (W, H, h)
    assert cf.aspect_problem((1920, 1080), (518, 378)) is not None  # 16:9 against 4:3
