"""Output folders: fresh ones never clobber earlier results, and staged ones appear complete
or not at all (a failure or Ctrl-C while writing leaves nothing behind)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from prosplat.core.paths import fresh_folder, partial_name, staged_folder


def _tree(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): p.read_text() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def test_a_new_folder_appears_only_when_complete(tmp_path):
    out = tmp_path / "out"
    with staged_folder(out) as partial:
        assert partial == partial_name(out) and partial.parent == tmp_path
        assert partial.is_dir() and not any(partial.iterdir())
        (partial / "sub").mkdir()
        (partial / "sub" / "a.txt").write_text("a")
        (partial / "b.txt").write_text("b")
        assert not out.exists()  # nothing at --out while the command runs
    assert _tree(out) == {"b.txt": "b", "sub/a.txt": "a"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


@pytest.mark.parametrize("error", [RuntimeError("a writer failed"), KeyboardInterrupt()])
def test_a_failure_mid_write_leaves_nothing(tmp_path, error):
    out = tmp_path / "new" / "deeper" / "out"  # its parents are made, and removed again
    with pytest.raises(type(error)):
        with staged_folder(out) as partial:
            (partial / "half.txt").write_text("half")
            raise error
    assert list(tmp_path.iterdir()) == []


def test_an_empty_folder_is_filled_and_a_file_refused(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    with staged_folder(out) as partial:
        (partial / "a.txt").write_text("a")
    assert _tree(out) == {"a.txt": "a"}
    (tmp_path / "file").write_text("x")
    with pytest.raises(FileExistsError, match="is a file"):
        with staged_folder(tmp_path / "file"):
            pass


def test_into_a_used_folder_each_entry_replaces_its_namesake_and_the_rest_stays(tmp_path):
    """The ``--overwrite`` semantics: the command's own files and folders are replaced
    (a folder wholesale: no stale render of an earlier run stays in it), a user's stay."""
    out = tmp_path / "out"
    (out / "renders").mkdir(parents=True)
    (out / "renders" / "old_view.png").write_text("old")
    (out / "report.md").write_text("old report")
    (out / "notes.txt").write_text("mine")
    with staged_folder(out) as partial:
        (partial / "renders").mkdir()
        (partial / "renders" / "new_view.png").write_text("new")
        (partial / "report.md").write_text("new report")
    assert _tree(out) == {
        "notes.txt": "mine",
        "renders/new_view.png": "new",
        "report.md": "new report",
    }
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


@pytest.mark.parametrize("error", [OSError("disk full"), KeyboardInterrupt()])
def test_a_failure_leaves_a_used_folder_as_it_was(tmp_path, error):
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.md").write_text("earlier")
    with pytest.raises(type(error)):
        with staged_folder(out) as partial:
            (partial / "report.md").write_text("half")
            raise error
    assert _tree(out) == {"report.md": "earlier"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_killed_runs_partial_folder_is_removed_and_a_running_ones_kept(tmp_path):
    out = tmp_path / "out"
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    dead = partial_name(out, int(gone.stdout))
    dead.mkdir()
    (dead / "half.txt").write_text("half")
    alive = partial_name(out, os.getppid())  # a process that runs (this one's parent)
    alive.mkdir()
    with staged_folder(out) as partial:
        (partial / "a.txt").write_text("a")
    assert not dead.exists() and alive.is_dir()


def test_fresh_folder_never_clobbers(tmp_path):
    out = tmp_path / "out"
    assert fresh_folder(out, overwrite=False) == out
    out.mkdir()
    assert fresh_folder(out, overwrite=False) == out  # empty: used
    (out / "x").write_text("x")
    assert fresh_folder(out, overwrite=False) == tmp_path / "out-2"
    assert fresh_folder(out, overwrite=True) == out


def test_write_text_atomic_replaces_whole_or_not_at_all(tmp_path: Path, monkeypatch) -> None:
    from prosplat.core import paths

    target = tmp_path / "train_config.json"
    paths.write_text_atomic(target, "old")
    assert target.read_text() == "old"

    def fail(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(paths.os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        paths.write_text_atomic(target, "new")
    assert target.read_text() == "old"  # the old file, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["train_config.json"]  # no temporary
