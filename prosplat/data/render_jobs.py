"""The line protocol between ``prosplat scenes render`` and its long-lived Blender workers
(``python -m scenes.render --jobs-from-stdin``). bpy-free, so both sides import it: the
CLI from here, the repository's Blender scripts (``scenes/``) from the library, never the
other way round.

The parent writes ``NAME SEED`` lines; the worker answers each with one line holding
``PROSPLAT_DONE {"name", "seed", "folder"}`` or ``PROSPLAT_FAILED {"name", "seed", "error"}``
(``error``: the last lines of the traceback). Blender's C code prints to the same stdout
through its own buffer, so an answer may follow some of Blender's text on its line: the
parent looks for the marker anywhere in a line, and the answer runs to the line's end.
"""

from __future__ import annotations

import json
from collections import deque
from typing import IO, Any

DONE = "PROSPLAT_DONE "
FAILED = "PROSPLAT_FAILED "


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
