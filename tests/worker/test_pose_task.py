"""The worker's ``poses`` task (issue 69): a folder of photos in, the registered photos'
cameras out as blender camera dicts with their working copies, progress per phase, Esc and
the pose step's one-line failures as every other job has them.

The pose step itself is a stand-in here (:mod:`fake_poses`), so these tests check the task's
plumbing in a fraction of a second; the end-to-end test at the bottom runs the real one.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fake_poses import NOT_MATCHED, FakeEstimate, cameras, install, write_photos

from prosplat.convert.posed import camera_from_dict, camera_to_blender_dict
from prosplat.worker import Cancelled, Progress, paths_for, run_job_file, run_task
from prosplat.worker.pose_task import PhaseProgress


def _progress(log: list, cancel_at: str | None = None) -> Progress:
    """A Progress that records (fraction, message) and cancels once a message starts so."""

    def report(fraction: float, message: str) -> None:
        log.append((fraction, message))
        if cancel_at and message.startswith(cancel_at):
            progress.cancel.set()

    progress = Progress(report)
    return progress


def test_poses_task_returns_the_registered_photos_as_blender_cameras(monkeypatch, tmp_path):
    fake = install(monkeypatch, FakeEstimate())
    photos = write_photos(tmp_path / "photos", 4)
    log: list = []
    progress = _progress(log)
    params = {"source": str(tmp_path / "photos"), "out": str(tmp_path / "poses"),
              "feature_size": 512, "threads": 1}  # fmt: skip
    result = run_task("poses", params, progress)
    assert fake.calls[0]["options"].feature_size == 512
    assert fake.calls[0]["out"] == tmp_path / "poses" and not fake.calls[0]["overwrite"]
    folder = tmp_path / "poses"
    assert result["folder"] == str(folder) and result["source"] == str(tmp_path / "photos")
    assert [f["name"] for f in result["frames"]] == ["img_000", "img_001", "img_002"]
    for frame, photo, cam in zip(result["frames"], photos[:3], cameras(3), strict=True):
        assert frame["image"] == str(folder / "images" / photo.name)
        assert Path(frame["image"]).is_file()
        assert frame["blender"] == camera_to_blender_dict(cam)
        back = camera_from_dict(frame["blender"])
        assert (back.K - cam.K).abs().max() < 1e-9
        assert (back.world_to_cam - cam.world_to_cam).abs().max() < 1e-9
    assert (result["registered"], result["photos"]) == (3, 4)
    assert result["unregistered"] == ["img_003.png"]
    assert result["skipped"] == [["broken.jpg", "not an image file"]]
    assert (result["near"], result["far"], result["reprojection_error"]) == (0.5, 9.0, 0.42)
    assert result["warnings"] == ["1 of 4 photos could not be matched and have no camera: img_003.png",
                                  "skipped broken.jpg: not an image file"]  # fmt: skip
    json.dumps(result)  # the result travels as JSON from an external worker
    # progress: every phase named with its count, never going back
    fractions = [f for f, _ in log]
    assert fractions == sorted(fractions) and fractions[-1] < 1.0
    messages = [m for _, m in log]
    for text in ("reading photos (4/4)", "finding features (2/4)", "matching photos (4/4)",
                 "solving camera poses (0/4)", "writing the pose folder (1/1)"):  # fmt: skip
        assert text in messages, messages


def test_an_existing_pose_folder_is_kept(monkeypatch, tmp_path: Path) -> None:
    install(monkeypatch, FakeEstimate())
    write_photos(tmp_path / "photos", 3)
    (tmp_path / "poses").mkdir()
    (tmp_path / "poses" / "mine.txt").write_text("an earlier run's")
    result = run_task("poses", {"source": str(tmp_path / "photos"), "out": str(tmp_path / "poses")})
    assert result["folder"] == str(tmp_path / "poses-2")
    assert (tmp_path / "poses" / "mine.txt").read_text() == "an earlier run's"


def test_pose_error_fails_the_job_with_its_one_line(monkeypatch, tmp_path: Path) -> None:
    install(monkeypatch, FakeEstimate(fail=NOT_MATCHED))
    write_photos(tmp_path / "photos", 3)
    job = tmp_path / "job.json"
    params = {"source": str(tmp_path / "photos"), "out": str(tmp_path / "poses")}
    job.write_text(json.dumps({"task": "poses", "params": params}))
    assert run_job_file(job) == 1
    status = json.loads(paths_for(job)["status"].read_text())
    assert (status["state"], status["error"], status["kind"]) == ("error", NOT_MATCHED, "PoseError")
    assert "traceback" not in status and not (tmp_path / "poses").exists()


def test_missing_source_is_named(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nowhere"):
        run_task("poses", {"source": str(tmp_path / "nowhere"), "out": str(tmp_path / "p")})
    with pytest.raises(ValueError, match="no photos given"):
        run_task("poses", {"out": str(tmp_path / "p")})


def test_cancel_mid_features_stops_and_writes_nothing(monkeypatch, tmp_path: Path) -> None:
    install(monkeypatch, FakeEstimate())
    write_photos(tmp_path / "photos", 4)
    log: list = []
    params = {"source": str(tmp_path / "photos"), "out": str(tmp_path / "poses")}
    with pytest.raises(Cancelled):
        run_task("poses", params, _progress(log, cancel_at="finding features (1/4)"))
    assert not any(m.startswith("matching") for _, m in log)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos"]


def test_cancel_file_cancels_a_job(monkeypatch, tmp_path: Path) -> None:
    """The external worker's cancel: the job's .cancel file, seen by the pose step's poll."""
    install(monkeypatch, FakeEstimate())
    write_photos(tmp_path / "photos", 3)
    job = tmp_path / "job.json"
    params = {"source": str(tmp_path / "photos"), "out": str(tmp_path / "poses")}
    job.write_text(json.dumps({"task": "poses", "params": params}))
    paths_for(job)["cancel"].touch()
    assert run_job_file(job) == 3
    assert json.loads(paths_for(job)["status"].read_text())["state"] == "cancelled"
    assert not (tmp_path / "poses").exists()


@pytest.mark.parametrize("video", [False, True])
def test_phase_progress_spans_the_bar_in_order(video: bool) -> None:
    log: list = []
    report = PhaseProgress(_progress(log), video)
    phases = ["frames"] * video + ["prepare", "extract", "match", "map", "write"]
    for phase in phases:
        for i in range(3):
            report(phase, i, 2)
    fractions = [f for f, _ in log]
    assert fractions == sorted(fractions)
    assert fractions[0] == 0.0 and 0.9 < fractions[-1] < 1.0
    assert log[0][1] == ("extracting video frames (0/2)" if video else "reading photos (0/2)")


def test_phase_progress_never_raises_once_cancelled() -> None:
    """pycolmap may call it from its own threads: a cancel shows through ``cancel``."""
    log: list = []
    progress = _progress(log)
    progress.cancel.set()
    PhaseProgress(progress, False)("extract", 1, 4)
    assert log == []


def test_real_pose_step_on_photos_with_no_overlap_fails_in_one_line(tmp_path: Path) -> None:
    """End to end with pycolmap: three unrelated photos cannot be posed; the job says how
    many matched and what to do, and writes no pose folder."""
    from prosplat import poses

    if not hasattr(poses, "estimate_poses"):
        pytest.skip("prosplat.poses.estimate_poses is not there yet")
    write_photos(tmp_path / "photos", 3, seed=5)
    job = tmp_path / "job.json"
    params = {"source": str(tmp_path / "photos"), "out": str(tmp_path / "poses"),
              "feature_size": 256, "threads": 1}  # fmt: skip
    job.write_text(json.dumps({"task": "poses", "params": params}))
    assert run_job_file(job) == 1
    status = json.loads(paths_for(job)["status"].read_text())
    assert status["kind"] == "PoseError" and "\n" not in status["error"]
    assert "of 3 photos could be matched" in status["error"], status["error"]
    assert sorted(p.name for p in tmp_path.iterdir() if "poses" in p.name) == []  # nor work


def test_distorted_photos_come_back_undistorted_with_pinhole_cameras(monkeypatch, tmp_path):
    """Blender's cameras are pinholes: a fitted radial term gets undistorted copies."""
    from prosplat.convert.distortion import Distortion, undistorted_camera
    from prosplat.core.image_io import read_image

    install(monkeypatch, FakeEstimate(k1=-0.15))
    write_photos(tmp_path / "photos", 3)
    result = run_task("poses", {"source": str(tmp_path / "photos"), "out": str(tmp_path / "p")})
    folder = tmp_path / "p"
    assert sorted(p.name for p in (folder / "undistorted").iterdir()) == [
        "img_000.png",
        "img_001.png",
    ]
    assert not list(folder.glob(".*partial"))
    for frame, cam in zip(result["frames"], cameras(2), strict=True):
        assert Path(frame["image"]).parent == folder / "undistorted"
        want = undistorted_camera(cam, Distortion("opencv", k1=-0.15))
        assert frame["blender"] == camera_to_blender_dict(want)
        assert read_image(frame["image"]).shape == (3, cam.height, cam.width)


def test_real_pose_step_cancelled_leaves_nothing_beside_the_photos(tmp_path: Path) -> None:
    """Esc during the real pose step: no pose folder and no work folder (the command line
    keeps its work folder to resume; Import Photos leaves nothing)."""
    write_photos(tmp_path / "photos", 3, seed=5)
    log: list = []
    params = {"source": str(tmp_path / "photos"), "out": str(tmp_path / "poses"),
              "feature_size": 256}  # fmt: skip
    with pytest.raises(Cancelled):
        run_task("poses", params, _progress(log, cancel_at="finding features"))
    assert any(m.startswith("finding features") for _, m in log)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos"]
