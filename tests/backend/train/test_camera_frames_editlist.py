"""Losslessly trimmed videos (issue 42): ``ffmpeg -ss … -t … -c copy`` and phones' trimming keep the coded packets
from the key frame before the cut and write an MP4 edit list saying which presentation times play. Players show
only those frames; so do ``probe_video`` (the count) and ``decode_video`` (the frames), and a clip whose video
holds more coded frames than it shows is read as the frames shown."""

import struct

import av
import numpy as np

from backend.train import camera_frames as cf
from backend.train import clip as clip_mod
from tests.backend.train.test_camera_frames_rotation import write_video
from tests_support import copy_clip


def _elst(data: bytearray) -> int:
    """Offset of the single edit list box's payload (after its type) in an MP4's bytes."""
    i = data.find(b"elst")
    assert i > 0 and data.find(b"elst", i + 4) < 0, "one edit list expected"
    return i + 4


def trimmed_copy(src, dst, head: int, keep: int):
    """Remux the MP4 ``src`` (one video stream, constant frame duration) to ``dst`` losslessly as ``ffmpeg -ss
    -t -c copy`` does: every packet kept, timestamps shifted so the first ``head`` frames have negative presentation
    times (FFmpeg's mov muxer then writes an edit list starting the presentation at the ``head``-th frame), and the
    edit's duration shortened to ``keep`` frames (the edit list box's segment_duration, ISO/IEC 14496-12 §8.6.6, in
    the movie time scale of ``mvhd``): the file holds all frames, players show frames head .. head + keep − 1."""
    with av.open(str(src)) as source, av.open(str(dst), "w", format="mp4") as out:
        stream = source.streams.video[0]
        copy = out.add_stream_from_template(stream)
        for packet in source.demux(stream):
            if packet.dts is None:  # the flushing packet
                continue
            packet.pts -= head * packet.duration
            packet.dts -= head * packet.duration
            packet.stream = copy
            out.mux(packet)
        rate = stream.average_rate
    data = bytearray(open(dst, "rb").read())
    e = _elst(data)
    version, count = data[e], struct.unpack(">I", data[e + 4:e + 8])[0]
    assert count == 1
    m = data.find(b"mvhd") + 4
    timescale = struct.unpack(">I", data[m + 12:m + 16] if data[m] == 0 else data[m + 20:m + 24])[0]
    duration = round(keep * timescale / rate)
    struct.pack_into(">Q" if version == 1 else ">I", data, e + 8, duration)
    open(dst, "wb").write(bytes(data))


def _error(message):
    return ValueError(message)


def test_an_edit_list_is_counted_and_decoded_as_players_show_it(tmp_path):
    """12 coded frames, the edit list plays frames 2..9: 8 counted, those 8 decoded exactly (lossless), pts from
    0. Before: probe_video counted the 12 packets, so a clip with 8 predictions was refused."""
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (12, 24, 40, 3), dtype=np.uint8)
    write_video(tmp_path / "full.mp4", frames)
    trimmed_copy(tmp_path / "full.mp4", tmp_path / "trim.mp4", head=2, keep=8)
    with av.open(str(tmp_path / "trim.mp4")) as c:  # the demuxer hands out the cut head too (decoding needs it)
        packets = [p for p in c.demux(video=0) if p.size > 0]
    assert len(packets) > 8 and sum(not p.is_discard for p in packets) == 8
    assert cf.probe_video(str(tmp_path / "trim.mp4"), _error) == (8, (40, 24))
    got = np.stack([rgb for _, rgb in cf.decode_video(str(tmp_path / "trim.mp4"), 8, _error)])
    assert np.array_equal(got, frames[2:10])


def test_a_head_only_trim_shows_the_rest(tmp_path):
    """``ffmpeg -ss`` alone: the edit list starts later and runs to the end."""
    frames = np.repeat(np.arange(0, 240, 20, dtype=np.uint8)[:, None, None, None], 1, 0) * np.ones((1, 16, 16, 3),
                                                                                                   np.uint8)
    write_video(tmp_path / "full.mp4", frames)
    trimmed_copy(tmp_path / "full.mp4", tmp_path / "trim.mp4", head=4, keep=8)
    count, _ = cf.probe_video(str(tmp_path / "trim.mp4"), _error)
    got = [int(rgb[0, 0, 0]) for _, rgb in cf.decode_video(str(tmp_path / "trim.mp4"), count, _error)]
    assert got == list(range(80, 240, 20))


def test_a_clip_from_a_trimmed_video_is_read(street_clip_path, tmp_path):
    """The street clip's 16 frames with two extra coded frames on each side, cut by an edit list: the clip loads
    (before: "the video … has 20 frames, the predictions 16") and its frames are the 16 shown, exactly."""
    image_clip = clip_mod.load(street_clip_path)
    frames = image_clip.load_frames(*image_clip.image_size)
    padded = np.concatenate([255 - frames[:2], frames, 255 - frames[-2:]])

    def edit(d, folder):
        write_video(folder / "coded.mp4", padded)
        trimmed_copy(folder / "coded.mp4", folder / "drive.mp4", head=2, keep=len(frames))
        d["frames"] = "drive.mp4"
    c = clip_mod.load(copy_clip(street_clip_path, tmp_path, edit, "trimmed"))
    assert c.num_frames == 16 and c.image_size == image_clip.image_size
    assert np.array_equal(c.load_frames(*c.image_size), frames)
