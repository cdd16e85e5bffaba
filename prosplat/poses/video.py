"""Frames of a video for structure from motion: the sharpest frame of each equal time interval.

A phone clip walked around a subject holds hundreds of frames, many smeared by motion. SfM
wants a few dozen sharp ones spread evenly over the walk, so the clip is split into
``max_frames`` equal time intervals and each keeps its sharpest frame (the variance of a
Laplacian, the usual focus measure), measured on a small grey copy so that only the frames
kept are ever converted to full-size RGB. Decoding goes through PyAV (FFmpeg's libraries, in
its wheels); the display matrix a phone writes for a portrait clip is applied, so the frames
are upright as a player shows them.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path

try:
    import av
except ImportError:  # a training-only machine: extract_frames says what to install
    av = None
import numpy as np

from prosplat.poses.errors import PoseCancelled, PoseError, require
from prosplat.poses.photos import write_rgb8

VIDEO_SUFFIXES = frozenset({".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm"})
SCORE_SIZE = 480  # longest side (px) of the grey copy the sharpness is measured on
FRAME_PATTERN = "frame_{:04d}.jpg"


def is_video(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` names a video file, by its suffix (mp4 mov m4v avi mkv webm, any case)."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def sharpness(grey: np.ndarray) -> float:
    """Variance of the 4-neighbour Laplacian of a grey image [H, W]: high when edges are crisp,
    low when motion blur or defocus has smoothed them."""
    g = grey.astype(np.float32)
    lap = g[1:-1, :-2] + g[1:-1, 2:] + g[:-2, 1:-1] + g[2:, 1:-1] - 4.0 * g[1:-1, 1:-1]
    return float(lap.var()) if lap.size else 0.0


def extract_frames(
    video: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    max_frames: int = 60,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> list[Path]:
    """Write the sharpest frame of each of ``max_frames`` equal time intervals of ``video`` to
    ``out_dir/frame_0000.jpg``, … (JPEG, quality 95, upright) and return their paths in time order.

    A clip with fewer frames than intervals gives one file per frame. ``progress(done, total)``
    is called as each interval is finished; ``cancel()`` is polled per decoded frame, and when
    it returns True the frames written so far are removed and :class:`PoseCancelled` is raised.
    An unreadable video raises :class:`PoseError` naming the file (nothing is left written).
    Frames of an earlier extraction into ``out_dir`` beyond this one's count are removed, so the
    folder holds exactly the returned frames.
    """
    require(av, "av")
    video, out_dir = Path(video), Path(out_dir)
    if max_frames < 1:
        raise ValueError(f"max_frames must be at least 1, got {max_frames}")
    if not video.is_file():
        raise PoseError(f"video not found: {video}")
    written: list[Path] = []
    try:
        with _open(video) as container:
            written = _extract(video, container, out_dir, max_frames, progress, cancel, written)
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        raise
    _remove_stale(out_dir, len(written))
    return written


def _open(video: Path) -> av.container.InputContainer:
    try:
        return av.open(str(video), mode="r")
    except (av.FFmpegError, OSError) as e:
        raise PoseError(f"cannot read video {video}: {e}") from e


def _extract(
    video: Path,
    container: av.container.InputContainer,
    out_dir: Path,
    max_frames: int,
    progress: Callable[[int, int], None] | None,
    cancel: Callable[[], bool] | None,
    written: list[Path],
) -> list[Path]:
    """The decode loop; appends to ``written`` as it goes, so the caller can undo a failure."""
    if not container.streams.video:
        raise PoseError(f"cannot read video {video}: it has no video stream")
    stream = container.streams.video[0]
    stream.thread_type = "AUTO"  # frame threads: decoding is most of the time
    start, span = _time_span(video, container, stream)
    total = max_frames if not stream.frames else min(max_frames, stream.frames)
    fps = float(stream.average_rate or stream.guessed_rate or 30)
    out_dir.mkdir(parents=True, exist_ok=True)

    current, best, best_score = -1, None, -1.0
    try:
        for index, frame in enumerate(container.decode(stream)):
            if cancel is not None and cancel():
                raise PoseCancelled(f"cancelled while extracting frames from {video.name}")
            t = frame.time if frame.time is not None else index / fps
            k = min(max(int((t - start) / span * max_frames), 0), max_frames - 1)
            if k > current:  # decoders give frames in presentation order: an interval ends
                if best is not None:
                    written.append(_write(best, out_dir / FRAME_PATTERN.format(len(written))))
                    if progress is not None:
                        progress(len(written), total)
                current, best, best_score = k, None, -1.0
            score = sharpness(_grey(frame))
            if score > best_score:
                best, best_score = frame, score
    except av.FFmpegError as e:
        raise PoseError(f"cannot decode video {video}: {e}") from e
    if best is not None:
        written.append(_write(best, out_dir / FRAME_PATTERN.format(len(written))))
        if progress is not None:
            progress(len(written), len(written))
    if not written:
        raise PoseError(f"cannot read video {video}: no frames could be decoded")
    return written


def _time_span(
    video: Path, container: av.container.InputContainer, stream: av.video.stream.VideoStream
) -> tuple[float, float]:
    """(start, duration) of the stream in seconds; the duration from the stream, else the
    container, else (a stream that records neither) the last packet's end, found by a
    demux-only pass over a second opening of the file."""
    tb = stream.time_base or Fraction(1, 1)
    start = float(stream.start_time * tb) if stream.start_time is not None else 0.0
    if stream.duration:
        return start, float(stream.duration * tb)
    if container.duration:
        return start, container.duration / av.time_base
    end = start
    with _open(video) as probe:
        s = probe.streams.video[0]
        for packet in probe.demux(s):
            if packet.pts is not None:
                end = max(end, float((packet.pts + (packet.duration or 0)) * s.time_base))
    return start, max(end - start, 1e-6)


def _grey(frame: av.VideoFrame) -> np.ndarray:
    """A small grey copy [h, w] uint8 of a frame (longest side SCORE_SIZE), for scoring only."""
    scale = min(1.0, SCORE_SIZE / max(frame.width, frame.height))
    width = max(2, round(frame.width * scale))
    height = max(2, round(frame.height * scale))
    small = frame.reformat(width=width, height=height, format="gray")
    return small.to_ndarray()[:height, :width]


def _upright(frame: av.VideoFrame, rgb: np.ndarray) -> np.ndarray:
    """Apply the frame's display matrix (rotation and mirroring, in quarter turns) to ``rgb``.

    FFmpeg's matrix maps a coded pixel (x, y) to the displayed (a·x + c·y, b·x + d·y) (the
    coefficients rounded here to -1, 0 or 1); ``frame.rotation`` alone would drop a mirror.
    """
    matrix = None
    for side in frame.side_data or ():
        if side.type.name == "DISPLAYMATRIX":
            matrix = np.frombuffer(bytes(side), dtype=np.int32)[:9]
    if matrix is None or matrix.size < 9:
        return np.rot90(rgb, round((frame.rotation or 0) / 90) % 4)
    a, b, c, d = (float(v) for v in (matrix[0], matrix[1], matrix[3], matrix[4]))
    if abs(a) + abs(d) >= abs(b) + abs(c):  # no transpose: x' = a·x, y' = d·y
        return rgb[:: -1 if d < 0 else 1, :: -1 if a < 0 else 1]
    transposed = rgb.transpose(1, 0, 2)  # rows are coded x, columns coded y
    return transposed[:: -1 if b < 0 else 1, :: -1 if c < 0 else 1]


def _write(frame: av.VideoFrame, path: Path) -> Path:
    """Write a frame upright as an sRGB JPEG (quality 95), whole or not at all."""
    write_rgb8(path, _upright(frame, frame.to_ndarray(format="rgb24")))
    return path


def _remove_stale(out_dir: Path, count: int) -> None:
    """Remove ``frame_NNNN.jpg`` files numbered ``count`` or more (left by a longer extraction)."""
    for path in out_dir.glob("frame_[0-9][0-9][0-9][0-9].jpg"):
        if int(path.stem.split("_")[1]) >= count:
            path.unlink(missing_ok=True)
