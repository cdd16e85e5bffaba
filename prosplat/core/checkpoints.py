"""safetensors checkpoints that carry their own config, written atomically and never clobbered.

Both models (generator and improvement model) store their weights with a JSON config in the
file's metadata, so a checkpoint always rebuilds the network it was trained as.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from torch import Tensor


def _no_clobber_write(tmp: Path, path: Path, overwrite: bool) -> None:
    """Move the finished ``tmp`` to ``path`` atomically; without ``overwrite``, a hard link
    (which fails if ``path`` exists, even if it appeared a moment ago) never replaces a file."""
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it") from None
    except OSError:  # a filesystem without hard links: check, then rename
        if path.exists():
            raise FileExistsError(f"{path} exists; pass overwrite=True to replace it") from None
        os.replace(tmp, path)
        return
    tmp.unlink()


def write_checkpoint(
    state: dict[str, Tensor], path: str | Path, metadata: dict[str, str], overwrite: bool = False
) -> Path:
    """Write ``state`` + ``metadata`` to ``path`` through a temp file in the same folder, never
    replacing an existing file unless ``overwrite``."""
    from safetensors.torch import save_file

    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().contiguous() for k, v in state.items()}
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        save_file(state, str(tmp), metadata=metadata)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp/safetensors make 0600; use the usual mode
        _no_clobber_write(tmp, path, overwrite)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def read_checkpoint(path: str | Path, what: str) -> tuple[dict[str, Tensor], dict[str, str]]:
    """(tensors on the CPU, metadata) of a safetensors file; clear errors for missing or
    unreadable files (``what`` names the kind of checkpoint in them)."""
    from safetensors import safe_open
    from safetensors.torch import load_file

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} checkpoint {path} does not exist")
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = f.metadata() or {}
        state = load_file(str(path), device="cpu")
    except Exception as e:  # safetensors raises its own error types for corrupt files
        raise ValueError(f"{path} is not a readable safetensors checkpoint: {e}") from e
    return state, meta
