"""A stand-in for :func:`prosplat.poses.estimate_poses` (the worker's ``poses`` task and the
add-on's *Import Photos* are tested without running pycolmap): it reports every phase through
``progress``, honours ``cancel`` between steps, writes a pose folder only when it finishes
(as the real one, through a staged folder), and returns a PoseResult-like object whose
cameras are known, so a test can check what the add-on built from them.

``install(monkeypatch, fake)`` puts it in place of ``prosplat.poses.estimate_poses``.
"""

from __future__ import annotations

import shutil
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from prosplat import Camera
from prosplat.convert.distortion import Distortion
from prosplat.core.image_io import write_image
from prosplat.core.paths import staged_folder
from prosplat.poses.errors import PoseError
from prosplat.worker import pose_task

W, H = 48, 32
PHASES = ("prepare", "extract", "match", "map", "write")
NOT_MATCHED = "only 1 of 3 photos could be matched (registered): take more photos with overlap"


def write_photos(folder: Path, count: int = 4, seed: int = 0) -> list[Path]:
    """``count`` small random PNG photos ``img_000.png``... in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    gen = torch.Generator().manual_seed(seed)
    paths = [folder / f"img_{i:03d}.png" for i in range(count)]
    for p in paths:
        write_image(p, torch.rand(3, H, W, generator=gen))
    return paths


def cameras(count: int) -> list[Camera]:
    """Cameras on an arc around the origin, z up (as the upright frame puts them)."""
    out = []
    for i in range(count):
        a = 0.4 * i
        eye = (4.0 * np.cos(a), 4.0 * np.sin(a), 1.0 + 0.1 * i)
        out.append(Camera.look_at(eye, (0.0, 0.0, 0.0), (0, 0, 1), 40.0 + i, W, H))
    return out


class FakeEstimate:
    """``estimate_poses`` that registers all photos but the last one (``unregistered``),
    with radial distortion ``k1`` (0: pinhole).

    ``fail``: raise this PoseError message after matching. ``block``: wait at the extract
    phase until cancelled (a cancel test's long step). ``calls``: the arguments seen.
    """

    def __init__(self, fail: str | None = None, block: bool = False, k1: float = 0.0) -> None:
        self.fail, self.block, self.k1 = fail, block, k1
        self.calls: list[dict] = []
        self.started = threading.Event()

    def __call__(self, source, out, options=None, *, progress=None, cancel=None, overwrite=False):
        self.calls.append({"source": Path(source), "out": Path(out), "options": options,
                           "overwrite": overwrite})  # fmt: skip
        photos = sorted(Path(source).glob("*.png"))
        n = len(photos)
        for phase in PHASES[:-1]:
            for i in range(n + 1):
                if cancel is not None and cancel():
                    raise PoseError("cancelled")  # PoseCancelled is a PoseError
                if progress is not None:
                    progress(phase, i, n)
                if phase == "extract" and self.block:
                    self.started.set()
                    while not cancel():
                        threading.Event().wait(0.01)
            if phase == "match" and self.fail:
                raise PoseError(self.fail)
        kept = photos[:-1]
        with staged_folder(out) as tmp:
            (tmp / "images").mkdir()
            for p in photos:
                shutil.copy(p, tmp / "images" / p.name)
            (tmp / "poses.json").write_text("{}")
        if progress is not None:
            progress("write", 1, 1)
        return SimpleNamespace(
            folder=Path(out), names=[p.name for p in kept], cameras=cameras(len(kept)),
            unregistered=[photos[-1].name], skipped=[("broken.jpg", "not an image file")],
            points=np.zeros((0, 3), np.float32), near=0.5, far=9.0, reprojection_error=0.42,
            timings={p: 0.01 for p in PHASES},
            distortions=[Distortion("opencv", k1=self.k1) if self.k1 else None for _ in kept],
        )  # fmt: skip


def install(monkeypatch, fake: FakeEstimate) -> FakeEstimate:
    """Make the ``poses`` task call ``fake`` instead of the real pose step."""
    monkeypatch.setattr(pose_task.poses, "estimate_poses", fake)
    return fake
