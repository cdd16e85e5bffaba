"""Frames from a video (prosplat.poses.video), on clips the tests encode with PyAV: a textured
pattern sliding sideways, every frame blurred but one per interval, so the frame each interval
keeps can be told apart from its neighbours."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import OpenImageIO as oiio
import pytest

from prosplat.poses.errors import PoseCancelled, PoseError
from prosplat.poses.video import extract_frames, is_video, sharpness

W, H, FPS, SECONDS = 128, 96, 24, 3
FRAMES = FPS * SECONDS  # 72
INTERVALS = 6  # 12 frames each
PER = FRAMES // INTERVALS


def _texture(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """Grey noise in 2-px blocks [height, width] uint8: detail at every scale SIFT and the
    sharpness score look at, and no symmetry (so a wrong orientation is detectable)."""
    blocks = rng.integers(0, 256, (height // 2 + 1, width // 2 + 1), dtype=np.uint8)
    return np.kron(blocks, np.ones((2, 2), np.uint8))[:height, :width]


def _blur(img: np.ndarray, r: int = 3) -> np.ndarray:
    """A (2r+1)² box blur with edge padding, in numpy."""
    pad = np.pad(img.astype(np.float32), r, mode="edge")
    k = 2 * r + 1
    c = np.cumsum(np.cumsum(pad, 0), 1)
    c = np.pad(c, ((1, 0), (1, 0)))
    box = c[k:, k:] - c[:-k, k:] - c[k:, :-k] + c[:-k, :-k]
    return (box / k**2).round().astype(np.uint8)


def _sharp_index(interval: int) -> int:
    """The one sharp frame of an interval, at a different place in each."""
    return interval * PER + (interval * 5 + 3) % PER


def _encode(path: Path, frames: list[np.ndarray], rotation: int = 0, hflip: bool = False) -> None:
    with av.open(str(path), "w") as container:
        stream = container.add_stream("mpeg4", rate=FPS)
        stream.width, stream.height = frames[0].shape[1], frames[0].shape[0]
        stream.pix_fmt = "yuv420p"
        stream.bit_rate = 8_000_000  # near lossless at this size
        if rotation or hflip:
            stream.set_display_rotation(rotation, hflip=hflip)
        for grey in frames:
            frame = av.VideoFrame.from_ndarray(np.repeat(grey[..., None], 3, 2), format="rgb24")
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def _read_grey(path: Path) -> np.ndarray:
    buf = oiio.ImageBuf(str(path))
    pixels = buf.get_pixels(oiio.FLOAT)
    assert pixels is not None, oiio.geterror()
    return pixels.mean(axis=2) * 255.0


def _closest(img: np.ndarray, frames: list[np.ndarray]) -> int:
    return int(np.argmin([np.mean((img - f.astype(np.float32)) ** 2) for f in frames]))


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> tuple[Path, list[np.ndarray]]:
    """A 3 s, 24 fps clip of a pattern sliding 2 px a frame; one sharp frame per half second."""
    texture = _texture(np.random.default_rng(0), H, W + 2 * FRAMES)
    sharp = {_sharp_index(k) for k in range(INTERVALS)}
    frames = []
    for i in range(FRAMES):
        view = np.ascontiguousarray(texture[:, 2 * i : 2 * i + W])
        frames.append(view if i in sharp else _blur(view))
    path = tmp_path_factory.mktemp("clip") / "walk.mp4"
    _encode(path, frames)
    return path, frames


def test_is_video_by_suffix() -> None:
    for name in ("a.mp4", "b.MOV", "c.m4v", "d.avi", "e.mkv", "f.WebM"):
        assert is_video(name), name
    for name in ("a.jpg", "b.png", "c", "mp4", "d.exr"):
        assert not is_video(name), name


def test_sharpness_prefers_the_sharp_image() -> None:
    img = _texture(np.random.default_rng(1), 64, 64)
    assert sharpness(img) > 4 * sharpness(_blur(img))


def test_keeps_the_sharpest_frame_of_each_interval_in_time_order(clip, tmp_path) -> None:
    path, frames = clip
    calls = []
    out = extract_frames(
        path, tmp_path / "frames", max_frames=INTERVALS, progress=lambda d, t: calls.append(d)
    )
    assert [p.name for p in out] == [f"frame_{k:04d}.jpg" for k in range(INTERVALS)]
    assert sorted((tmp_path / "frames").iterdir()) == out  # nothing else left there
    chosen = [_closest(_read_grey(p), frames) for p in out]
    assert chosen == [_sharp_index(k) for k in range(INTERVALS)]  # one per interval, in order
    assert calls == list(range(1, INTERVALS + 1))
    assert _read_grey(out[0]).shape == (H, W)


def test_max_frames_caps_the_count_and_a_short_clip_gives_every_frame(clip, tmp_path) -> None:
    path, frames = clip
    assert len(extract_frames(path, tmp_path / "a", max_frames=4)) == 4
    every = extract_frames(path, tmp_path / "b", max_frames=200)
    assert len(every) == FRAMES
    assert [_closest(_read_grey(p), frames) for p in every[::9]] == list(range(0, FRAMES, 9))


def test_a_shorter_rerun_removes_the_extra_frames(clip, tmp_path) -> None:
    path, _ = clip
    extract_frames(path, tmp_path, max_frames=5)
    out = extract_frames(path, tmp_path, max_frames=3)
    assert sorted(tmp_path.iterdir()) == out and len(out) == 3


@pytest.mark.parametrize(
    ("rotation", "hflip"), [(90, False), (-90, False), (180, False), (90, True)]
)
def test_rotation_metadata_is_honoured(tmp_path, rotation, hflip) -> None:
    """A clip with a display matrix (a phone held upright) comes out as a player shows it:
    turned ``rotation`` degrees counter-clockwise, then mirrored left-right when ``hflip``."""
    img = _texture(np.random.default_rng(2), H, W)
    path = tmp_path / "turned.mov"
    _encode(path, [img] * 3, rotation=rotation, hflip=hflip)
    (out,) = extract_frames(path, tmp_path / "frames", max_frames=1)
    expected = np.rot90(img, rotation // 90)
    if hflip:
        expected = expected[:, ::-1]
    got = _read_grey(out)
    assert got.shape == expected.shape
    candidates = [np.rot90(img, k) for k in range(4)] + [
        np.rot90(img, k)[:, ::-1] for k in range(4)
    ]
    same_shape = [c for c in candidates if c.shape == got.shape]
    assert _closest(got, same_shape) == next(
        i for i, c in enumerate(same_shape) if np.array_equal(c, expected)
    )


def test_an_unreadable_video_is_named(tmp_path) -> None:
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"this is not a video" * 100)
    with pytest.raises(PoseError, match="broken.mp4"):
        extract_frames(broken, tmp_path / "frames")
    with pytest.raises(PoseError, match="missing.mov"):
        extract_frames(tmp_path / "missing.mov", tmp_path / "frames")
    assert not (tmp_path / "frames").exists()  # nothing written


def test_cancel_stops_and_leaves_no_frames(clip, tmp_path) -> None:
    path, _ = clip
    polls = []

    def cancel() -> bool:
        polls.append(1)
        return len(polls) > 40  # after three intervals were written

    out_dir = tmp_path / "frames"
    with pytest.raises(PoseCancelled):
        extract_frames(path, out_dir, max_frames=INTERVALS, cancel=cancel)
    assert len(polls) == 41  # it stopped at once
    assert list(out_dir.iterdir()) == []
