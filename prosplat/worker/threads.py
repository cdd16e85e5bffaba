"""How many CPU threads torch uses in the worker, and why not torch's default.

torch starts one OpenMP thread per core it sees. Inside Blender that core count is shared
with Blender itself, a Cycles render, a browser: an oversubscribed OpenMP team whose threads
spin-wait for each other is many times slower than one thread (measured on a busy 2-core box:
a warm 128-px Render View took 12.5 s with torch's 2 threads against 0.95 s with 1; see
BENCHMARKS.md, "Add-on worker"). Two things fix it, both applied to every worker job:

- ``OMP_WAIT_POLICY=PASSIVE`` (set before torch loads, so only where torch is not imported
  yet: always in the external worker, and in Blender before the first in-process job): an
  idle OpenMP thread sleeps instead of spinning, so a busy CPU costs time, not a collapse.
- a thread count of :func:`auto_threads`, or the add-on's *CPU Threads* preference when it
  is not 0: with sleeping threads, all physical cores up to 4 (busy 2-core box: 2 threads
  0.22 s, 1 thread 0.63 s); where torch was loaded before we could ask for that (another
  add-on imported it first), half of them, since spinning threads collapse on a busy CPU.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

MAX_AUTO_THREADS = 4


def physical_cores() -> int:
    """Physical cores this process may use (hyper-threads counted once where Linux says)."""
    try:
        usable = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        usable = os.cpu_count() or 1
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return max(1, usable)
    cores: set[tuple[str, str]] = set()
    phys = core = None
    for line in text.splitlines():
        key, _, value = line.partition(":")
        key, value = key.strip(), value.strip()
        if key == "physical id":
            phys = value
        elif key == "core id":
            core = value
        elif not key and phys is not None and core is not None:
            cores.add((phys, core))
            phys = core = None
    if phys is not None and core is not None:
        cores.add((phys, core))
    return max(1, min(usable, len(cores) or usable))


def passive_wait() -> bool:
    """Whether this process's OpenMP threads sleep when idle (see the module docstring)."""
    return os.environ.get("OMP_WAIT_POLICY", "").upper() == "PASSIVE"


def auto_threads(cores: int | None = None, passive: bool | None = None) -> int:
    """The physical cores (``passive``) or half of them (spinning OpenMP threads), at least 1
    and at most :data:`MAX_AUTO_THREADS`, where the gain flattens at the sizes an artist
    previews; BENCHMARKS.md, "Add-on worker", has the measurement."""
    cores = physical_cores() if cores is None else cores
    passive = passive_wait() if passive is None else passive
    return max(1, min(MAX_AUTO_THREADS, cores if passive else cores // 2))


def prefer_passive_wait() -> None:
    """Ask OpenMP to sleep rather than spin when idle, if torch has not started it yet (a
    user's own ``OMP_WAIT_POLICY`` wins). Set too late it would only make
    :func:`passive_wait` lie, so it is not set then."""
    if "torch" not in sys.modules:
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def apply_threads(threads: int | None) -> int:
    """Set torch's intra-op thread count (None/0: :func:`auto_threads`); returns it.

    Called at the start of every job, in the thread that runs it (OpenMP keeps the count
    per calling thread), so a changed preference applies to the next job without a restart.
    """
    import torch

    n = int(threads) if threads else auto_threads()
    if n < 1:
        raise ValueError(f"threads must be 0 (automatic) or a positive count, got {threads}")
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return torch.get_num_threads()
