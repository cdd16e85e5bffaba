"""The add-on's session worker: external jobs share one long-lived process that keeps the
models loaded, a dead worker is replaced, Esc still cancels, errors stay one line, and the
CPU-thread preference reaches the job. Reuse is asserted on the worker's pid and load
counters, not on timing (that is ``benchmarks/addon_worker.py``)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.blender
pytest.importorskip("bpy")

import addon_support  # noqa: E402, F401 - puts the repository root on sys.path
from synthetic_scenes import worker_scene  # noqa: E402

from addon.blender import runtime  # noqa: E402
from addon.core import jobs, worker_process  # noqa: E402


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("scene") / "s"
    frames, target = worker_scene(folder)
    return {"folder": folder, "frames": frames, "target": target}


@pytest.fixture(autouse=True)
def no_worker_left():
    worker_process.shutdown()
    yield
    worker_process.shutdown()


def _ext(task: str, params: dict, **kw) -> jobs.ExternalJob:
    return jobs.ExternalJob(task, {**params, "threads": 1}, sys.executable, **kw).start()


def _reconstruct(scene) -> dict:
    return {"frames": scene["frames"], "device": "cpu", "near": 0.5, "far": 10.0}


def _render(scene, arrays, out: Path, n: int = 1) -> dict:
    targets = [{"name": f"v{i}", "camera": scene["target"]} for i in range(n)]
    return {"arrays": arrays, "targets": targets, "inputs": scene["frames"],
            "output_dir": str(out), "device": "cpu"}  # fmt: skip


def test_jobs_share_one_warm_worker(scene, tmp_path: Path) -> None:
    starts = worker_process.STARTS["count"]
    rec = _ext("reconstruct", _reconstruct(scene)).wait(timeout=300)
    first = _ext("render", _render(scene, rec["arrays"], tmp_path)).wait(timeout=300)
    second = _ext("render", _render(scene, rec["arrays"], tmp_path)).wait(timeout=300)
    pids = {r["worker"]["pid"] for r in (rec, first, second)}
    assert pids == {worker_process.current_worker().pid}  # one process served all three
    assert worker_process.STARTS["count"] == starts + 1
    assert [r["worker"]["jobs"] for r in (rec, first, second)] == [1, 2, 3]
    # the generator loaded once (by reconstruct), the improver once (by the first render)
    assert rec["worker"]["model_loads"] == {"generator": 1, "improver": 0}
    assert second["worker"]["model_loads"] == {"generator": 1, "improver": 1}
    assert second["worker"]["threads"] == 1
    assert Path(second["views"][0]["image"]).name == "v0-2.png"


def test_a_dead_worker_is_replaced(scene, tmp_path: Path) -> None:
    ply_job = {"path": str(tmp_path / "g.ply"), "arrays": _tiny_arrays()}
    first = _ext("export_ply", ply_job).wait(timeout=300)
    old = worker_process.current_worker()
    old.proc.kill()  # crashed, or killed by the OS
    old.proc.wait()
    second = _ext("export_ply", {**ply_job, "path": str(tmp_path / "h.ply")}).wait(timeout=300)
    assert second["worker"]["pid"] != first["worker"]["pid"]
    assert worker_process.current_worker().alive() and second["worker"]["jobs"] == 1


def _until_a_quarter_done(job) -> None:
    """Poll ``job`` until it reports 25 % progress (at most 2 minutes)."""
    t0 = time.monotonic()
    while job.progress < 0.25 and time.monotonic() - t0 < 120:
        job.poll()
        time.sleep(0.05)


def test_worker_dying_mid_job_is_an_error_then_a_fresh_worker(scene, tmp_path: Path) -> None:
    rec = _ext("reconstruct", _reconstruct(scene)).wait(timeout=300)
    job = _ext("render", _render(scene, rec["arrays"], tmp_path / "a", n=400))
    _until_a_quarter_done(job)
    job.worker.proc.kill()
    with pytest.raises(jobs.JobError, match="exited with code"):
        job.wait(timeout=60)
    again = _ext("export_ply", {"path": str(tmp_path / "g.ply"), "arrays": _tiny_arrays()})
    assert again.wait(timeout=300)["count"] == 4


def test_esc_cancels_a_served_job_and_the_worker_stays_warm(scene, tmp_path: Path) -> None:
    rec = _ext("reconstruct", _reconstruct(scene)).wait(timeout=300)
    job = _ext("render", _render(scene, rec["arrays"], tmp_path / "a", n=400))
    _until_a_quarter_done(job)
    job.cancel()
    with pytest.raises(jobs.JobCancelled):
        job.wait(timeout=60)
    assert len(list((tmp_path / "a").glob("*.png"))) < 400  # stopped early
    pid = worker_process.current_worker().pid
    after = _ext("render", _render(scene, rec["arrays"], tmp_path / "b")).wait(timeout=300)
    assert after["worker"]["pid"] == pid and after["worker"]["model_loads"]["generator"] == 1


def test_cancelling_a_queued_job_leaves_the_running_one_alone(scene, tmp_path: Path) -> None:
    rec = _ext("reconstruct", _reconstruct(scene)).wait(timeout=300)
    running = _ext("render", _render(scene, rec["arrays"], tmp_path / "a", n=60))
    queued = _ext("export_ply", {"path": str(tmp_path / "g.ply"), "arrays": _tiny_arrays()})
    while running.progress < 0.25:
        running.poll()
        time.sleep(0.05)
    queued.cancel()
    with pytest.raises(jobs.JobCancelled):
        queued.wait(timeout=5)  # at once: it never started, and nothing was killed for it
    result = running.wait(timeout=300)
    assert len(result["views"]) == 60 and result["worker"]["pid"] == queued.worker.pid
    assert not (tmp_path / "g.ply").exists()


def test_errors_are_one_line_and_the_worker_goes_on(tmp_path: Path) -> None:
    with pytest.raises(jobs.JobError) as e:
        _ext("import_ply", {"path": str(tmp_path / "none.ply")}).wait(timeout=300)
    assert "not found" in str(e.value) and "\n" not in str(e.value)
    pid = worker_process.current_worker().pid
    ok = _ext("export_ply", {"path": str(tmp_path / "g.ply"), "arrays": _tiny_arrays()})
    assert ok.wait(timeout=300)["worker"]["pid"] == pid


def test_one_process_per_job_when_asked(tmp_path: Path) -> None:
    params = {"path": str(tmp_path / "g.ply"), "arrays": _tiny_arrays()}
    a = _ext("export_ply", params, persistent=False).wait(timeout=300)
    b = _ext("export_ply", {**params, "path": str(tmp_path / "h.ply")}, persistent=False)
    b = b.wait(timeout=300)
    assert a["worker"]["pid"] != b["worker"]["pid"] and worker_process.current_worker() is None


def test_make_job_passes_the_thread_preference(monkeypatch, tmp_path: Path) -> None:
    prefs = runtime.Defaults(threads=1, python_path=sys.executable)
    monkeypatch.setattr(runtime, "prefs", lambda context=None: prefs)
    job = runtime.make_job(
        "export_ply", {"path": str(tmp_path / "g.ply"), "arrays": _tiny_arrays()}
    )
    assert isinstance(job, jobs.ExternalJob) and job.persistent and job.params["threads"] == 1
    assert job.start().wait(timeout=300)["worker"]["threads"] == 1
    prefs.threads, prefs.keep_worker = 0, False
    job = runtime.make_job(
        "export_ply", {"path": str(tmp_path / "h.ply"), "arrays": _tiny_arrays()}
    )
    assert not job.persistent and job.params["threads"] == 0


def test_shutdown_stops_the_worker(tmp_path: Path) -> None:
    _ext("export_ply", {"path": str(tmp_path / "g.ply"), "arrays": _tiny_arrays()}).wait(300)
    w = worker_process.current_worker()
    assert w.alive()
    worker_process.shutdown()
    assert not w.alive() and worker_process.current_worker() is None


def _tiny_arrays() -> dict:
    from factories import random_gaussians

    from prosplat.convert.pointcloud import to_attributes

    return to_attributes(random_gaussians(4, 0))


def test_a_camera_path_shows_as_one_image_sequence(tmp_path: Path) -> None:
    import bpy

    from addon.blender import steps

    for f in (1, 2, 3):  # three frames as the render task writes them
        img = bpy.data.images.new(f"f{f}", 4, 4)
        img.filepath_raw, img.file_format = str(tmp_path / f"Cam_{f:04d}.png"), "PNG"
        img.save()
        bpy.data.images.remove(img)
    views = [{"name": f"Cam_{f:04d}", "image": str(tmp_path / f"Cam_{f:04d}.png"), "frame": f}
             for f in (1, 2, 3)]  # fmt: skip
    result = {"views": views, "output_dir": str(tmp_path), "sequence": {"prefix": "Cam",
              "frames": [1, 2, 3], "pattern": "Cam_####.png", "first": views[0]["image"]}}  # fmt: skip
    before = len(bpy.data.images)
    (img,) = steps.apply_render(result)
    assert img.source == "SEQUENCE" and img.name == "ProSplat Cam"
    assert len(bpy.data.images) == before + 1  # one Image, not one per frame
    steps.apply_render(result)  # again: replaced, not duplicated
    assert len(bpy.data.images) == before + 1
    line = steps.describe_render(result)
    assert "3 frame(s)" in line and "Cam_####.png" in line
    assert "s per view" not in line  # a result without the worker's timing
    timed = steps.describe_render({**result, "seconds_per_view": 1.234})
    assert "Cam_####.png (1.23 s per view)" in timed
