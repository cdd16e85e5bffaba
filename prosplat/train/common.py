"""Training utilities shared by the training scripts (generator now, improvement model next).

Four pieces, each usable on its own:

Checkpoints that survive a crash at any point of a save
    :func:`save_checkpoint` writes the weights (safetensors, the step in its metadata) and the
    resumable state (``state.pt``: optimiser, step, anything else) each atomically, keeping
    the previous weights as ``<name>.prev.safetensors``. :func:`load_checkpoint` returns the
    newest pair whose steps agree, so a kill between the two writes resumes from the last
    consistent step instead of pairing new weights with an old optimiser; files that hold no
    consistent pair raise :class:`CheckpointError` naming them.

torch.distributed setup
    :func:`setup_distributed` reads torchrun's environment (``WORLD_SIZE``, ``RANK``,
    ``LOCAL_RANK``), picks the device and the backend that goes with it (NCCL for CUDA, gloo
    for the CPU) and returns a :class:`Dist` with ``rank``, ``is_main``, ``wrap`` (DDP),
    ``barrier``, ``mean`` / ``mean_all`` (floats averaged over ranks) and ``close``. Without
    torchrun it is a no-op single process, so one script serves the CPU, one GPU and several.

Logs
    :func:`truncate_log` drops ``log.jsonl`` records past the step a run resumes from, so a
    resumed log lists every step once.

Step-indexed sampling
    :func:`step_indices` gives the scenes of global step ``s`` for rank ``r`` as a pure
    function of (seed, step, batch, world size): a seeded permutation per epoch, cut into
    global batches of ``batch * world_size`` items, rank ``r`` taking its slice. Resuming at
    any step continues the exact sequence, and K processes with ``--batch B`` see the same
    scenes per step as one process with ``--batch K*B``. :func:`draw_count` draws a per-step
    value (e.g. the number of input views) the same way.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import random
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from prosplat.core.paths import write_text_atomic

WEIGHTS_NAME = "checkpoint.safetensors"
STATE_NAME = "state.pt"


# ---- run settings ----------------------------------------------------------------------------
def check_intervals(cfg, *names: str) -> None:
    """Refuse step intervals below 1 (``--save-every 0`` would divide by zero mid-run): a
    training config's ``__post_init__`` calls it so the run fails before its first step."""
    for name in names:
        value = getattr(cfg, name)
        if int(value) != value or value < 1:
            raise ValueError(
                f"--{name.replace('_', '-')} must be a whole number of steps >= 1, got {value}"
            )


def lr_at(step: int, cfg) -> float:
    """Linear warm-up, then cosine decay to 10 % of the peak; ``cfg`` is any training config
    with ``lr``, ``warmup`` and ``steps`` (the generator's and the stage-2 ones)."""
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    t = (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup)
    return cfg.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(1.0, t))))


# ---- devices and torch.distributed ----------------------------------------------------------
def pick_device(name: str = "auto", local_rank: int | None = None) -> torch.device:
    """``auto`` → this process's GPU (``LOCAL_RANK`` under torchrun) if CUDA works, else CPU.

    A bare ``cuda`` also resolves to the local rank's GPU, so ``--device cuda`` under torchrun
    does not put every process on GPU 0.
    """
    if local_rank is None:
        local_rank = int(os.environ.get("LOCAL_RANK", 0))
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda":
        return torch.device("cuda", local_rank)
    return torch.device(name)


@dataclass
class Dist:
    """Where this process stands in a (possibly one-process) run."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    device: torch.device = torch.device("cpu")

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        """Only the main process writes checkpoints, logs and progress bars."""
        return self.rank == 0

    def wrap(self, model: torch.nn.Module) -> torch.nn.Module:
        """DDP around ``model`` when distributed (gradients averaged over ranks), else itself."""
        if not self.distributed:
            return model
        ids = [self.device.index] if self.device.type == "cuda" else None
        return torch.nn.parallel.DistributedDataParallel(model, device_ids=ids)

    def barrier(self) -> None:
        if self.distributed:
            torch.distributed.barrier()

    def mean(self, value: float) -> float:
        """``value`` averaged over all ranks (every rank must call it at the same point)."""
        if not self.distributed:
            return value
        t = torch.tensor([value], dtype=torch.float64, device=self.device)
        torch.distributed.all_reduce(t)
        return float(t) / self.world_size

    def mean_all(self, values: Mapping[str, float]) -> dict[str, float]:
        """Each value averaged over all ranks, in one all-reduce."""
        if not self.distributed:
            return dict(values)
        t = torch.tensor(list(values.values()), dtype=torch.float64, device=self.device)
        torch.distributed.all_reduce(t)
        return {k: float(v) / self.world_size for k, v in zip(values, t.tolist())}

    def close(self) -> None:
        if self.distributed and torch.distributed.is_initialized():
            torch.distributed.destroy_process_group()


def setup_distributed(device: str = "auto") -> Dist:
    """Join the torchrun process group if there is one; the backend follows the device.

    Returns a single-process :class:`Dist` when ``WORLD_SIZE`` is unset or 1.
    """
    world = int(os.environ.get("WORLD_SIZE", "1"))
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    dev = pick_device(device, local_rank)
    if world <= 1:
        return Dist(device=dev)
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    backend = "nccl" if dev.type == "cuda" else "gloo"
    if not torch.distributed.is_initialized():
        torch.distributed.init_process_group(backend)
    return Dist(torch.distributed.get_rank(), world, local_rank, dev)


# ---- step-indexed sampling -------------------------------------------------------------------
def steps_per_epoch(n_items: int, batch: int, world_size: int = 1) -> int:
    """Whole global batches per pass over the data (a ragged last batch is dropped)."""
    if batch < 1 or world_size < 1:
        raise ValueError(f"batch and world size must be >= 1, got {batch} and {world_size}")
    per = n_items // (batch * world_size)
    if per == 0:
        raise ValueError(
            f"{n_items} scenes cannot fill one step of {batch} per process x {world_size} "
            "processes; lower --batch, use fewer processes or render more scenes"
        )
    return per


def step_indices(
    n_items: int, batch: int, seed: int, step: int, rank: int = 0, world_size: int = 1
) -> tuple[int, list[int]]:
    """(epoch, item indices) that ``rank`` trains on at global ``step``.

    Pure in its arguments, so a resumed run continues the same sequence, and the union over
    ranks equals the single-process batch of ``batch * world_size`` items.
    """
    per = steps_per_epoch(n_items, batch, world_size)
    epoch, pos = divmod(step, per)
    order = list(range(n_items))
    random.Random(f"prosplat-order/{seed}/{epoch}").shuffle(order)
    start = pos * batch * world_size + rank * batch
    return epoch, order[start : start + batch]


def draw_count(counts: Sequence[int], seed: int, step: int) -> int:
    """One of ``counts`` for ``step``, drawn with a RNG seeded by (seed, step).

    Every rank draws the same value, and a resumed run draws what an uninterrupted one would.
    """
    if not counts:
        raise ValueError("draw_count needs at least one value to draw from")
    if len(counts) == 1:
        return int(counts[0])
    return int(random.Random(f"prosplat-count/{seed}/{step}").choice(list(counts)))


# ---- checkpoints -----------------------------------------------------------------------------
class CheckpointError(RuntimeError):
    """The run folder holds checkpoint files but no weights/state pair with the same step."""


@dataclass
class Checkpoint:
    """A consistent resume point: weights and state written at the same step."""

    step: int
    weights: dict[str, Tensor]
    state: dict[str, Any]
    weights_path: Path


def seeded_generator(key: str) -> torch.Generator:
    """A CPU ``torch.Generator`` seeded from the text ``key`` (its sha256), e.g.
    ``"prosplat-camera/{seed}/{step}"``: each random draw of a training step gets a stream of
    its own, the same on every platform and Python build (no ``hash()``), so switching one
    augmentation on changes no other draw."""
    digest = hashlib.sha256(key.encode()).digest()
    return torch.Generator().manual_seed(int.from_bytes(digest[:8], "little") >> 1)


def _prev_name(weights_name: str) -> str:
    stem = weights_name.removesuffix(".safetensors")
    return f"{stem}.prev.safetensors"


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(folder: Path) -> None:
    try:
        _fsync(folder)
    except OSError:  # not every filesystem lets a directory be opened/fsynced
        pass


def save_checkpoint(
    out: str | Path,
    step: int,
    weights: Mapping[str, Tensor],
    state: Mapping[str, Any],
    metadata: Mapping[str, str] | None = None,
    weights_name: str = WEIGHTS_NAME,
    state_name: str = STATE_NAME,
) -> Path:
    """Write ``weights`` and ``state`` for ``step`` into ``out`` so any crash leaves a pair.

    Order: new weights to a temp file → current weights become ``*.prev.safetensors`` → temp
    renamed into place → state to a temp file → renamed into place. Each rename is atomic, and
    at every point between them either (weights, state) or (prev, state) carry the same step.
    ``metadata`` (strings) goes into the safetensors header beside ``step``; ``state`` must be
    loadable with ``torch.load(weights_only=True)``. Returns the weights path.
    """
    from safetensors.torch import save_file

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ckpt, prev, state_path = out / weights_name, out / _prev_name(weights_name), out / state_name
    tmp_w, tmp_s = out / f".{weights_name}.tmp", out / f".{state_name}.tmp"
    meta = {**(metadata or {}), "step": str(int(step))}
    tensors = {k: v.detach().cpu().contiguous() for k, v in weights.items()}
    save_file(tensors, str(tmp_w), metadata=meta)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_w, 0o666 & ~umask)  # safetensors creates 0600; give the usual mode
    _fsync(tmp_w)
    if ckpt.exists():
        os.replace(ckpt, prev)
    os.replace(tmp_w, ckpt)
    _fsync_dir(out)
    torch.save({**state, "step": int(step)}, tmp_s)
    _fsync(tmp_s)
    os.replace(tmp_s, state_path)
    _fsync_dir(out)
    return ckpt


def weights_step(path: str | Path, key: str = "step") -> int | None:
    """The step stored in a checkpoint's safetensors metadata under ``key`` (None for files
    without one; stage-2 weights store it as ``steps``)."""
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as f:
        meta = f.metadata() or {}
    return int(meta[key]) if key in meta else None


def load_checkpoint(
    out: str | Path,
    map_location: str | torch.device = "cpu",
    weights_name: str = WEIGHTS_NAME,
    state_name: str = STATE_NAME,
) -> Checkpoint | None:
    """The newest consistent (weights, state) pair in ``out``; None if there is no checkpoint.

    Raises :class:`CheckpointError` when checkpoint files exist but no pair agrees on the step
    (e.g. a crash during the very first save), naming the files so the user can decide.
    """
    from safetensors.torch import load_file

    out = Path(out)
    ckpt, prev, state_path = out / weights_name, out / _prev_name(weights_name), out / state_name
    candidates = [p for p in (ckpt, prev) if p.is_file()]
    if not state_path.is_file():
        if not candidates:
            return None
        raise CheckpointError(
            f"{out} has {', '.join(p.name for p in candidates)} but no {state_name} (a crash "
            "during the first save?): nothing consistent to resume; delete the run folder's "
            "checkpoint files to start over, or use another --out"
        )
    state = torch.load(state_path, map_location=map_location, weights_only=True)
    step = int(state["step"])
    seen = []
    for path in candidates:
        w_step = weights_step(path)
        seen.append(f"{path.name}: step {w_step}")
        if w_step is None and path == ckpt:
            warnings.warn(
                f"{path} has no step in its metadata (written before checkpoints carried one); "
                f"resuming it with {state_name} at step {step} unchecked",
                stacklevel=2,
            )
            w_step = step
        if w_step == step:
            weights = load_file(str(path), device=str(map_location))
            return Checkpoint(step, weights, state, path)
    raise CheckpointError(
        f"{out}: {state_name} is at step {step} but no weights file matches "
        f"({'; '.join(seen) or 'none found'}); refusing to resume with mixed steps"
    )


def changed_settings(
    old: Mapping[str, Any], new: Mapping[str, Any], per_call: Sequence[str] = ()
) -> list[str]:
    """The settings a saved ``train_config.json`` (``old``, as loaded) holds at other values
    than ``new``, sorted; ``per_call`` keys (where this invocation stops) do not count, and a
    key ``old`` lacks (written before the setting existed) counts as today's value."""
    new = json.loads(json.dumps(dict(new)))  # tuples as lists, as the saved file has them
    return sorted(k for k in old if k not in per_call and (k not in new or old[k] != new[k]))


def claim_run_folder(
    out: str | Path, config: Mapping[str, Any], per_call: Sequence[str] = (), is_main: bool = True
) -> None:
    """Make sure a run with no checkpoint in ``out`` may start there from step 0.

    A folder whose ``train_config.json`` is this very run's (the same settings, apart from the
    ``per_call`` keys such as where this invocation stops) was stopped before its first save:
    it starts over, with a warning, and its old log records are dropped (on the main rank),
    instead of the user deleting the folder by hand. A folder holding another run's config
    raises :class:`FileExistsError` naming the settings that differ, so no run's record is
    overwritten. Call it on every rank, so that every rank raises.
    """
    out = Path(out)
    cfg_path = out / "train_config.json"
    if not cfg_path.exists():
        return
    differ = changed_settings(json.loads(cfg_path.read_text()), config, per_call)
    if differ:
        raise FileExistsError(
            f"{out} holds another run's config but no checkpoint (it differs in "
            f"{', '.join(differ)}); pick a new --out, or delete the folder to start it over"
        )
    if is_main:
        warnings.warn(
            f"{out}: this run stopped before its first checkpoint; starting it again from step 0",
            stacklevel=2,
        )
        truncate_log(out / "log.jsonl", 0)


def truncate_log(path: str | Path, step: int) -> None:
    """Drop the JSON-lines records of ``path`` whose ``step`` is past ``step`` (written after
    the checkpoint a resume starts from), so the log of a resumed run lists each step once.
    Rewritten atomically; a missing file is left missing."""
    path = Path(path)
    if not path.exists():
        return
    keep = [ln for ln in path.read_text().splitlines() if ln and json.loads(ln)["step"] <= step]
    write_text_atomic(path, "".join(ln + "\n" for ln in keep))
