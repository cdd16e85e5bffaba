"""Build and load the C++ kernels (``_cpu_kernels.cpp``: compositing; ``_cpu_project.cpp``:
the fused projection and the depth order; both include ``_cpu_parallel.h``, their thread
helpers) as one library through ctypes.

The source has no torch headers, so it compiles in about a second with the system C++
compiler on first use and is cached per hash of both sources under ``$PROSPLAT_CACHE`` (default
``~/.cache/prosplat``). Nothing is built at install time, so ``pip install`` never needs a
compiler in an isolated build environment (which would pull a second torch).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import sysconfig
import tempfile
import threading
from pathlib import Path

from prosplat.core.paths import cache_dir

_SOURCES = [Path(__file__).with_name(n) for n in ("_cpu_kernels.cpp", "_cpu_project.cpp")]
#: what the sources include (the thread helpers): part of the cache hash, not compiled alone
_HEADERS = [Path(__file__).with_name("_cpu_parallel.h")]
_FLAGS = ["-O3", "-std=c++17", "-shared", "-fPIC", "-ffp-contract=off", "-pthread"]
_lock = threading.Lock()
_lib: ctypes.CDLL | None = None


def _compiler() -> str:
    for name in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if name and shutil.which(name):
            return name
    raise RuntimeError(
        "ProSplat's CPU rasterizer needs a C++17 compiler to build its kernels once "
        "(none of $CXX, c++, g++, clang++ was found). Install one (Debian/Ubuntu: "
        "`apt-get install g++`; macOS: `xcode-select --install`) or use the gsplat backend on CUDA."
    )


def _library_path() -> Path:
    text = b"".join(s.read_bytes() for s in _SOURCES + _HEADERS) + " ".join(_FLAGS).encode()
    digest = hashlib.sha256(text).hexdigest()[:16]
    tag = f"{platform.system()}-{platform.machine()}".lower()
    suffix = sysconfig.get_config_var("SHLIB_SUFFIX") or ".so"
    return cache_dir() / "kernels" / f"prosplat_cpu_{tag}_{digest}{suffix}"


def _build(target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        out = Path(tmp) / target.name
        cmd = [_compiler(), *_FLAGS, *map(str, _SOURCES), "-o", str(out)]
        result = subprocess.run(cmd, capture_output=True, text=True)
        if result.returncode != 0:
            raise RuntimeError(
                f"building the CPU rasterizer failed:\n{' '.join(cmd)}\n{result.stderr}"
            )
        os.replace(out, target)  # atomic: concurrent builders never see a half-written library


def load() -> ctypes.CDLL:
    """The compiled kernel library, building it on first use."""
    global _lib
    with _lock:
        if _lib is None:
            path = _library_path()
            if not path.exists():
                _build(path)
            lib = ctypes.CDLL(str(path))
            _declare(lib)
            _lib = lib
    return _lib


def _declare(lib: ctypes.CDLL) -> None:
    i64, i32, p = ctypes.c_int64, ctypes.c_int, ctypes.c_void_p
    for suffix in ("f32", "f64"):
        fwd = getattr(lib, f"prosplat_forward_{suffix}")
        fwd.argtypes = [i64, i32, i32, i32, p, p, p, p, p, p, p, p, p, i32]
        fwd.restype = None
        bwd = getattr(lib, f"prosplat_backward_{suffix}")
        bwd.argtypes = [i64, i32, i32, i32, p, p, p, p, p, p, p, p, p, p, p, i64, i32]
        bwd.restype = None
        proj = getattr(lib, f"prosplat_project_forward_{suffix}")
        proj.argtypes = [i64] + [p] * 12 + [i32]
        proj.restype = None
        order = getattr(lib, f"prosplat_depth_order_{suffix}")
        order.argtypes = [i64, p, p, p]
        order.restype = i64
        pair = getattr(lib, f"prosplat_forward_pair_{suffix}")
        pair.argtypes = [i64, i32, i32, i32] + [p] * 13 + [i32]
        pair.restype = None
        finish = getattr(lib, f"prosplat_finish_{suffix}")
        finish.argtypes = [i64] + [p] * 6 + [i32]
        finish.restype = None
    lib.prosplat_project_backward_f64.argtypes = [i64] + [p] * 10 + [i32]
    lib.prosplat_project_backward_f64.restype = None
    lib.prosplat_abi_version.restype = ctypes.c_int
    if lib.prosplat_abi_version() != 2:
        raise RuntimeError(
            "stale ProSplat kernel library; delete the cache folder " + str(cache_dir())
        )
