"""Saving and loading improvement-model checkpoints (weights + config JSON in the metadata)."""

from __future__ import annotations

import json
from pathlib import Path

from prosplat.core.checkpoints import read_checkpoint, write_checkpoint
from prosplat.improve.config import ImproveConfig
from prosplat.improve.model import ImproveModel

CHECKPOINT_FORMAT = "prosplat-improve"
WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
DEFAULT_IMPROVE_WEIGHTS = WEIGHTS_DIR / "improve_tiny.safetensors"


def save_improver(
    model: ImproveModel, path: str | Path, overwrite: bool = False, **extra: str
) -> Path:
    """Write ``model``'s weights and config to ``path`` (atomic, no clobbering); ``extra``
    strings go into the metadata too (e.g. the training command)."""
    meta = {
        "format": CHECKPOINT_FORMAT,
        "config": model.config.to_json(),
        "parameters": json.dumps(model.num_parameters()),
        **extra,
    }
    return write_checkpoint(model.state_dict(), path, meta, overwrite)


def load_improver(
    path: str | Path,
    device=None,
    alpha_input: bool = False,
    warp_input: bool = False,
    drop_reference: bool = False,
    fill_input: bool = False,
) -> ImproveModel:
    """The :class:`ImproveModel` a checkpoint written by :func:`save_improver` describes.

    ``alpha_input=True`` / ``warp_input=True`` add the (zero-initialised) alpha / warped
    reference input to weights trained without it, to fine-tune them with it: the model then
    behaves exactly as before. ``drop_reference=True`` leaves DWEA out (its weights are not
    loaded), for the ablation rows without the reference that start from the same weights.
    ``fill_input=True`` switches on :attr:`ImproveConfig.fill_input` (no weights of its own),
    to fine-tune a model on filled renders."""
    path = Path(path)
    state, meta = read_checkpoint(path, "improvement-model")
    if meta.get("format") != CHECKPOINT_FORMAT or "config" not in meta:
        raise ValueError(
            f"{path} is not an improvement-model checkpoint (format {meta.get('format')!r}); "
            "generator checkpoints load with ProSplat.from_pretrained(path)"
        )
    config = ImproveConfig.from_json(meta["config"])
    if fill_input:
        config = config.with_(fill_input=True)
    added = {
        name: True
        for name, wanted in (("alpha_input", alpha_input), ("warp_input", warp_input))
        if wanted and not getattr(config, name)
    }
    dropped = ("dwea.", "injection.") if drop_reference and config.reference else ()
    if dropped:
        state = {k: v for k, v in state.items() if not k.startswith(dropped)}
        added["reference"] = False
    adding = bool(added)
    model = ImproveModel(config.with_(**added) if adding else config)
    new_prefixes = tuple(f"{name.split('_')[0]}_in." for name in added if name != "reference")
    try:
        missing, unexpected = model.load_state_dict(state, strict=not adding)
        if adding and (unexpected or any(not k.startswith(new_prefixes) for k in missing)):
            raise RuntimeError(f"missing {missing}, unexpected {unexpected}")
    except RuntimeError as e:
        raise ValueError(f"{path} does not match the improvement model it describes: {e}") from e
    model.eval()
    return model.to(device) if device is not None else model
