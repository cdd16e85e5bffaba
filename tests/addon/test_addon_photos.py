"""*Import Photos* (issue 69): a folder of photos (or a video) becomes cameras showing them,
posed by the worker's ``poses`` task, exactly as Import Posed Images makes cameras; a failure
or Esc leaves the .blend as it was.

The pose step is a stand-in (:mod:`fake_poses`) with known cameras, run by the real worker
task in the add-on's job thread, so these tests check the add-on's half in seconds.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from fake_poses import NOT_MATCHED, FakeEstimate, cameras, install, write_photos

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

from addon_support import data_counts, run_op  # noqa: E402

from addon.blender import cameras as bl_cameras  # noqa: E402
from addon.blender import modal, steps  # noqa: E402
from addon.core import jobs, photos  # noqa: E402
from prosplat.convert.posed import camera_from_dict  # noqa: E402
from prosplat.worker import run_task  # noqa: E402


@pytest.fixture
def photo_dir(blank, tmp_path: Path) -> Path:
    write_photos(tmp_path / "garden", 4)
    return tmp_path / "garden"


def test_source_and_pose_folder(tmp_path: Path) -> None:
    shots = write_photos(tmp_path / "garden", 2)
    clip = tmp_path / "walk.MP4"
    clip.write_bytes(b"")
    assert photos.photo_source(tmp_path / "garden") == tmp_path / "garden"
    assert photos.photo_source(shots[1]) == tmp_path / "garden"  # a photo means its folder
    assert photos.photo_source(clip) == clip
    assert photos.default_pose_folder(tmp_path / "garden") == tmp_path / "garden_prosplat_poses"
    assert photos.default_pose_folder(clip) == tmp_path / "walk_prosplat_poses"
    assert photos.collection_name(clip) == "ProSplat Inputs walk"
    with pytest.raises(FileNotFoundError, match="nowhere"):
        photos.photo_source(tmp_path / "nowhere")


def test_photos_job_writes_beside_the_photos_never_into_them(photo_dir: Path) -> None:
    task, params = steps.photos_job(str(photo_dir / "img_001.png"), None, 512, 30)
    assert task == "poses"
    assert params == {"source": str(photo_dir), "out": str(photo_dir.parent / "garden_prosplat_poses"),
                      "feature_size": 512, "max_frames": 30}  # fmt: skip
    with pytest.raises(ValueError, match="photos' own folder"):
        steps.photos_job(str(photo_dir), str(photo_dir))


def test_import_photos_creates_the_tasks_cameras(monkeypatch, photo_dir: Path) -> None:
    fake = install(monkeypatch, FakeEstimate())
    scene = bpy.context.scene
    res, err = run_op(bpy.ops.prosplat.import_photos, filepath=str(photo_dir), feature_size=768)
    assert res == {"FINISHED"}, err
    assert fake.calls[-1]["options"].feature_size == 768
    folder = photo_dir.parent / "garden_prosplat_poses"
    coll = scene.prosplat.inputs
    assert coll.name == "ProSplat Inputs garden" and coll.name in scene.collection.children
    objs = bl_cameras.input_cameras(coll)
    assert [o.name for o in objs] == ["img_000", "img_001", "img_002"]  # img_003 not matched
    # the same cameras the task returns: run it again into another pose folder
    want = run_task("poses", {"source": str(photo_dir), "out": str(photo_dir.parent / "again")})
    for obj, frame, cam in zip(objs, want["frames"], cameras(3), strict=True):
        got = bl_cameras.input_frame(obj, scene)
        assert got["image"] == str(folder / "images" / f"{obj.name}.png")
        assert Path(frame["image"]).name == Path(got["image"]).name
        back = camera_from_dict(got["camera"])
        for c in (cam, camera_from_dict(frame["blender"])):
            assert (back.K - c.K).abs().max() < 1e-4
            assert (back.world_to_cam - c.world_to_cam).abs().max() < 1e-5
        assert obj.data.background_images[0].image.filepath == got["image"]
    assert coll[steps.NEAR_PROP] == 0.5 and coll[steps.FAR_PROP] == 9.0
    assert (scene.render.resolution_x, scene.render.resolution_y) == (48, 32)
    assert scene.camera is not None and scene.camera.name not in coll.objects


def test_a_failed_pose_step_leaves_the_blend_untouched(monkeypatch, photo_dir: Path) -> None:
    install(monkeypatch, FakeEstimate(fail=NOT_MATCHED))
    before = data_counts()
    res, err = run_op(bpy.ops.prosplat.import_photos, filepath=str(photo_dir))
    assert res == {"CANCELLED"}
    assert err.strip().splitlines() == [f"Error: import photos failed: {NOT_MATCHED}"]
    assert data_counts() == before and bpy.context.scene.prosplat.inputs is None
    assert sorted(p.name for p in photo_dir.parent.iterdir()) == ["garden"]


def test_a_missing_folder_is_named(blank, tmp_path: Path) -> None:
    before = data_counts()
    res, err = run_op(bpy.ops.prosplat.import_photos, filepath=str(tmp_path / "nowhere"))
    assert res == {"CANCELLED"} and "nowhere" in err and "does not exist" in err
    assert data_counts() == before


class _Reports:
    def __init__(self) -> None:
        self.items: list[tuple[str, str]] = []

    def __call__(self, levels, text) -> None:
        self.items.append((next(iter(levels)), text))


def test_esc_cancels_and_leaves_nothing(monkeypatch, photo_dir: Path) -> None:
    """Esc in the middle of feature extraction, through the modal driver every long
    operator uses: the job stops, nothing is created, no pose folder is written."""
    fake = install(monkeypatch, FakeEstimate(block=True))
    before = data_counts()
    job = jobs.ThreadJob(*steps.photos_job(str(photo_dir))).start()
    reports, applied = _Reports(), []
    driver = modal.JobDriver("import photos", job, applied.append, reports)
    driver.begin(bpy.context)
    t0, pressed = time.monotonic(), False
    while True:
        event = "TIMER"
        if not pressed and fake.started.is_set():
            assert driver.event(bpy.context, "TIMER") == {"RUNNING_MODAL"}
            assert job.message.startswith("finding features")  # the phase shows in the UI
            event, pressed = "ESC", True
        ret = driver.event(bpy.context, event)
        if ret != {"RUNNING_MODAL"}:
            break
        assert time.monotonic() - t0 < 60
        time.sleep(0.02)
    assert ret == {"CANCELLED"} and job.state == "cancelled" and not applied
    assert reports.items == [("WARNING", "import photos cancelled; nothing was created")]
    assert data_counts() == before and "import photos" not in modal.ACTIVE
    assert sorted(p.name for p in photo_dir.parent.iterdir()) == ["garden"]


def test_a_failure_while_creating_cameras_leaves_no_orphans(monkeypatch, photo_dir: Path) -> None:
    """All or nothing inside Blender too: a camera that cannot be made (here a broken
    camera dict) removes the collection, the cameras made before it and their images."""
    install(monkeypatch, FakeEstimate())
    result = run_task("poses", {"source": str(photo_dir), "out": str(photo_dir.parent / "p")})
    del result["frames"][2]["blender"]["lens"]
    before = data_counts()
    with pytest.raises(KeyError, match="lens"):
        steps.apply_photos(result, bpy.context.scene)
    assert data_counts() == before


def test_api_import_photos(monkeypatch, photo_dir: Path) -> None:
    from addon.blender import api

    install(monkeypatch, FakeEstimate())
    coll, result = api.import_photos(photo_dir / "img_000.png", set_resolution=False)
    assert coll.name == "ProSplat Inputs garden" and len(coll.objects) == 3
    assert result["unregistered"] == ["img_003.png"] and result["folder"].endswith(
        "garden_prosplat_poses"
    )


def test_the_external_worker_reports_the_one_line(blank, tmp_path: Path) -> None:
    """The same task in an external worker process: its failure arrives as one line."""
    import sys

    params = {"source": str(tmp_path / "gone"), "out": str(tmp_path / "poses"), "threads": 1}
    job = jobs.ExternalJob("poses", params, sys.executable, persistent=False).start()
    with pytest.raises(jobs.JobError) as e:
        job.wait(180)
    assert (
        str(e.value) == f"{tmp_path / 'gone'} does not exist; choose a folder of photos or a video"
    )


def test_the_operator_defaults_are_the_pose_steps(blank) -> None:
    """The add-on copies PoseOptions' defaults (Blender's own Python may lack torch): they
    must not drift apart."""
    from prosplat.poses import PoseOptions

    props = bpy.ops.prosplat.import_photos.get_rna_type().properties
    assert props["feature_size"].default == PoseOptions().feature_size
    assert props["max_frames"].default == PoseOptions().max_frames
