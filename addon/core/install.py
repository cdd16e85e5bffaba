"""Install ``prosplat``'s requirements into a folder of the add-on with Blender's own pip:
exactly the set the tests ran with, never a second numpy.

What is installed is :mod:`.pins` (generated from the tested environment by
``scripts/pin_requirements.py``; a test fails when it drifts): torch at the tested version,
the CPU build from the PyTorch CPU index unless the artist picks CUDA, and every other
package at its tested version with ``--no-deps``, so pip resolves nothing on its own and in
particular never fetches numpy (Blender's numpy is checked against :data:`.pins.NUMPY_RANGE`
instead; the requirements folder comes after Blender's own modules on ``sys.path``).

Two pip runs, one after the other: torch from its index, then the rest from the user's usual
index (PyPI unless pip is configured otherwise). pip runs as a subprocess whose output a
thread reads line by line, so the preferences can show progress while Blender stays
responsive, and the result is one clear line: what was installed, or the error pip gave.
The download size is shown before anything starts; it is an estimate from a shipped table
(:data:`.pins.WHEEL_MB`), as Blender may be offline until the artist agrees.
"""

from __future__ import annotations

import re
import subprocess
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

from . import pins

TORCH_INDEX = {
    "CPU": "https://download.pytorch.org/whl/cpu",
    "CUDA": "https://download.pytorch.org/whl/cu128",
}
PYPI = "https://pypi.org/simple"
#: Rough extra download of a CUDA build over the CPU one on Linux/Windows: torch's CUDA wheel
#: plus the NVIDIA libraries it pulls (cuDNN, cuBLAS, NCCL, ...); public wheel listings.
CUDA_EXTRA_MB = 3000.0
_BASE = ("-m", "pip", "install", "--upgrade", "--disable-pip-version-check")


def torch_requirement(build: str = "CPU", platform: str = sys.platform) -> str:
    """``torch==V+cpu`` for the CPU build where the CPU index labels it (Linux, Windows), so
    pip cannot quietly take PyPI's CUDA wheel instead; plain ``torch==V`` otherwise."""
    v = pins.TORCH_VERSION
    cpu_label = build == "CPU" and not platform.startswith("darwin")
    return f"torch=={v}+cpu" if cpu_label else f"torch=={v}"


def pinned_requirements() -> list[str]:
    """Every pinned requirement but torch, as pip arguments (platform-only ones with their
    marker, which pip evaluates)."""
    reqs = [f"{name}=={version}" for name, version in pins.PINS if name != "torch"]
    reqs += [f"{name}{spec}; {marker}" for name, spec, marker in pins.ELSEWHERE]
    return reqs


def constraints_text() -> str:
    """The tested versions as a pip constraints file (the CUDA step lets torch pull its
    NVIDIA libraries, and this keeps torch's other dependencies at the tested versions)."""
    return "".join(f"{n}=={v}\n" for n, v in pins.PINS if n != "torch")


def pip_commands(
    target: str,
    build: str = "CPU",
    extra_args: str = "",
    python: str = sys.executable,
    platform: str = sys.platform,
    constraints: str | None = None,
) -> list[list[str]]:
    """The pip runs that install the pinned set into ``target``: [torch, everything else].

    CPU: torch alone from the PyTorch CPU index with ``--no-deps``. CUDA: torch from the
    CUDA index with its dependencies (the NVIDIA libraries), held to the tested versions by
    ``constraints`` (a file of :func:`constraints_text`). Then the rest, ``--no-deps``.
    """
    if build not in TORCH_INDEX:
        raise ValueError(f"unknown torch build {build!r}; use one of {sorted(TORCH_INDEX)}")
    base = [python, *_BASE, "--target", target]
    extra = extra_args.split()
    torch_cmd = [*base, "--index-url", TORCH_INDEX[build]]
    if build == "CPU":
        torch_cmd.append("--no-deps")
    else:
        torch_cmd += ["--extra-index-url", PYPI]
        if constraints:
            torch_cmd += ["--constraint", constraints]
    torch_cmd += [*extra, torch_requirement(build, platform)]
    rest = [*base, "--no-deps", *extra, *pinned_requirements()]
    return [torch_cmd, rest]


def download_estimate_mb(build: str = "CPU") -> float:
    """Estimated download in MB: the shipped wheel-size table (+ CUDA's libraries)."""
    return sum(pins.WHEEL_MB.values()) + (CUDA_EXTRA_MB if build == "CUDA" else 0.0)


def describe_download(build: str = "CPU") -> str:
    mb = download_estimate_mb(build)
    size = f"{mb / 1000:.1f} GB" if mb >= 1000 else f"{mb:.0f} MB"
    what = "CUDA" if build == "CUDA" else "CPU"
    return (f"about {size} to download (an estimate: {len(pins.PINS)} packages, torch "
            f"{pins.TORCH_VERSION} {what} build)")  # fmt: skip


def _version_tuple(version: str) -> tuple[int, ...]:
    parts = re.match(r"\d+(\.\d+)*", version)
    return tuple(int(x) for x in parts.group(0).split(".")) if parts else (0,)


def version_in_range(version: str, spec: str) -> bool:
    """``version`` against a range like ``<2.0,>=1.24`` (the operators pins use), without
    ``packaging``, which Blender's Python may lack."""
    ops = {
        ">=": lambda a, b: a >= b, "<=": lambda a, b: a <= b, ">": lambda a, b: a > b,
        "<": lambda a, b: a < b, "==": lambda a, b: a == b, "!=": lambda a, b: a != b,
    }  # fmt: skip
    v = _version_tuple(version)
    for clause in filter(None, (c.strip() for c in spec.split(","))):
        op = next(o for o in (">=", "<=", "==", "!=", ">", "<") if clause.startswith(o))
        bound = _version_tuple(clause[len(op) :])
        n = max(len(v), len(bound))
        if not ops[op](v + (0,) * (n - len(v)), bound + (0,) * (n - len(bound))):
            return False
    return True


def numpy_problem() -> str | None:
    """None if Blender's numpy is in the tested range, else what is wrong (pip is never
    asked to replace it: that would break Blender)."""
    try:
        import numpy
    except ImportError:
        return f"Blender's Python has no numpy; prosplat needs numpy{pins.NUMPY_RANGE}"
    if not version_in_range(numpy.__version__, pins.NUMPY_RANGE):
        return (f"Blender's numpy {numpy.__version__} is outside the tested range "
                f"{pins.NUMPY_RANGE}; prosplat may not work in this Blender")  # fmt: skip
    return None


class PipInstall:
    """The pip runs of one install, in order; :meth:`poll` says whether all finished.

    ``fraction`` grows with each step's "Collecting"/"Installing"/"Successfully" lines, the
    torch step weighted by its share of the download.
    """

    def __init__(self, commands: Sequence[list[str]], weights: Sequence[float] | None = None):
        self.commands = [list(c) for c in commands]
        w = list(weights) if weights else [1.0] * len(self.commands)
        total = sum(w) or 1.0
        self._spans = []
        lo = 0.0
        for x in w:
            self._spans.append((lo, lo + x / total))
            lo += x / total
        self.lines: list[str] = []
        self.fraction, self.returncode = 0.0, None
        self._cancelled = False
        self.proc: subprocess.Popen | None = None

    @property
    def command(self) -> list[str]:  # the last (main) run, for messages and old callers
        return self.commands[-1]

    def start(self) -> PipInstall:
        self._thread = threading.Thread(target=self._run_all, daemon=True)
        self._thread.start()
        return self

    def _run_all(self) -> None:
        code = 0
        for i, cmd in enumerate(self.commands):
            if self._cancelled:
                code = -2
                break
            code = self._run_one(cmd, *self._spans[i])
            if code != 0:
                break
        self.returncode = code

    def _run_one(self, cmd: list[str], lo: float, hi: float) -> int:
        try:
            self.proc = subprocess.Popen(
                cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1
            )
        except OSError as e:
            self.lines.append(f"could not start pip: {e}")
            return -1
        expected = max(1, sum(1 for a in cmd if "==" in a))
        collected = 0
        for line in self.proc.stdout:
            line = line.rstrip()
            if not line:
                continue
            self.lines.append(line)
            step = None
            if line.startswith("Collecting "):
                collected += 1
                step = 0.7 * min(1.0, collected / expected)
            elif line.startswith("Installing collected packages"):
                step = 0.85
            elif line.startswith("Successfully installed"):
                step = 1.0
            if step is not None:
                self.fraction = max(self.fraction, lo + (hi - lo) * step)
        return self.proc.wait()

    def poll(self) -> bool:
        return self.returncode is not None

    def wait(self) -> None:
        if hasattr(self, "_thread"):
            self._thread.join()

    @property
    def last_line(self) -> str:
        return self.lines[-1] if self.lines else "starting pip"

    def cancel(self) -> None:
        self._cancelled = True
        if self.returncode is None and self.proc is not None:
            self.proc.terminate()

    def summary(self) -> tuple[bool, str]:
        """(ok, one line for the user)."""
        if self.returncode == 0:
            done = [ln for ln in self.lines if ln.startswith("Successfully")]
            n = sum(len(ln.split()) - 2 for ln in done)
            return True, (f"installed {n} packages (the tested set, torch {pins.TORCH_VERSION})"
                          if n else "requirements are already installed")  # fmt: skip
        if self.returncode == -2:
            return False, "install cancelled"
        errors = [ln for ln in self.lines if re.match(r"(ERROR|error)\b", ln)]
        tail = errors[-1] if errors else (self.lines[-1] if self.lines else "no output")
        if "No module named pip" in "\n".join(self.lines):
            tail += " (this Python has no pip; run `python -m ensurepip` with Blender's Python)"
        return False, f"pip failed (exit code {self.returncode}): {tail}"


#: The install running now (one at a time), for the preferences to draw.
CURRENT: dict[str, PipInstall] = {}


def start_install(
    target: str | Path,
    extra_args: str = "",
    build: str = "CPU",
    commands: Sequence[list[str]] | None = None,
) -> PipInstall:
    """Start the pinned install into ``target`` (the add-on's requirements folder, which
    the Blender layer knows: :func:`..blender.runtime.deps_dir`) in the background; or
    ``commands`` instead, for tests."""
    if commands is None:
        constraints = None
        if build == "CUDA":
            constraints = Path(target).parent / "prosplat-constraints.txt"
            constraints.write_text(constraints_text())
        commands = pip_commands(str(target), build, extra_args,
                                constraints=str(constraints) if constraints else None)  # fmt: skip
    torch_share = pins.WHEEL_MB.get("torch", 1.0) / max(download_estimate_mb("CPU"), 1.0)
    weights = [torch_share, 1.0 - torch_share] if len(commands) == 2 else None
    run = PipInstall(commands, weights).start()
    CURRENT["run"] = run
    return run
