"""Bad posed sets as a new user makes them (issue 67, item 8), and commands that stop halfway.

A 12-frame scene folder whose frames all have one pose, or that lists one frame three times,
ends in one clear line on stderr (exit 2) or, when at least 2 distinct views remain, in a
clean success with distinct views; and nothing is left beside ``--out`` either way. A failure
or Ctrl-C while the output is being written leaves no output folder and no partial one.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from synthetic_scenes import write_synthetic_scene

import prosplat.cli.reconstruct as reconstruct
import prosplat.core.image_io as image_io
from prosplat.cli import build_parser
from prosplat.convert.nerfstudio import read_transforms
from prosplat.pipeline.posed_views import load_posed_set, pick_views


def cli(*argv) -> int:
    args = build_parser().parse_args([str(a) for a in argv])
    return args.func(args)


def _one_line_error(capsys, command: str) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    err = [e for e in err if e.strip() and not e.startswith(("reading", "rendering"))]  # tqdm
    assert len(err) == 1 and err[0].startswith(f"prosplat {command}: "), err
    return err[0]


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    """A 12-frame scene folder (the analytic demo scene on an arc, 32 px)."""
    folder = tmp_path_factory.mktemp("bad") / "scene"
    write_synthetic_scene(folder, size=32, n_views=12)
    return folder


def _variant(scene: Path, dest: Path, how: str) -> Path:
    """A copy of ``scene`` in ``dest`` with its transforms.json made bad ``how``."""
    shutil.copytree(scene, dest)
    data = json.loads((dest / "transforms.json").read_text())
    frames = data["frames"]
    if how == "same pose":  # every frame the first frame's pose
        for f in frames:
            f["transform_matrix"] = frames[0]["transform_matrix"]
    elif how == "one frame thrice":  # the file lists one frame, three times
        data["frames"] = [frames[0]] * 3
    elif how == "a frame thrice":  # the first frame listed three times among the others
        data["frames"] = [frames[0]] * 3 + frames[1:]
    elif how == "poses of 3":  # frames 3 apart share a pose: 3 distinct poses of 12 frames
        for k, f in enumerate(frames):
            f["transform_matrix"] = frames[k % 3]["transform_matrix"]
    (dest / "transforms.json").write_text(json.dumps(data, indent=1))
    return dest


def _listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.mark.parametrize(
    ("how", "match"),
    [
        ("same pose", "has 12 frames but they all have the same camera pose"),
        ("one frame thrice", "lists only 1 distinct image (images/000.png 3 times)"),
    ],
)
def test_too_few_distinct_views_end_in_one_line_and_leave_nothing(
    scene, tmp_path, capsys, how, match
):
    data = _variant(scene, tmp_path / "data", how)
    for command in (["reconstruct"], ["eval", "posed"]):
        capsys.readouterr()
        assert cli(*command, data, "--out", tmp_path / "out", "--size", "32") == 2
        line = _one_line_error(capsys, " ".join(command))
        assert match in line and "at least 2" in line, line
        assert _listing(tmp_path) == ["data"]  # no output folder, no partial one


def test_a_frame_listed_thrice_is_used_once_with_a_warning(scene, tmp_path, capsys):
    data = _variant(scene, tmp_path / "data", "a frame thrice")
    posed = load_posed_set(data)
    assert posed.names == [f"{i:03d}" for i in range(12)]  # stems again: no repeats
    assert posed.repeats == ["images/000.png", "images/000.png"]
    out = tmp_path / "out"
    assert cli("reconstruct", data, "--out", out, "--size", "32", "--max-renders", "2") == 0
    captured = capsys.readouterr()
    assert "warning: left out 2 frames" in captured.out and "images/000.png" in captured.out
    report = (out / "report.md").read_text()
    assert "- leave-one-out over 4 inputs: re-rendered" in report  # prosplat.pipeline.trust
    inputs = next(ln for ln in report.splitlines() if ln.startswith("- input views: "))
    names = inputs.removeprefix("- input views: ").split(", ")
    assert len(names) == 4 and len(set(names)) == 4, names
    tf = read_transforms(out / "transforms.json")
    assert [f.file_path for f in tf.frames] == [f"inputs/{n}.png" for n in names]
    assert _listing(tmp_path) == ["data", "out"]


def test_coincident_cameras_count_as_one_view(scene, tmp_path, capsys):
    data = _variant(scene, tmp_path / "data", "poses of 3")
    posed = load_posed_set(data)
    assert posed.first_of_pose() == [k % 3 for k in range(12)]
    assert pick_views(posed, None, 3) == [0, 1, 2]
    with pytest.raises(ValueError, match="only 3 distinct camera poses"):
        pick_views(posed, None, 4)
    with pytest.raises(ValueError, match="--inputs 001 and 004 have the same camera pose"):
        pick_views(posed, ["001", "004"])
    out = tmp_path / "out"
    # without --num-inputs: as many inputs as there are distinct poses (up to 4)
    assert cli("reconstruct", data, "--out", out, "--size", "32", "--render", "none") == 0
    assert "input views: 000, 001, 002" in (out / "report.md").read_text()


def _fail_on_the_second_image(monkeypatch, error: BaseException) -> None:
    """``write_image`` writes one file, then raises ``error``: a failure mid-write."""
    real, calls = image_io.write_image, []

    def writer(*args, **kwargs):
        calls.append(args[0])
        if len(calls) == 2:
            raise error
        return real(*args, **kwargs)

    monkeypatch.setattr(image_io, "write_image", writer)
    if hasattr(reconstruct, "write_image"):  # imported at the module's top
        monkeypatch.setattr(reconstruct, "write_image", writer)


@pytest.mark.parametrize("error", [OSError("disk full"), KeyboardInterrupt()])
def test_reconstruct_stopped_mid_write_leaves_nothing(scene, tmp_path, monkeypatch, error):
    _fail_on_the_second_image(monkeypatch, error)
    with pytest.raises(type(error)):
        cli("reconstruct", scene, "--out", tmp_path / "a" / "out", "--size", "32",
            "--render", "none")  # fmt: skip
    assert _listing(tmp_path) == []  # neither out, nor its partial folder, nor a/


@pytest.mark.parametrize("error", [OSError("disk full"), KeyboardInterrupt()])
def test_reconstruct_overwrite_stopped_mid_write_keeps_the_earlier_result(
    scene, tmp_path, monkeypatch, error
):
    out = tmp_path / "out"
    assert cli("reconstruct", scene, "--out", out, "--size", "32", "--render", "none") == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    _fail_on_the_second_image(monkeypatch, error)
    with pytest.raises(type(error)):
        cli("reconstruct", scene, "--out", out, "--size", "32", "--num-inputs", "3",
            "--render", "none", "--overwrite")  # fmt: skip
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before and _listing(tmp_path) == ["out"]


def test_eval_posed_stopped_mid_write_leaves_nothing(scene, tmp_path, monkeypatch):
    import prosplat.eval.posed as posed

    def broken(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(posed, "contact_sheet", broken)  # after summary.md and the scores
    with pytest.raises(KeyboardInterrupt):
        cli("eval", "posed", scene, "--out", tmp_path / "out", "--size", "32",
            "--num-inputs", "2", "--targets", "1")  # fmt: skip
    assert _listing(tmp_path) == []
