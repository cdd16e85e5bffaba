"""The scene the add-on speed benchmarks render: the analytic demo scene at 128 px (two input
views, Gaussians from the shipped generator), written once to a folder and reused."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIZE = 128


def ensure_scene(folder: Path) -> Path:
    """Write the scene (images, cameras, the generator's Gaussians) into ``folder`` once."""
    if (folder / "bench.json").is_file():
        return folder
    sys.path.insert(0, str(ROOT / "tests"))
    from synthetic_scenes import write_synthetic_scene

    from prosplat.convert.posed import camera_to_blender_dict
    from prosplat.worker import run_task

    cams = write_synthetic_scene(folder, size=SIZE, n_views=4)
    frames = [{"name": f"{i:03d}", "image": str(folder / "images" / f"{i:03d}.png"),
               "camera": camera_to_blender_dict(cams[i])} for i in (0, 2)]  # fmt: skip
    rec = run_task("reconstruct", {"frames": frames, "device": "cpu", "near": 0.5, "far": 10.0})
    np.savez(folder / "gaussians.npz", **rec["arrays"])
    target = {"name": "target", "camera": camera_to_blender_dict(cams[1])}
    (folder / "bench.json").write_text(json.dumps({"inputs": frames, "target": target}))
    return folder


def render_params(folder: str | Path, out: str | Path | None = None) -> dict:
    """A ``render`` task's params for the scene's 128-px target camera (enhanced, CPU)."""
    folder = Path(folder)
    spec = json.loads((folder / "bench.json").read_text())
    with np.load(folder / "gaussians.npz") as z:
        arrays = {k: z[k] for k in z.files}
    return {"arrays": arrays, "targets": [spec["target"]], "inputs": spec["inputs"],
            "output_dir": str(out or folder / "renders"), "device": "cpu", "enhance": True}  # fmt: skip
