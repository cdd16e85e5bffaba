"""Bad input and cancelling: the operator says what is wrong (``self.report``), returns
CANCELLED, leaves no half-made data-blocks and overwrites nothing."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

from addon_support import data_counts, run_op  # noqa: E402
from synthetic_scenes import write_synthetic_scene  # noqa: E402

from addon.blender import capture, modal, steps  # noqa: E402
from addon.core import jobs  # noqa: E402


@pytest.fixture
def inputs(blank, tmp_path: Path):
    """Two input cameras of the analytic demo scene, imported; returns the collection (view
    001 is marked a target, so the inputs are 000 and 002: a wide baseline)."""
    write_synthetic_scene(tmp_path / "s", size=64, n_views=3)
    res, err = run_op(bpy.ops.prosplat.import_posed_images, filepath=str(tmp_path / "s"))
    assert res == {"FINISHED"}, err
    coll = bpy.context.scene.prosplat.inputs
    assert sorted(coll.objects.keys()) == ["000", "002"]
    return coll


def test_camera_without_image_is_named(inputs, tmp_path: Path) -> None:
    cam = bpy.data.objects.new("hand made", bpy.data.cameras.new("hand made"))
    inputs.objects.link(cam)
    before = data_counts()
    res, err = run_op(bpy.ops.prosplat.reconstruct)
    assert res == {"CANCELLED"} and "hand made" in err and "no image" in err, err
    assert data_counts() == before


def test_image_deleted_after_import_is_named(inputs, tmp_path: Path) -> None:
    (tmp_path / "s" / "images" / "002.png").unlink()
    res, err = run_op(bpy.ops.prosplat.reconstruct)
    assert res == {"CANCELLED"} and "002" in err and "no image file" in err, err


def test_no_inputs_or_one_camera(blank) -> None:
    res, err = run_op(bpy.ops.prosplat.reconstruct)
    assert res == {"CANCELLED"} and "no input collection" in err
    coll = bpy.data.collections.new("empty")
    bpy.context.scene.prosplat.inputs = coll
    res, err = run_op(bpy.ops.prosplat.reconstruct)
    assert res == {"CANCELLED"} and "has no cameras" in err


def test_render_view_needs_gaussians_and_a_camera(inputs) -> None:
    res, err = run_op(bpy.ops.prosplat.render_view)
    assert res == {"CANCELLED"} and "no Gaussian object" in err


def test_capture_never_writes_into_a_used_folder(blank, tmp_path: Path) -> None:
    (tmp_path / "cap").mkdir()
    (tmp_path / "cap" / "mine.txt").write_text("keep")
    assert capture.free_folder(tmp_path / "cap") == tmp_path / "cap-2"
    assert capture.free_folder(tmp_path / "new") == tmp_path / "new"


def test_capture_abort_leaves_nothing(blank, tmp_path: Path) -> None:
    scene = bpy.context.scene
    cams = []
    for i in range(2):
        cam = bpy.data.objects.new(f"c{i}", bpy.data.cameras.new(f"c{i}"))
        scene.collection.objects.link(cam)
        cam.location = (i, -5, 0)
        cams.append(cam)
    cap = capture.Capture(scene, cams, tmp_path / "cap")
    cap.begin()
    assert cap.tmp.is_dir()
    cap.abort()
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="at least 2"):
        capture.Capture(scene, cams[:1], tmp_path / "cap")
    cams[1].data.type = "ORTHO"
    with pytest.raises(ValueError, match="perspective"):
        capture.Capture(scene, cams, tmp_path / "cap")


class _Reports:
    def __init__(self) -> None:
        self.items: list[tuple[str, str]] = []

    def __call__(self, levels, text) -> None:
        self.items.append((next(iter(levels)), text))


def _drive_cancel(job: jobs.Job, cancel_when) -> tuple[set, _Reports]:
    """Run ``job`` through the modal driver, pressing Esc once ``cancel_when(job)``."""
    reports = _Reports()
    applied = []
    driver = modal.JobDriver("reconstruct", job, applied.append, reports)
    driver.begin(bpy.context)
    t0 = time.monotonic()
    pressed = False
    while True:
        event = "TIMER"
        if not pressed and cancel_when(job):
            event, pressed = "ESC", True
        assert driver.event(bpy.context, "MOUSEMOVE") == {"PASS_THROUGH"}
        ret = driver.event(bpy.context, event)
        if ret != {"RUNNING_MODAL"}:
            break
        assert time.monotonic() - t0 < 120
        time.sleep(0.02)
    assert not applied and "reconstruct" not in modal.ACTIVE
    return ret, reports


def test_esc_mid_reconstruction_cancels_cleanly(inputs, tmp_path: Path) -> None:
    task, params = steps.reconstruct_job(inputs, bpy.context.scene)
    params["ply"] = str(tmp_path / "partial.ply")
    before = data_counts()
    job = jobs.ThreadJob(task, params).start()
    ret, reports = _drive_cancel(job, lambda j: j.progress > 0.0)
    assert ret == {"CANCELLED"} and job.state == "cancelled"
    assert reports.items == [("WARNING", "reconstruct cancelled; nothing was created")]
    assert data_counts() == before and not (tmp_path / "partial.ply").exists()


def test_esc_stops_the_external_worker(inputs, tmp_path: Path) -> None:
    task, params = steps.reconstruct_job(inputs, bpy.context.scene)
    params["ply"] = str(tmp_path / "partial.ply")
    job = jobs.ExternalJob(task, params, sys.executable).start()
    job_dir = job.dir
    ret, _ = _drive_cancel(job, lambda j: j.message.startswith("reading input"))
    assert ret == {"CANCELLED"} and job.state == "cancelled"
    assert not job_dir.exists() and not (tmp_path / "partial.ply").exists()


def test_external_worker_failure_is_reported(inputs, tmp_path: Path) -> None:
    fake = tmp_path / "python"
    fake.write_text("#!/bin/sh\necho 'No module named prosplat' >&2\nexit 1\n")
    fake.chmod(0o755)
    job = jobs.ExternalJob("reconstruct", {"frames": []}, str(fake)).start()
    with pytest.raises(jobs.JobError, match="No module named prosplat.*has prosplat"):
        job.wait(timeout=30)
    with pytest.raises(jobs.JobError, match="not an executable"):
        jobs.ExternalJob("reconstruct", {}, str(tmp_path / "nothing")).start()


def test_job_paths_match_the_worker(tmp_path: Path) -> None:
    from prosplat.worker import paths_for

    assert jobs.job_paths(tmp_path / "job.json") == paths_for(tmp_path / "job.json")
    status = json.dumps({"state": "done"})
    assert json.loads(status)["state"] in jobs.FINISHED
