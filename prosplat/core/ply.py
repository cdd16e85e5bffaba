"""Standard 3DGS PLY read/write, compatible with the INRIA 3DGS, SuperSplat, gsplat and
nerfstudio tools.

On disk a Gaussian is one ``vertex`` with float32 properties, in INRIA's order::

    x y z  nx ny nz  f_dc_0..2  f_rest_0..(3(K-1)-1)  opacity  scale_0..2  rot_0..3

then, for Gaussians that know their input views (:attr:`Gaussians.views`), one more float32
property ``prosplat_view`` (:data:`VIEW_PROPERTY`); tools that read properties by name (INRIA's
Python code, SuperSplat, gsplat, nerfstudio) read past it, while a reader that assumes the
fixed INRIA record size does not: pass ``Gaussians.with_views(None)`` to write without it.
``nx ny nz`` are zeros (INRIA writes them and some viewers expect them), ``opacity`` is a
logit, ``scale_*`` are natural logs, ``rot_*`` is the quaternion (w, x, y, z) as stored.
``f_rest`` is channel-major, as INRIA flattens ``features_rest.transpose(1, 2)``: all
coefficients 1..K-1 of red, then of green, then of blue.

Exactness of a float32 round trip ``read_ply(write_ply(g))``:

* ``means``, ``sh`` and ``quats`` come back bit for bit (they are copied as float32).
* ``opacities`` and ``scales`` are stored as float32 logit / log. The writer computes
  logit / log in float64 and rounds once to float32; the reader computes sigmoid / exp in
  float64 and rounds once to the requested dtype. That is exact (bit for bit) for every float32
  opacity in [0.25, 1] and every scale in (1/e, e), checked exhaustively over those float32
  values. Outside, the float32 code grid is coarser than the float32 value grid (a code ulp
  moves the value by several value ulps), so no float32 code decodes exactly to every value;
  above the clamps below, the relative error is at most ``(|logit(o)| (1 - o) + 1) 2^-24``
  for opacities and ``(|log(s)| + 1) 2^-24`` for scales (e.g. 4.7e-7 for a scale of 1e-3,
  1.8e-7 for an opacity of 0.1): a few float32 ulps.
  Picking a neighbouring float32 code instead of the nearest never gave an exact decode where
  the nearest did not (checked on 10M random values), so the writer simply rounds.
* Values the encodings cannot hold are clamped first (see ``OPACITY_MIN`` etc.), so opacity 0
  comes back as ~1e-38 and scale 0 as ~1e-38; opacity 1 comes back as exactly 1.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement, PlyListProperty, PlyParseError

from prosplat.core.gaussians import Gaussians

#: Smallest opacity written. ``logit(0)`` is -inf, so 0 is clamped here. The smallest normal
#: float32 (2^-126, logit -87.3) leaves every normal float32 opacity untouched and keeps
#: ``exp(-logit)`` finite for tools that decode in float32.
OPACITY_MIN = float(np.finfo(np.float32).tiny)
#: Largest opacity written. ``logit(1)`` is +inf, so 1 is clamped here (logit ~18.0).
#: 1 - 2^-26 is above every float32 below 1 (1 - 2^-24 is the largest), so none of those is
#: changed, and its sigmoid rounds to exactly 1.0 in float32, so opacity 1 survives the trip.
OPACITY_MAX = 1.0 - 2.0**-26
#: Smallest scale written. ``log(0)`` is -inf, so 0 is clamped here (log -87.3): every normal
#: float32 scale passes unchanged, and ``exp`` of the code is finite in float32.
SCALE_MIN = float(np.finfo(np.float32).tiny)

_DEGREE_BY_REST_COUNT = {0: 0, 9: 1, 24: 2, 45: 3}  # number of f_rest_* -> SH degree
_F_REST = re.compile(r"f_rest_(\d+)")
_MEANS = ("x", "y", "z")
_F_DC = ("f_dc_0", "f_dc_1", "f_dc_2")
_SCALES = ("scale_0", "scale_1", "scale_2")
_QUATS = ("rot_0", "rot_1", "rot_2", "rot_3")
_REQUIRED = (*_MEANS, *_F_DC, "opacity", *_SCALES, *_QUATS)
#: The optional last property: the input view that predicted each Gaussian
#: (:attr:`Gaussians.views`), written when known so a scene read back renders as it did
#: (views favour the input nearest them). Other tools read past it as an extra property.
VIEW_PROPERTY = "prosplat_view"
#: Vertex properties read_ply knows but does not keep: INRIA's (always zero) normals.
_IGNORED = frozenset({"nx", "ny", "nz"})


class PlyWarning(UserWarning):
    """Something in a PLY that :func:`read_ply` read past (e.g. properties it drops)."""


def _dropped_message(path: Path, props: list[str], elements: list[str]) -> str | None:
    """One line naming what the file holds that a 3DGS reader drops, or None.

    Splat editors add their own data (SuperSplat a ``transform``, others per-splat ids,
    selection flags or colours); a user who moved or edited splats there should learn that it
    is not applied here rather than find it silently gone.
    """
    parts = []
    if props:
        shown = ", ".join(props[:8]) + (f" and {len(props) - 8} more" if len(props) > 8 else "")
        parts.append(f"vertex properties {shown}")
    if elements:
        parts.append(f"elements {', '.join(elements)}")
    if not parts:
        return None
    return f"{path.name}: dropped {' and '.join(parts)} (not part of a 3DGS Gaussian)"


# ---- encodings ----------------------------------------------------------------------------
def _sigmoid64(x: np.ndarray) -> np.ndarray:
    """Float64 sigmoid, accurate in both tails (no overflow warning for large |x|)."""
    return np.exp(-np.logaddexp(0.0, -x))


def _logit64(p: np.ndarray) -> np.ndarray:
    """Float64 logit of p in (0, 1); ``log1p`` keeps precision for p near 1."""
    return np.log(p) - np.log1p(-p)


def _float_numpy(t: torch.Tensor, dtype: type[np.floating]) -> np.ndarray:
    """A tensor as a CPU numpy array of ``dtype`` (via torch, which also handles bfloat16)."""
    torch_dtype = torch.float64 if dtype is np.float64 else torch.float32
    return t.detach().to(device="cpu", dtype=torch_dtype).numpy()


# ---- write --------------------------------------------------------------------------------
def _property_names(k: int) -> list[str]:
    """INRIA's property order for K SH coefficients per channel."""
    return [
        *_MEANS,
        "nx",
        "ny",
        "nz",
        *_F_DC,
        *(f"f_rest_{i}" for i in range(3 * (k - 1))),
        "opacity",
        *_SCALES,
        *_QUATS,
    ]


def _vertex_array(g: Gaussians) -> np.ndarray:
    """[N] structured float32 array in INRIA's layout, filled column block by column block,
    then :data:`VIEW_PROPERTY` when the Gaussians know their views (float32 holds every
    view index exactly)."""
    n, k = len(g), g.sh.shape[1]
    names = _property_names(k) + ([VIEW_PROPERTY] if g.views is not None else [])
    table = np.zeros((n, len(names)), dtype="<f4")  # [N, P]; nx ny nz stay 0
    table[:, 0:3] = _float_numpy(g.means, np.float32)
    sh = _float_numpy(g.sh, np.float32)  # [N, K, 3]
    table[:, 6:9] = sh[:, 0]
    rest = 3 * (k - 1)
    # [N, K-1, 3] -> [N, 3, K-1]: channel-major, as INRIA writes f_rest (no temporary copy).
    table[:, 9 : 9 + rest].reshape(n, 3, k - 1)[:] = sh[:, 1:].transpose(0, 2, 1)
    col = 9 + rest

    opacity = _float_numpy(g.opacities, np.float64)  # [N]
    logit = _logit64(np.clip(opacity, OPACITY_MIN, OPACITY_MAX))
    table[:, col] = logit  # float64 -> float32: round to nearest, the best code there is
    scales = _float_numpy(g.scales, np.float64)  # [N, 3]
    log_scales = np.log(np.maximum(scales, SCALE_MIN))
    table[:, col + 1 : col + 4] = log_scales
    table[:, col + 4 : col + 8] = _float_numpy(g.quats, np.float32)
    if g.views is not None:
        table[:, col + 8] = g.views.detach().cpu().numpy()

    dtype = np.dtype([(name, "<f4") for name in names])
    return table.view(dtype).reshape(n)  # same memory, one record per row


def write_ply(
    gaussians: Gaussians, path: str | os.PathLike[str], overwrite: bool = False, binary: bool = True
) -> None:
    """Write ``gaussians`` as a standard 3DGS PLY (layout in the module docstring).

    Everything is written as float32, the type every splat tool reads; float64 Gaussians are
    rounded. ``binary=False`` writes ASCII (readable, but large and slow: plyfile formats it
    row by row, so use it for small files and debugging).

    Nothing the user owns is overwritten unless ``overwrite=True``, and the file appears
    atomically: the data goes to a hidden temporary file in the same folder, which is then
    renamed into place, so an interrupted write never leaves a half file under ``path``.
    The folder must exist (a typo in a folder name should fail, not create a tree).

    Raises:
        FileNotFoundError: the folder of ``path`` does not exist.
        FileExistsError: ``path`` exists and ``overwrite`` is False.
        ValueError: ``gaussians`` is invalid (NaN, negative scale, ...).
    """
    if not isinstance(gaussians, Gaussians):
        raise TypeError(f"write_ply needs a prosplat.Gaussians, got {type(gaussians).__name__}")
    gaussians.validate()  # fields may have been edited in place since construction
    path = Path(path)
    folder = path.parent
    if not folder.is_dir():
        raise FileNotFoundError(
            f"Cannot write {path}: the folder {folder} does not exist; create it first"
        )
    if path.is_dir():
        raise IsADirectoryError(f"Cannot write {path}: it is a folder; give a file name")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} already exists; pass overwrite=True to replace it")

    element = PlyElement.describe(_vertex_array(gaussians), "vertex")
    ply = PlyData([element], text=not binary, byte_order="<" if binary else "=")
    _write_atomically(ply, path, overwrite)


def _write_atomically(ply: PlyData, path: Path, overwrite: bool) -> None:
    """Write to a temporary sibling, fsync, then move it into place (see :func:`write_ply`)."""
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    # os.open with mode 0o666 honours the umask, so the final file gets the usual permissions
    # (tempfile would create it 0o600).
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    try:
        with os.fdopen(fd, "wb") as stream:
            ply.write(stream)
            stream.flush()
            os.fsync(stream.fileno())
        if overwrite:
            os.replace(tmp, path)
        else:
            _move_no_clobber(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _move_no_clobber(tmp: Path, path: Path) -> None:
    """Move ``tmp`` to ``path`` unless ``path`` exists, without a check-then-act race.

    A hard link fails atomically if the target exists; on filesystems without hard links
    fall back to check-then-rename.
    """
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise FileExistsError(f"{path} already exists; pass overwrite=True to replace it") from None
    except OSError:  # no hard links here (some network / FAT filesystems)
        if path.exists():
            raise FileExistsError(
                f"{path} already exists; pass overwrite=True to replace it"
            ) from None
        os.replace(tmp, path)
    else:
        os.unlink(tmp)


# ---- read ---------------------------------------------------------------------------------
def _table(data: np.ndarray) -> np.ndarray | None:
    """[N] structured array -> [N, P] plain view if all P fields share one type, else None.

    A 3DGS file is usually all one type (float32); then its records are rows of a 2D array,
    and ``np.take`` gathers the wanted columns of the (memory-mapped) file in one pass per
    group, instead of one strided pass per property (which made a 1M-Gaussian degree-3 file
    take several seconds).
    """
    fields = data.dtype.fields or {}
    types = {spec[0] for spec in fields.values()}
    if len(types) != 1 or data.dtype.itemsize != len(fields) * next(iter(types)).itemsize:
        return None
    try:
        return np.asarray(data).view(next(iter(types))).reshape(len(data), len(fields))
    except (ValueError, TypeError):  # not contiguous, or object (list) fields
        return None


def read_ply(
    path: str | os.PathLike[str],
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
    on_warning: Callable[[str], None] | None = None,
    allow_empty: bool = False,
) -> Gaussians:
    """Read a 3DGS PLY written by prosplat or another splat tool.

    Accepts SH degree 0-3 (from the number of ``f_rest_*`` properties: 0, 9, 24 or 45; none
    at all is degree 0), properties in any order, ASCII or binary little/big endian, and any
    numeric property type. Extra properties and elements (custom fields, SuperSplat's
    ``transform``, ...) are dropped with one warning naming them: ``on_warning(message)`` if
    given (the add-on's worker passes its report), else a :class:`PlyWarning`. INRIA's
    normals ``nx ny nz`` are dropped silently (they are always zero). Opacity is
    passed through a sigmoid and scales through exp, both in float64 before the cast to
    ``dtype``, so a file from :func:`write_ply` decodes to the values that were written.

    Quaternions are returned as stored (not normalised, as the rasterizer normalises), except
    that all-zero rows become (1, 0, 0, 0): some tools write zeros for "no rotation", and a
    zero quaternion has no rotation to keep, while :class:`Gaussians` rejects it.

    A file with no Gaussians is refused unless ``allow_empty``: an importer that made an
    empty object would hide the real problem (a failed export upstream).

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: not a PLY, no ``vertex`` element, no vertices (unless ``allow_empty``), a
            required property missing, an unsupported number of ``f_rest_*``, or a NaN/Inf
            value (the message names the property and the file).
    """
    if not dtype.is_floating_point:
        raise ValueError(f"read_ply needs a floating-point dtype, got {dtype}")
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"PLY file not found: {path}")
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a folder, not a PLY file")
    try:
        ply = PlyData.read(str(path))  # binary data is memory-mapped, not parsed per vertex
    except (PlyParseError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path} is not a readable PLY file: {exc}") from exc

    elements = [e.name for e in ply.elements]
    if "vertex" not in elements:
        raise ValueError(
            f"{path} has no 'vertex' element (it has {elements}); a 3DGS PLY stores one "
            "Gaussian per vertex"
        )
    vertex = ply["vertex"]
    data = vertex.data  # [N] structured
    scalar = {p.name for p in vertex.properties if not isinstance(p, PlyListProperty)}
    listed = {p.name for p in vertex.properties} - scalar

    rest_indices = sorted(int(m.group(1)) for name in scalar if (m := _F_REST.fullmatch(name)))
    rest_count = len(rest_indices)
    if rest_count not in _DEGREE_BY_REST_COUNT:
        raise ValueError(
            f"{path} has {rest_count} f_rest_* properties; expected 0, 9, 24 or 45 "
            "(SH degree 0, 1, 2 or 3)"
        )
    rest_names = [f"f_rest_{i}" for i in range(rest_count)]
    for name in (*_REQUIRED, *rest_names):
        if name in listed:
            raise ValueError(f"{path}: property '{name}' is a list; a 3DGS PLY stores scalars")
        if name not in scalar:
            hint = (
                " (this looks like a compressed PLY, e.g. SuperSplat's; decompress it first)"
                if "packed_position" in scalar or "chunk" in elements
                else ""
            )
            raise ValueError(
                f"{path} has no vertex property '{name}'{hint}; a 3DGS PLY needs x y z, "
                "f_dc_0-2, opacity, scale_0-2, rot_0-3 and f_rest_0.. for SH degree > 0"
            )

    n = len(data)
    if n == 0 and not allow_empty:
        raise ValueError(
            f"{path} holds 0 Gaussians (element vertex 0); nothing to import - re-export it "
            "from the tool that made it"
        )
    known = {*_REQUIRED, *rest_names, *_IGNORED, VIEW_PROPERTY}
    dropped = _dropped_message(
        path,
        [p.name for p in vertex.properties if p.name not in known],
        [name for name in elements if name != "vertex"],
    )
    if dropped is not None:
        if on_warning is not None:
            on_warning(dropped)
        else:
            warnings.warn(dropped, PlyWarning, stacklevel=2)

    # float32 targets are filled directly (one rounding); others go through float64 first.
    fill = np.float32 if dtype == torch.float32 else np.float64
    k = (_DEGREE_BY_REST_COUNT[rest_count] + 1) ** 2
    # SH coefficients in [K, 3] order; f_rest is channel-major: f_rest_{c(K-1) + j-1} = sh[j, c].
    sh_names = [*_F_DC, *np.array(rest_names, dtype=object).reshape(3, k - 1).T.ravel()]
    table = _table(data)  # [N, P] or None

    def columns(names: list[str]) -> np.ndarray:
        """[N, len(names)] contiguous array of those properties, refusing NaN/Inf in the file.

        In the file's type (numpy's promotion if the properties have different types, so
        float32 values stay exact next to float64 ones).
        """
        if table is not None:
            block = np.take(table, [data.dtype.fields[m][1] // table.itemsize for m in names], 1)
        else:
            block = np.stack([np.asarray(data[m]) for m in names], axis=1)
        if block.dtype.kind == "f":
            finite = np.isfinite(block)
            if not finite.all():
                i = int(np.argmin(finite.all(axis=0)))
                raise ValueError(
                    f"{path}: property '{names[i]}' has {int((~finite[:, i]).sum())} NaN or "
                    f"Inf values of {n}"
                )
        return block

    def to_torch(a: np.ndarray, names: list[str], may_overflow: bool = False) -> torch.Tensor:
        """``a`` [N, len(names)] as a ``dtype`` tensor; refuses values the file holds but
        ``dtype`` cannot (1e300 in float32, or a scale whose exp overflows)."""
        with np.errstate(over="ignore"):
            a = a.astype(fill, copy=False)
        t = torch.from_numpy(a).to(device=device, dtype=dtype)
        if may_overflow or dtype not in (torch.float32, torch.float64):
            bad = ~torch.isfinite(t.reshape(n, len(names))).all(dim=0)  # [len(names)]
            if bad.any():
                name = names[int(bad.nonzero()[0, 0])]
                raise ValueError(f"{path}: property '{name}' gives values too large for {dtype}")
        return t

    narrowing = fill is np.float32  # a float64 file can hold values float32 cannot
    means = columns(list(_MEANS))
    means = to_torch(means, list(_MEANS), narrowing and means.itemsize > 4)  # [N, 3]
    sh = columns(sh_names)
    sh = to_torch(sh, sh_names, narrowing and sh.itemsize > 4).reshape(n, k, 3)  # [N, K, 3]
    logits = columns(["opacity"])[:, 0].astype(np.float64)  # [N]
    opacities = to_torch(_sigmoid64(logits), ["opacity"])  # [N]
    with np.errstate(over="ignore"):  # overflow becomes inf, reported by to_torch
        scales = np.exp(columns(list(_SCALES)).astype(np.float64))  # [N, 3]
    scales = to_torch(scales, list(_SCALES), may_overflow=True)
    quats = columns(list(_QUATS))
    quats = to_torch(quats, list(_QUATS), narrowing and quats.itemsize > 4)  # [N, 4] wxyz

    zero = (quats == 0).all(dim=1)  # after the cast: also catches rows that underflowed
    if zero.any():
        quats[zero] = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=dtype, device=quats.device)
    views = None
    if VIEW_PROPERTY in scalar:
        views = view_indices(np.asarray(data[VIEW_PROPERTY]), n)
        if views is None:
            message = (
                f"{path}: property '{VIEW_PROPERTY}' is not a view index per Gaussian "
                "(integers >= 0); read without it"
            )
            if on_warning is not None:
                on_warning(message)
            else:
                warnings.warn(message, PlyWarning, stacklevel=2)
        else:
            views = views.to(device)
    return Gaussians(means, quats, scales, opacities, sh, views)


def view_indices(values: np.ndarray, n: int) -> torch.Tensor | None:
    """``values`` [n] (any numeric type) as int64 view indices, or None unless every one is a
    finite integer >= 0 (a file's or a point cloud's :data:`VIEW_PROPERTY`)."""
    a = np.asarray(values, dtype=np.float64).reshape(-1)
    if a.shape[0] != n or not np.isfinite(a).all() or (a < 0).any() or (a != np.round(a)).any():
        return None
    return torch.from_numpy(a.astype(np.int64))
