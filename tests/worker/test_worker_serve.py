"""The warm worker: models stay loaded between jobs, ``--serve`` runs many jobs in one
process, and every job runs with the torch thread count it asks for.

Reuse is asserted on load counters (``result["worker"]``), not on timing alone, so a test
fails if a job reloads a model even on a fast machine. The timing itself is a benchmark:
``benchmarks/addon_worker.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from synthetic_scenes import worker_scene

from prosplat.worker import models, paths_for, run_task, tasks, threads

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> dict:
    """Render params for a 32-px demo scene (Gaussians from the shipped generator)."""
    folder = tmp_path_factory.mktemp("scene") / "s"
    frames, target_camera = worker_scene(folder)
    rec = run_task("reconstruct", {"frames": frames, "device": "cpu", "near": 0.5, "far": 10.0})
    target = {"name": "t", "camera": target_camera}
    return {"arrays": rec["arrays"], "targets": [target], "inputs": frames, "device": "cpu",
            "output_dir": str(folder / "renders"), "frames": frames}  # fmt: skip


@pytest.fixture
def fresh_cache(monkeypatch) -> models.ModelCache:
    cache = models.ModelCache()
    monkeypatch.setattr(models, "MODELS", cache)
    monkeypatch.setattr(tasks, "MODELS", cache)
    return cache


def _render(scene: dict) -> dict:
    return {k: v for k, v in scene.items() if k != "frames"}


def test_second_job_reuses_the_loaded_models(scene, fresh_cache) -> None:
    first = run_task("render", _render(scene))
    assert first["views"][0]["enhanced"]  # the improver was loaded and used
    assert first["worker"]["model_loads"] == {"generator": 1, "improver": 1}
    second = run_task("render", _render(scene))
    assert second["worker"]["model_loads"] == {"generator": 1, "improver": 1}  # no reload
    assert second["worker"]["model_cache_hits"] == first["worker"]["model_cache_hits"] + 1
    # Reconstruct (generator only) and Render View (both) share the generator, evict nothing
    rec = {"frames": scene["frames"], "device": "cpu", "near": 0.5, "far": 10.0}
    run_task("reconstruct", rec)
    third = run_task("render", _render(scene))
    assert third["worker"]["model_loads"] == {"generator": 1, "improver": 1}


def test_cache_reloads_for_other_weights_and_keeps_models_apart(fresh_cache) -> None:
    cpu = torch.device("cpu")
    a = fresh_cache.get(None, cpu, None)
    b = fresh_cache.get(None, cpu, False)
    assert b.improver is None and a.improver is not None  # a copy: b did not change a
    assert b.generator is a.generator and fresh_cache.loads == {"generator": 1, "improver": 1}
    with pytest.raises(FileNotFoundError):
        fresh_cache.get("/no/such/generator.safetensors", cpu, False)
    assert fresh_cache.loads["generator"] == 1  # the failed load counted nothing


def test_a_checkpoint_rewritten_in_place_is_reloaded(fresh_cache, tmp_path: Path) -> None:
    import shutil

    from prosplat.pipeline.model import DEFAULT_WEIGHTS

    ckpt = tmp_path / "gen.safetensors"
    shutil.copy(DEFAULT_WEIGHTS, ckpt)
    cpu = torch.device("cpu")
    fresh_cache.get(str(ckpt), cpu, False)
    fresh_cache.get(str(ckpt), cpu, False)
    assert fresh_cache.loads["generator"] == 1
    os.utime(ckpt, ns=(ckpt.stat().st_atime_ns, ckpt.stat().st_mtime_ns + 10**9))  # retrained
    fresh_cache.get(str(ckpt), cpu, False)
    assert fresh_cache.loads["generator"] == 2


@pytest.mark.parametrize(
    ("cores", "passive", "expected"),
    [(2, True, 2), (2, False, 1), (1, False, 1), (16, True, 4), (16, False, 4), (6, False, 3)],
)
def test_auto_threads_rule(cores: int, passive: bool, expected: int) -> None:
    assert threads.auto_threads(cores, passive) == expected


def test_job_thread_count_is_applied(tmp_path: Path) -> None:
    before = torch.get_num_threads()
    try:
        for n in (1, 2, 1):
            res = run_task("import_ply", {"path": str(_ply(tmp_path)), "threads": n})
            assert res["worker"]["threads"] == n == torch.get_num_threads()
        res = run_task("import_ply", {"path": str(_ply(tmp_path)), "threads": 0})
        assert res["worker"]["threads"] == threads.auto_threads()
        with pytest.raises(ValueError, match="threads"):
            run_task("import_ply", {"path": str(_ply(tmp_path)), "threads": -2})
    finally:
        torch.set_num_threads(before)


def _ply(folder: Path) -> Path:
    from factories import random_gaussians

    from prosplat import write_ply

    path = folder / "a.ply"
    if not path.exists():
        write_ply(random_gaussians(16, 0), path)
    return path


# ---- python -m prosplat.worker --serve ---------------------------------------------------
class Server:
    """A serving worker driven the way the add-on drives it (one JSON line per request)."""

    def __init__(self) -> None:
        env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE", "PYTHONPATH": str(ROOT)}
        self.proc = subprocess.Popen([sys.executable, "-m", "prosplat.worker", "--serve"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     env=env)  # fmt: skip
        self.ready = self.read()

    def read(self) -> dict:
        return json.loads(self.proc.stdout.readline())

    def send(self, line: str) -> dict:
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        return self.read()

    def job(self, folder: Path, task: str, params: dict) -> tuple[dict, dict]:
        job = folder / f"job{len(list(folder.glob('job*.json')))}.json"
        job.write_text(json.dumps({"task": task, "params": params}))
        reply = self.send(json.dumps({"id": job.stem, "job": str(job)}))
        return reply, json.loads(paths_for(job)["status"].read_text())


@pytest.fixture
def server():
    s = Server()
    yield s
    s.proc.kill()
    s.proc.wait()


def test_serve_keeps_models_between_jobs(server, scene, tmp_path: Path) -> None:
    assert server.ready["event"] == "ready" and server.ready["threads"] >= 1
    params = {k: v for k, v in _render(scene).items() if k != "arrays"}
    import numpy as np

    np.savez(tmp_path / "g.npz", **scene["arrays"])
    params["arrays_file"] = str(tmp_path / "g.npz")
    reply1, st1 = server.job(tmp_path, "render", {**params, "threads": 1})
    reply2, st2 = server.job(tmp_path, "render", {**params, "threads": 1})
    assert (reply1["event"], reply1["code"], st1["state"]) == ("finished", 0, "done")
    assert st2["state"] == "done", st2.get("error")
    w1, w2 = st1["result"]["worker"], st2["result"]["worker"]
    assert w1["pid"] == w2["pid"] == server.proc.pid and (w1["jobs"], w2["jobs"]) == (1, 2)
    assert w1["model_loads"] == w2["model_loads"] == {"generator": 1, "improver": 1}
    assert w2["threads"] == 1
    pong = server.send('{"cmd": "ping", "id": 7}')
    assert (pong["event"], pong["id"], pong["jobs"]) == ("pong", 7, 2)


def test_serve_survives_bad_requests_and_failing_jobs(server, tmp_path: Path) -> None:
    assert server.send("{not json")["event"] == "error"
    assert server.send('{"id": 3}')["error"] == "no job file given"
    reply, status = server.job(tmp_path, "import_ply", {"path": "/no/such.ply"})
    assert reply["code"] == 1 and status["state"] == "error"
    assert "not found" in status["error"] and "\n" not in status["error"]  # one line
    reply, status = server.job(tmp_path, "import_ply", {"path": str(_ply(tmp_path))})
    assert reply["code"] == 0 and status["state"] == "done"  # still serving
    server.proc.stdin.close()  # end of input (Blender closed the pipe): the worker leaves
    assert server.proc.wait(timeout=30) == 0


def test_serve_honours_a_cancel_file(server, tmp_path: Path) -> None:
    job = tmp_path / "job.json"
    job.write_text(json.dumps({"task": "import_ply", "params": {"path": str(_ply(tmp_path))}}))
    paths_for(job)["cancel"].touch()
    reply = server.send(json.dumps({"id": 1, "job": str(job)}))
    assert reply["code"] == 3
    assert json.loads(paths_for(job)["status"].read_text())["state"] == "cancelled"


# ---- a camera path: an image sequence ----------------------------------------------------
def _path_targets(scene: dict, frames: list[int]) -> list[dict]:
    cam = scene["targets"][0]["camera"]
    return [{"name": f"Cam_{f:04d}", "camera": cam, "sequence": "Cam", "frame": f} for f in frames]


def test_camera_path_renders_a_frame_numbered_sequence(scene, tmp_path: Path) -> None:
    seen: list[str] = []
    params = {**_render(scene), "targets": _path_targets(scene, [3, 4, 5]),
              "output_dir": str(tmp_path), "save_depth": True}  # fmt: skip
    from prosplat.worker import Progress

    res = run_task("render", params, Progress(lambda f, m: seen.append(m)))
    assert sorted(p.name for p in tmp_path.glob("*.png")) == [
        "Cam_0003.png",
        "Cam_0004.png",
        "Cam_0005.png",
    ]
    assert res["sequence"] == {"prefix": "Cam", "frames": [3, 4, 5], "pattern": "Cam_####.png",
                               "first": str(tmp_path / "Cam_0003.png")}  # fmt: skip
    assert [m for m in seen if m.startswith("rendering")] == [
        "rendering frame 3 (1/3)",
        "rendering frame 4 (2/3)",
        "rendering frame 5 (3/3)",
    ]
    again = run_task("render", params)  # never replaces a frame, never mixes sequences
    assert again["sequence"]["prefix"] == "Cam-2"
    assert (tmp_path / "Cam-2_0005.png").is_file() and (tmp_path / "Cam-2_0005_depth.exr").is_file()


def test_cancelled_camera_path_leaves_no_frames(scene, tmp_path: Path) -> None:
    from prosplat.worker import Cancelled, Progress

    def esc_at_frame_3(fraction: float, message: str) -> None:
        if message.startswith("rendering frame 3"):
            progress.cancel.set()

    progress = Progress(esc_at_frame_3)
    params = {**_render(scene), "targets": _path_targets(scene, [1, 2, 3, 4]),
              "output_dir": str(tmp_path)}  # fmt: skip
    with pytest.raises(Cancelled):
        run_task("render", params, progress)
    assert list(tmp_path.glob("*.png")) == []  # frames 1-2 were written, then removed
