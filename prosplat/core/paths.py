"""Where ProSplat keeps files: its cache (compiled kernels, converted weights, reference venvs),
fresh output folders that never clobber earlier results, and output folders written aside
(:func:`staged_folder`) so that a failed or interrupted command leaves no half-written one. A
leaf module: the CLI, the benchmarks, the demo and the evaluation ladder all import it, and it
imports none of them."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

CACHE_ENV = "PROSPLAT_CACHE"


def cache_dir() -> Path:
    """``$PROSPLAT_CACHE`` if set (and non-empty), else ``~/.cache/prosplat``."""
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "prosplat"


def fresh_folder(path: Path, overwrite: bool) -> Path:
    """``path`` if it is new, empty, or ``overwrite``; otherwise the first free ``path-N``.

    Earlier results are never clobbered by a re-run unless the user asks.
    """
    if overwrite or not path.exists() or not any(path.iterdir()):
        return path
    k = 2
    while (candidate := path.with_name(f"{path.name}-{k}")).exists() and any(candidate.iterdir()):
        k += 1
    return candidate


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` through a hidden sibling and a rename: a reader (or a resumed run) sees
    the old file or the new one, never half of one."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def partial_name(out: Path, pid: int | None = None) -> Path:
    """The sibling folder :func:`staged_folder` writes ``out`` into: ``.NAME.partial-PID``
    (hidden, and named for the process, as ``prosplat scenes render`` names its scenes')."""
    return out.with_name(f".{out.name}.partial-{os.getpid() if pid is None else pid}")


@contextmanager
def staged_folder(out: str | os.PathLike[str]) -> Iterator[Path]:
    """Write a command's output folder aside, and move it to ``out`` only when complete.

    Yields a new, empty sibling folder (:func:`partial_name`) to write everything into. When
    the block ends normally, its contents become ``out``: by one rename when ``out`` is new
    or empty (atomic: the folder appears complete or not at all); into a non-empty ``out``
    (``--overwrite``, or a folder ``fresh_folder`` gave back) each top-level entry replaces
    the one of the same name, so this command's files are replaced and anything else there
    stays. When the block raises anything, Ctrl-C (KeyboardInterrupt) included, the partial
    folder is deleted with the folders made for it, ``out`` is untouched, and the exception
    goes on. Left-overs of processes that were killed (a partial folder whose process is
    gone) are deleted on the way in.

    Why aside and not in place: a command that stops halfway (a bad input found late, a
    crash, Ctrl-C) would otherwise leave a folder that looks like a result.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} is a file; give a folder")
    made = [d for d in (out.parent, *out.parent.parents) if not d.exists()]
    out.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_partials(out)
    partial = partial_name(out)
    shutil.rmtree(partial, ignore_errors=True)  # our own pid's: a killed run's, reused
    partial.mkdir()
    try:
        yield partial
        _move_into_place(partial, out)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        for d in made:  # deepest first; stop at the first one something else now fills
            try:
                d.rmdir()
            except OSError:
                break
        raise


def _remove_stale_partials(out: Path) -> None:
    """Delete partial folders of ``out`` whose process is gone (killed, not interrupted)."""
    if os.name == "nt":  # os.kill(pid, 0) would end the process there, not probe it
        return
    for leftover in out.parent.glob(f".{out.name}.partial-*"):
        suffix = leftover.name.rsplit("-", 1)[1]
        if not suffix.isdigit() or int(suffix) in (0, os.getpid()):
            continue  # not a partial folder of ours; our own is replaced by the caller
        try:
            os.kill(int(suffix), 0)  # still running: another process owns it
        except ProcessLookupError:
            shutil.rmtree(leftover, ignore_errors=True)
        except (PermissionError, OSError):  # running as another user, or cannot tell
            pass


def _move_into_place(partial: Path, out: Path) -> None:
    """``partial``'s contents to ``out`` (see :func:`staged_folder`); ``partial`` is gone after."""
    if out.is_dir() and not any(out.iterdir()):
        out.rmdir()  # an empty folder the user made: renamed over, as if new
    if not out.exists():
        os.rename(partial, out)
        return
    for entry in sorted(partial.iterdir()):
        dest = out / entry.name
        if dest.is_dir() and not dest.is_symlink():
            old = dest.with_name(f".{entry.name}.old-{os.getpid()}")
            os.rename(dest, old)
            os.rename(entry, dest)
            shutil.rmtree(old, ignore_errors=True)
        else:
            if entry.is_dir() and (dest.exists() or dest.is_symlink()):
                dest.unlink()
            os.replace(entry, dest)  # a file replaces a file atomically
    partial.rmdir()
