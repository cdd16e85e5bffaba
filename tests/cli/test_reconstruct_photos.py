"""``prosplat reconstruct PHOTOS``: a folder of unposed photos is posed into OUT/poses first.

The pose step (:func:`prosplat.poses.estimate_poses`) is replaced by a fake that writes a small
valid pose folder (the analytic demo scene, :func:`synthetic_scenes.write_synthetic_scene`,
with a COLMAP model of its cameras and a ``poses.json`` as the real step writes them) and
counts its calls, so these tests check the command's plumbing in seconds: detection, reuse,
the report, the errors. One test runs the real pose step end to end."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from pathlib import Path

import pytest
import torch
from posed_data import write_colmap_project
from synthetic_scenes import write_synthetic_scene

from prosplat.cli import build_parser, photo_input
from prosplat.cli import poses as poses_cli
from prosplat.core.image_io import write_image
from prosplat.poses import PoseError, PoseResult, load_pose_result, source_record

PHOTOS = [f"{k:03d}.png" for k in range(6)]
NOT_REGISTERED = ["005.png"]
SKIPPED = [("broken.jpg", "not an image")]


def cli(*argv) -> int:
    args = build_parser().parse_args([str(a) for a in argv])
    return args.func(args)


@pytest.fixture
def photos(tmp_path) -> Path:
    """A folder of 6 photos (no poses) and one broken file."""
    folder = tmp_path / "photos"
    folder.mkdir()
    for k, name in enumerate(PHOTOS):
        write_image(folder / name, torch.full((3, 24, 32), k / 8))
    (folder / "broken.jpg").write_bytes(b"not a jpeg")
    return folder


class FakePoses:
    """Stands in for estimate_poses: 000-004 registered (the demo scene's cameras), 005 not."""

    def __init__(self, error: str | None = None) -> None:
        self.calls: list[tuple[Path, Path]] = []
        self.error = error

    def __call__(self, source, out, options, *, progress=None, cancel=None, overwrite=False):
        self.calls.append((Path(source), Path(out)))
        if progress:
            progress("prepare", 7, 7)
        if self.error:
            raise PoseError(self.error)
        out = Path(out)
        assert overwrite or not out.exists()
        shutil.rmtree(out, ignore_errors=True)  # as estimate_poses(overwrite=True) replaces it
        cams = write_synthetic_scene(out, size=32, n_views=5)
        with tempfile.TemporaryDirectory() as tmp:  # the same cameras as a COLMAP model
            write_colmap_project(Path(tmp) / "model", cams)
            shutil.move(Path(tmp) / "model" / "sparse", out / "sparse")
        result = PoseResult(
            folder=out,
            names=[f"{k:03d}.png" for k in range(5)],
            cameras=[],
            unregistered=list(NOT_REGISTERED),
            skipped=list(SKIPPED),
            points=torch.zeros(0, 3).numpy(),
            near=0.5,
            far=10.0,
            reprojection_error=0.42,
            timings={"extract": 1.0, "match": 2.0, "map": 3.0},
        )
        write_fake_record(out, Path(source), options, result)
        return result


def write_fake_record(out: Path, source: Path, options, result: PoseResult) -> None:
    """poses.json as estimate_poses writes it (the fields the reuse check and the report read)."""
    record = {
        "source": str(source),
        "source_files": source_record(source),
        "options": dataclasses.asdict(options),
        "registered": result.names,
        "unregistered": result.unregistered,
        "skipped": [list(s) for s in result.skipped],
        "near": result.near,
        "far": result.far,
        "reprojection_error": result.reprojection_error,
        "timings": result.timings,
    }
    (out / "poses.json").write_text(json.dumps(record))


@pytest.fixture
def fake(monkeypatch) -> FakePoses:
    f = FakePoses()
    monkeypatch.setattr(poses_cli, "estimate_poses", f)
    return f


def test_photo_folder_is_posed_then_reconstructed_and_reported(photos, fake, tmp_path, capsys):
    out = tmp_path / "out"
    assert cli("reconstruct", photos, "--out", out, "--size", "32", "--num-inputs", "2",
               "--max-renders", "1") == 0  # fmt: skip
    assert fake.calls == [(photos, out / "poses")]  # posed straight into OUT/poses
    assert (out / "poses" / "transforms.json").is_file() and (out / "gaussians.ply").is_file()
    report = (out / "report.md").read_text()
    assert "2 of 6 registered" not in report and "5 of 6 registered" in report
    assert "not registered (1): 005.png" in report
    assert "skipped, unreadable (1): broken.jpg (not an image)" in report
    assert "input views: 000, 004" in report  # picked among the registered photos
    printed = capsys.readouterr().out
    assert "5 of 6 photos registered" in printed and "not registered: 005.png" in printed


def test_poses_survive_a_failed_reconstruct_and_are_reused(photos, fake, tmp_path, capsys):
    out = tmp_path / "out"
    # fails after the pose step (no such input view): the poses stay, nothing else is written
    assert cli("reconstruct", photos, "--out", out, "--size", "32", "--inputs", "nope", "000") == 2
    assert len(fake.calls) == 1 and sorted(os.listdir(out)) == ["poses"]
    # the re-run needs no --overwrite (OUT holds only the poses) and does not pose again
    assert cli("reconstruct", photos, "--out", out, "--size", "32", "--num-inputs", "2",
               "--render", "none") == 0  # fmt: skip
    assert len(fake.calls) == 1
    assert "reused from an earlier run" in (out / "report.md").read_text()
    assert "reusing the poses" in capsys.readouterr().out
    # other pose options: posed again (with --overwrite: OUT now holds a result)
    assert cli("reconstruct", photos, "--out", out, "--size", "32", "--num-inputs", "2",
               "--render", "none", "--overwrite", "--feature-size", "512") == 0  # fmt: skip
    assert len(fake.calls) == 2
    # a photo changed: posed again
    os.utime(photos / "001.png", ns=(1, 1))
    assert cli("reconstruct", photos, "--out", out, "--size", "32", "--num-inputs", "2",
               "--render", "none", "--overwrite", "--feature-size", "512") == 0  # fmt: skip
    assert len(fake.calls) == 3


def test_other_poses_in_out_are_not_replaced_without_overwrite(photos, fake, tmp_path, capsys):
    out = tmp_path / "out"
    assert cli("reconstruct", photos, "--out", out, "--size", "32", "--inputs", "nope") == 2
    (photos / "000.png").unlink()  # the photos changed since
    capsys.readouterr()
    assert cli("reconstruct", photos, "--out", out, "--size", "32") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--overwrite" in err[0] and len(fake.calls) == 1


def test_pose_error_exits_2_with_one_line_and_writes_nothing(photos, monkeypatch, tmp_path, capsys):
    message = "only 1 of 6 photos could be matched (registered): take more photos with overlap"
    monkeypatch.setattr(poses_cli, "estimate_poses", FakePoses(error=message))
    out = tmp_path / "out"
    capsys.readouterr()
    assert cli("reconstruct", photos, "--out", out, "--size", "32") == 2
    err = [e for e in capsys.readouterr().err.strip().splitlines() if "%|" not in e]  # tqdm bars
    assert err == [f"prosplat reconstruct: {message}"]
    assert not out.exists()


def test_bad_flags_are_refused_before_the_pose_step(photos, fake, tmp_path, capsys):
    for flags in (["--size", "40"], ["--images", str(photos)], ["--refine-seconds", "0"]):
        assert cli("reconstruct", photos, "--out", tmp_path / "out", *flags) == 2
    assert fake.calls == [] and not (tmp_path / "out").exists()


def test_a_posed_folder_goes_the_old_way(fake, tmp_path):
    scene = tmp_path / "scene"
    write_synthetic_scene(scene, size=32, n_views=4)  # images/ + transforms.json
    assert photo_input.photo_input(scene) is None
    assert cli("reconstruct", scene, "--out", tmp_path / "out", "--size", "32",
               "--num-inputs", "2", "--render", "none") == 0  # fmt: skip
    assert fake.calls == [] and not (tmp_path / "out" / "poses").exists()
    assert "not registered" not in (tmp_path / "out" / "report.md").read_text()


def test_a_folder_without_photos_or_poses_says_photos_are_accepted(tmp_path, capsys):
    empty = tmp_path / "empty"
    (empty / "images").mkdir(parents=True)
    write_image(empty / "images" / "a.png", torch.rand(3, 8, 8))
    capsys.readouterr()
    assert cli("reconstruct", empty, "--out", tmp_path / "out") == 2
    err = capsys.readouterr().err.strip()
    assert "a folder of photos" in err and "images holds photos: give that folder" in err
    assert photo_input.photo_input(empty / "images") == "photos"


def test_the_fake_pose_folder_reads_back(photos, fake, tmp_path):
    """The fake writes what the real pose step writes (else the tests above prove nothing)."""
    result = fake(photos, tmp_path / "p", photo_input.PoseOptions())
    back = load_pose_result(tmp_path / "p")
    assert back.names == result.names and back.unregistered == result.unregistered


def test_a_video_is_posed_and_reused_by_its_size_and_time(fake, tmp_path, capsys):
    clip = tmp_path / "clip.MP4"
    clip.write_bytes(b"frames")  # the fake pose step never decodes it
    out = tmp_path / "out"
    args = ["--out", out, "--size", "32", "--num-inputs", "2", "--render", "none"]
    assert cli("reconstruct", clip, *args) == 0
    assert cli("reconstruct", clip, *args, "--overwrite") == 0
    assert fake.calls == [(clip, out / "poses")]  # the second run reused the poses
    assert "video frames: " in (out / "report.md").read_text()
    clip.write_bytes(b"other frames")
    assert cli("reconstruct", clip, *args, "--overwrite") == 0
    assert len(fake.calls) == 2
