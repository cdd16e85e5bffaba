"""Loading DepthSplat checkpoints: file formats, variant detection, strict key checks, and the
deterministic random-weights recipe used by the parity tests."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import torch
from torch import Tensor

from prosplat.generator.depthsplat.config import (
    RELEASED,
    VIT_SPECS,
    DepthSplatConfig,
    released_entry,
)
from prosplat.generator.depthsplat.dpt import LEVEL_INPUTS, WIDTHS
from prosplat.generator.depthsplat.model import DepthSplatEncoder

PREFIX = "encoder."
#: Where a file written by prosplat (``save_released_format(..., config=True)``, e.g. the
#: output of ``prosplat train generator --init X.pth``) keeps its full DepthSplat settings:
#: ``gaussian_scale_max`` is not in the weights, and a fine-tuned file may be renamed.
CONFIG_KEY = "prosplat_depthsplat_config"
META_KEY = "prosplat_meta"
HINT = (
    "expected a DepthSplat checkpoint: a released depthsplat-*.pth (a Lightning checkpoint "
    "whose state_dict keys start with 'encoder.'), a depth checkpoint ({'model': ...}), or "
    "an encoder state dict (keys 'depth_predictor.*', 'gaussian_head.*', ...)"
)


def _one_line(text: str, limit: int = 300) -> str:
    """``text`` on one line, cut at ``limit`` characters: torch's unpickling errors run to
    several paragraphs, and the add-on shows an error in one status-bar line."""
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


STRIP_HINT = (
    "Checkpoints are read with torch.load(weights_only=True), which runs no code from the file; "
    "a full training checkpoint that holds Python objects can be cut to its weights (only if "
    "you trust it) with: python -c \"import torch; torch.save({'state_dict': torch.load('IN', "
    "weights_only=False)['state_dict']}, 'OUT.pth')\""
)


def _unpickling_reason(e: Exception) -> str:
    """The specific part of torch's weights-only error ("Unsupported operand 110", "Unsupported
    global: GLOBAL x.Y ..."), without its advice to load with weights_only=False."""
    text = " ".join(str(e).split())
    if "WeightsUnpickler error:" in text:
        text = text.split("WeightsUnpickler error:", 1)[1]
        for stop in (" Please use", " Check the documentation"):
            text = text.split(stop, 1)[0]
    return _one_line(text.strip() or type(e).__name__, 200)


def _read_object(source) -> tuple[Mapping, str]:
    """A path or a mapping -> (the file's top-level mapping, a name for messages)."""
    if not isinstance(source, (str, Path)):
        if not isinstance(source, Mapping):
            raise ValueError(f"<state dict>: not a mapping of tensors; {HINT}")
        return source, "<state dict>"
    path = Path(source).expanduser()
    if not path.is_file():
        raise FileNotFoundError(
            f"DepthSplat checkpoint {path} not found; download it (README, 'DepthSplat "
            "weights') and pass its path"
        )
    if path.suffix == ".safetensors":
        from safetensors.torch import load_file

        try:
            obj = load_file(str(path))
        except Exception as e:  # noqa: BLE001 - any unreadable file
            raise ValueError(f"{path} is not a readable safetensors file ({_one_line(e)})") from e
    else:
        try:
            obj = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as e:  # noqa: BLE001 - any unreadable file
            raise ValueError(
                f"{path} could not be read as a PyTorch checkpoint ({_unpickling_reason(e)}); "
                f"{HINT}. {STRIP_HINT}"
            ) from e
    if not isinstance(obj, Mapping):
        raise ValueError(f"{path.name}: not a mapping of tensors; {HINT}")
    return obj, path.name


def _encoder_state(obj: Mapping, name: str) -> tuple[dict[str, Tensor], bool]:
    """The encoder's state dict (keys without ``encoder.``) and whether it is depth only."""
    depth_only = False
    if "state_dict" in obj and isinstance(obj["state_dict"], Mapping):
        obj = obj["state_dict"]
    elif "model" in obj and isinstance(obj["model"], Mapping):
        obj = {"depth_predictor." + k: v for k, v in obj["model"].items()}
        depth_only = True
    keys = list(obj)
    if any(k.startswith(PREFIX) for k in keys):
        # a Lightning checkpoint of the whole model: keep the encoder, drop decoder/losses
        obj = {k[len(PREFIX) :]: v for k, v in obj.items() if k.startswith(PREFIX)}
    elif keys and all(
        k.startswith("pretrained.")
        or k.startswith("backbone.")
        or k.startswith("transformer.")
        or k.startswith("regressor")
        or k.startswith("depth_head.")
        or k.startswith("upsampler.")
        or k.startswith("mv_pyramid.")
        or k.startswith("mono_pyramid.")
        for k in keys
    ):
        obj = {"depth_predictor." + k: v for k, v in obj.items()}  # a bare depth_predictor
    obj = {k: v for k, v in obj.items() if isinstance(v, Tensor)}
    if not any(k.startswith("depth_predictor.") for k in obj):
        sample = ", ".join(sorted(str(k) for k in keys)[:5])
        raise ValueError(
            f"{name} is not a DepthSplat checkpoint (no 'depth_predictor.*' keys; "
            f"found {sample}...); {HINT}"
        )
    if "gaussian_head.0.weight" not in obj:
        depth_only = True
    return obj, depth_only


def read_state_dict(source) -> tuple[dict[str, Tensor], bool, str]:
    """A path or a mapping -> (encoder state dict without prefix, depth_only, description)."""
    obj, name = _read_object(source)
    sd, depth_only = _encoder_state(obj, name)
    return sd, depth_only, name


def stored_config(obj: Mapping, name: str = "") -> DepthSplatConfig | None:
    """The settings a file written by :func:`save_released_format` with ``config=True``
    carries under :data:`CONFIG_KEY` (prosplat's fine-tuned files), else None. Released files
    have none: their variant is read from the shapes and their name."""
    stored = obj.get(CONFIG_KEY) if isinstance(obj, Mapping) else None
    if stored is None:
        return None
    if not isinstance(stored, Mapping):
        raise ValueError(f"{name}: '{CONFIG_KEY}' must be a mapping of DepthSplat settings")
    return DepthSplatConfig.from_dict(dict(stored))


def detect_config(sd: Mapping[str, Tensor], depth_only: bool, name: str = "") -> DepthSplatConfig:
    """The variant from the keys and shapes (ViT width and depth, number of scales, the DPT's
    input widths), and gaussian_scale_max from the table of released files when the name is
    known (it is not stored in the weights; 3.0 otherwise)."""
    try:
        dim = sd["depth_predictor.pretrained.pos_embed"].shape[-1]
    except KeyError as e:
        raise ValueError(f"{name}: no DINOv2 weights (depth_predictor.pretrained.*); {HINT}") from e
    depth = 1 + max(
        int(k.split(".")[3]) for k in sd if k.startswith("depth_predictor.pretrained.blocks.")
    )
    vit = next((n for n, s in VIT_SPECS.items() if s.dim == dim and s.depth == depth), None)
    if vit is None:
        raise ValueError(
            f"{name}: a ViT of width {dim} and {depth} blocks is none of DepthSplat's (vits, vitb, vitl)"
        )
    num_scales = 2 if "depth_predictor.regressor.1.0.weight" in sd else 1
    spec = VIT_SPECS[vit]
    key = "depth_predictor.upsampler.concat_projects.0.weight"
    if key not in sd:
        raise ValueError(f"{name}: missing {key}; {HINT}")
    cin = sd[key].shape[1]
    factor = None
    for (up, ns), levels in LEVEL_INPUTS.items():
        if ns != num_scales:
            continue
        width = sum(spec.dpt_out[0] if n == "vit" else WIDTHS[n] for n in levels[0])
        if width == cin:
            factor = up
    if factor is None:
        raise ValueError(
            f"{name}: the depth upsampler's first projection takes {cin} channels, which "
            "matches no DepthSplat layout"
        )
    cfg = DepthSplatConfig(
        vit, num_scales, factor, factor * 2 ** (num_scales - 1), depth_only=depth_only
    )
    entry = released_entry(name)
    if entry is not None:
        cfg = replace(cfg, gaussian_scale_max=entry[1]["config"].gaussian_scale_max)
    return cfg


def check_keys(model: DepthSplatEncoder, sd: Mapping[str, Tensor], name: str) -> None:
    """Strict: every key present with its shape, nothing extra; the message names them."""
    want = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    missing = sorted(set(want) - set(sd))
    unexpected = sorted(set(sd) - set(want))
    shapes = [
        f"{k}: file {tuple(sd[k].shape)} vs model {want[k]}"
        for k in sorted(set(want) & set(sd))
        if tuple(sd[k].shape) != want[k]
    ]
    if missing or unexpected or shapes:

        def listing(items):
            return ", ".join(items[:8]) + (f" ... ({len(items)} in all)" if len(items) > 8 else "")

        parts = []
        if missing:
            parts.append(f"missing keys: {listing(missing)}")
        if unexpected:
            parts.append(f"unexpected keys: {listing(unexpected)}")
        if shapes:
            parts.append(f"shape mismatches: {listing(shapes)}")
        raise ValueError(
            f"{name} does not match DepthSplat {model.cfg.monodepth_vit_type} with "
            f"num_scales={model.cfg.num_scales}, upsample_factor={model.cfg.upsample_factor}: "
            + "; ".join(parts)
            + " (check the overrides, or that the file is a DepthSplat checkpoint)"
        )


def load_depthsplat(path_or_state_dict, device=None, **overrides) -> DepthSplatEncoder:
    """Load a DepthSplat checkpoint into :class:`DepthSplatEncoder` (eval mode).

    Args:
        path_or_state_dict: a released ``depthsplat-*.pth`` (or ``.safetensors``), a Lightning
            checkpoint dict, a depth checkpoint dict ``{'model': ...}``, or an encoder state
            dict (keys without the ``encoder.`` prefix). A file prosplat wrote (a fine-tuned
            generator) carries its settings, which are used instead of the detected ones.
        device: where to put the model (default CPU).
        **overrides: DepthSplat encoder settings (``monodepth_vit_type``, ``num_scales``,
            ``upsample_factor``, ``lowest_feature_resolution``, ``gaussian_scale_max``,
            ``local_mv_match``, ...; ``gaussian_adapter.gaussian_scale_max`` works too).
    Raises:
        FileNotFoundError: no such file. ValueError: not a DepthSplat checkpoint, or keys or
        shapes that do not match the (detected or overridden) configuration; the message
        names the missing and unexpected keys.
    """
    obj, name = _read_object(path_or_state_dict)
    sd, depth_only = _encoder_state(obj, name)
    cfg = stored_config(obj, name) or detect_config(sd, depth_only, name)
    if overrides:
        cfg = cfg.with_overrides(**overrides)
    with torch.device("meta"):
        model = DepthSplatEncoder(cfg)
    check_keys(model, sd, name)
    model.load_state_dict({k: v.float() for k, v in sd.items()}, strict=True, assign=True)
    model.variant = released_entry(name)[0] if released_entry(name) else name
    model.to(memory_format=torch.channels_last).eval()  # oneDNN's fast conv layout
    if device is not None:
        model.to(device)
    return model


def random_state_dict(model_or_layout, seed: int) -> dict[str, Tensor]:
    """The parity tests' recipe: one ``torch.Generator`` seeded with ``seed``; keys in sorted
    order; each floating tensor ``randn(shape) / sqrt(fan_in)`` with fan_in = prod(shape[1:])
    for ndim > 1, shape[0] for 1-D tensors (biases, norm weights, layer scales), 1 for 0-d.
    ``model_or_layout``: a module or a {key: shape} mapping."""
    if isinstance(model_or_layout, torch.nn.Module):
        layout = {k: tuple(v.shape) for k, v in model_or_layout.state_dict().items()}
    else:
        layout = {k: tuple(s) for k, s in model_or_layout.items()}
    g = torch.Generator().manual_seed(seed)
    out = {}
    for k in sorted(layout):
        shape = layout[k]
        fan = math.prod(shape[1:]) if len(shape) > 1 else (shape[0] if len(shape) == 1 else 1)
        out[k] = torch.randn(shape, generator=g, dtype=torch.float32) / math.sqrt(fan)
    return out


def random_encoder(cfg: DepthSplatConfig, seed: int) -> DepthSplatEncoder:
    """A :class:`DepthSplatEncoder` filled by :func:`random_state_dict` (eval mode)."""
    with torch.device("meta"):
        model = DepthSplatEncoder(cfg)
    model.load_state_dict(random_state_dict(model, seed), strict=True, assign=True)
    return model.to(memory_format=torch.channels_last).eval()


def save_released_format(
    model: DepthSplatEncoder,
    path: str | Path,
    config: bool = False,
    meta: Mapping[str, object] | None = None,
) -> Path:
    """Write ``model`` as DepthSplat writes its released files (a dict with a Lightning-style
    ``state_dict`` whose keys start with ``encoder.``), so :func:`load_depthsplat` and
    DepthSplat's own code read it. ``config``: also store the settings under
    :data:`CONFIG_KEY` (and ``meta``, plain values, under :data:`META_KEY`), which DepthSplat
    ignores. Written through a temp file and a rename: a reader never sees half a file."""
    path = Path(path)
    sd = {PREFIX + k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    obj: dict = {"state_dict": sd, "pytorch-lightning_version": "2.4.0"}
    if config:
        obj[CONFIG_KEY] = model.cfg.to_dict()
        obj[META_KEY] = dict(meta or {})
    tmp = path.with_name(f".{path.name}.tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)
    return path


__all__ = [
    "CONFIG_KEY",
    "RELEASED",
    "detect_config",
    "load_depthsplat",
    "random_encoder",
    "random_state_dict",
    "read_state_dict",
    "save_released_format",
    "stored_config",
]
