"""The line protocol between ``prosplat scenes render`` and its long-lived Blender workers
(``python -m scenes.render --jobs-from-stdin``). bpy-free, so both sides import it: the
CLI from here, the repository's Blender scripts (``scenes/``) from the library, never the
other way round.

The parent writes ``NAME SEED`` lines; the worker answers each with one line holding
``PROSPLAT_DONE {"name", "seed", "folder"}`` or ``PROSPLAT_FAILED {"name", "seed", "error"}``
(``error``: the last lines of the traceback). Blender's C code prints to the same stdout
through its own buffer, so an answer may follow some of Blender's text on its line: the
parent looks for the marker anywhere in a line, and the answer runs to the line's end.

The image size travels on the worker's command line, not in the job lines: every scene of
one run shares it. :func:`image_size` checks ``--size`` / ``--width --height`` the same way on
both sides, and :func:`size_options` writes the worker's options for a checked size.
"""

from __future__ import annotations

import argparse
import json
from collections import deque
from collections.abc import Callable
from typing import IO, Any

DONE = "PROSPLAT_DONE "
FAILED = "PROSPLAT_FAILED "

DEFAULT_SIZE = 128  #: ``--size`` when no size is given: 128 x 128 px
MIN_SIZE = 8  #: the smallest image side, in px
#: Cycles' denoiser settings ``--denoise-quality`` offers: ``scenes.render.DENOISE_QUALITY``'s
#: names (that module needs bpy; a test keeps the two alike)
DENOISE_QUALITIES = ("high", "fast")


def image_size(size: int | None, width: int | None, height: int | None) -> tuple[int, int]:
    """The ``(width, height)`` in px that ``--size N`` (N x N) or ``--width W --height H``
    asks for; neither gives :data:`DEFAULT_SIZE` squared. Raises ``ValueError`` with a
    one-line message naming the fix for both kinds together, only one of width and height,
    or a side below :data:`MIN_SIZE`."""
    if size is not None and (width is not None or height is not None):
        raise ValueError(
            "--size N renders N x N; for other shapes pass --width W --height H without --size"
        )
    if (width is None) != (height is None):
        raise ValueError("--width and --height go together; pass both (or --size N for N x N)")
    if width is None or height is None:
        width = height = DEFAULT_SIZE if size is None else size
    if width < MIN_SIZE or height < MIN_SIZE:
        raise ValueError(f"image sides must be >= {MIN_SIZE} px, got {width} x {height}")
    return width, height


def size_options(width: int, height: int) -> list[str]:
    """A worker's command-line options for images ``width`` x ``height`` px."""
    return ["--width", str(width), "--height", str(height)]


def answer_line(done: bool, answer: dict[str, Any]) -> str:
    """The worker's answer for one job, as one line (no newline)."""
    return (DONE if done else FAILED) + json.dumps(answer)


def read_answer(stream: IO[str], keep: int = 15) -> tuple[dict[str, Any] | None, list[str]]:
    """Read ``stream`` up to the next answer: ``(answer, last lines before it)``, the answer
    holding ``folder`` when the scene was rendered and ``error`` when it failed. ``(None,
    last lines)`` when the stream ends first (the worker died)."""
    tail: deque[str] = deque(maxlen=keep)
    for line in stream:
        for marker in (DONE, FAILED):
            at = line.find(marker)
            if at >= 0:
                return json.loads(line[at + len(marker) :]), list(tail)
        tail.append(line.rstrip("\n"))
    return None, list(tail)


def argparse_type(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse ``type`` that reports ``parse``'s ``ValueError`` message as it is, so both
    sides' ``--lens-range 85-24`` fail with "runs backwards", not "invalid value"."""

    def checked(text: str):
        try:
            return parse(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    checked.__name__ = parse.__name__
    return checked


def add_camera_arguments(parser: argparse.ArgumentParser) -> None:
    """``--roll DEG`` and ``--lens-range A-B``, parsed and checked alike by ``prosplat scenes
    render`` and by its Blender workers (:func:`prosplat.data.rigs.parse_roll`,
    :func:`~prosplat.data.rigs.parse_lens_range`)."""
    from prosplat.data.rigs import parse_lens_range, parse_roll

    parser.add_argument(
        "--roll",
        type=argparse_type(parse_roll),
        default=0.0,
        metavar="DEG",
        help="roll each view's camera about its viewing axis by an angle drawn uniformly in "
        "[-DEG, DEG] degrees, seeded per scene and view, as hand-held photos are rarely level "
        "(default 0: level cameras, as before)",
    )
    parser.add_argument(
        "--lens-range",
        type=argparse_type(parse_lens_range),
        default=None,
        metavar="A-B",
        help="draw each scene's lens log-uniformly in [A, B] mm (36 mm sensor), one per scene "
        "from its seed, e.g. 24-85; the camera path stays (default: the scene's own lens)",
    )
