"""Building the improvement model on a local diffusers-format SD-Turbo, fine-tuned with LoRA.

Nothing is downloaded: ``path`` is a folder laid out like the hub's ``stabilityai/sd-turbo``
(``vae/`` and ``unet/`` with ``config.json`` + weights, optionally ``scheduler/``). Following
pix2pix-turbo, the U-Net gets rank-8 LoRA adapters and the VAE rank-4 ones on the same module
names; the base weights are frozen, while the encoder->decoder skip convolutions and DWEA
(new modules) train fully.

The U-Net cross-attends to the empty prompt's CLIP embedding. It is read from
``path/empty_prompt.safetensors`` (key ``prompt_embedding``, ``[1,77,D]``) if present,
computed once with ``path/text_encoder`` + ``path/tokenizer`` (transformers) if those exist,
and otherwise zeros (with a warning: the U-Net then sees a context it was not trained with).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import torch
from diffusers import AutoencoderKL, DDPMScheduler, UNet2DConditionModel
from torch import Tensor

from prosplat.improve.config import SD_PROMPT_TOKENS, ImproveConfig
from prosplat.improve.model import ImproveModel

#: pix2pix-turbo's LoRA targets (module-name suffixes) for the U-Net and the VAE.
UNET_LORA_TARGETS = (
    "to_k", "to_q", "to_v", "to_out.0", "conv", "conv1", "conv2", "conv_shortcut",
    "conv_out", "proj_in", "proj_out", "ff.net.2", "ff.net.0.proj",
)  # fmt: skip
VAE_LORA_TARGETS = (
    "conv1", "conv2", "conv_in", "conv_shortcut", "conv", "conv_out",
    "to_k", "to_q", "to_v", "to_out.0",
)  # fmt: skip


def _prompt_embedding(path: Path, dim: int) -> Tensor:
    """[1,L,dim] embedding of the empty prompt (see the module docstring for the sources)."""
    cached = path / "empty_prompt.safetensors"
    if cached.is_file():
        from safetensors.torch import load_file

        emb = load_file(str(cached))["prompt_embedding"]
    elif (path / "text_encoder").is_dir() and (path / "tokenizer").is_dir():
        from transformers import CLIPTextModel, CLIPTokenizer

        tok = CLIPTokenizer.from_pretrained(path / "tokenizer")
        enc = CLIPTextModel.from_pretrained(path / "text_encoder")
        ids = tok("", padding="max_length", max_length=tok.model_max_length, return_tensors="pt")
        with torch.no_grad():
            emb = enc(ids.input_ids)[0]
    else:
        warnings.warn(
            f"{path} has no empty_prompt.safetensors and no text_encoder/tokenizer; the U-Net's "
            "prompt context is zeros",
            stacklevel=3,
        )
        emb = torch.zeros(1, SD_PROMPT_TOKENS, dim)
    if emb.ndim != 3 or emb.shape[0] != 1 or emb.shape[2] != dim:
        raise ValueError(f"the empty-prompt embedding must be [1,L,{dim}], got {list(emb.shape)}")
    return emb.float()


def config_for(
    vae: AutoencoderKL, unet: UNet2DConditionModel, tokens: int, **changes
) -> ImproveConfig:
    """The :class:`ImproveConfig` that describes given diffusers modules."""
    vc, uc = vae.config, unet.config
    head_dim = uc.attention_head_dim
    return ImproveConfig(
        vae_channels=tuple(vc.block_out_channels),
        vae_layers=vc.layers_per_block,
        latent_channels=vc.latent_channels,
        vae_groups=vc.norm_num_groups,
        unet_channels=tuple(uc.block_out_channels),
        unet_layers=uc.layers_per_block
        if isinstance(uc.layers_per_block, int)
        else uc.layers_per_block[0],
        unet_cross_attention=tuple("CrossAttn" in t for t in uc.down_block_types),
        cross_attention_dim=uc.cross_attention_dim,
        attention_head_dim=head_dim if isinstance(head_dim, int) else head_dim[0],
        unet_groups=uc.norm_num_groups,
        prompt_tokens=tokens,
        scaling_factor=vc.scaling_factor,
        residual=False,
        **changes,
    )


def from_diffusers(
    path: str | Path,
    *,
    lora: bool = True,
    unet_rank: int = 8,
    vae_rank: int = 4,
    timestep: int = 999,
    reference: bool = True,
) -> ImproveModel:
    """An :class:`ImproveModel` around the VAE and U-Net saved under ``path``.

    Args:
        path: local diffusers-format SD-Turbo folder (``vae/``, ``unet/``).
        lora: add LoRA adapters (peft) and freeze the base weights; False trains everything.
        unet_rank, vae_rank: LoRA ranks (pix2pix-turbo: 8 and 4).
        timestep: the one-step timestep (SD-Turbo / pix2pix-turbo use 999).
        reference: MORI + DWEA on (the full model) or off (ablation).
    """
    path = Path(path)
    for sub in ("vae", "unet"):
        if not (path / sub / "config.json").is_file():
            raise FileNotFoundError(
                f"{path / sub} has no config.json; pass a local diffusers-format SD-Turbo folder "
                "(with vae/ and unet/ subfolders)"
            )
    vae = AutoencoderKL.from_pretrained(path / "vae")
    unet = UNet2DConditionModel.from_pretrained(path / "unet")
    scheduler = None
    if (path / "scheduler").is_dir():
        scheduler = DDPMScheduler.from_pretrained(path / "scheduler", clip_sample=False)
    emb = _prompt_embedding(path, unet.config.cross_attention_dim)
    config = config_for(vae, unet, emb.shape[1], timestep=timestep, reference=reference)
    model = ImproveModel(config, vae=vae, unet=unet, scheduler=scheduler, prompt_embedding=emb)
    if lora:
        add_lora(model, unet_rank, vae_rank)
    return model


def add_lora(model: ImproveModel, unet_rank: int = 8, vae_rank: int = 4) -> None:
    """Freeze the VAE and U-Net base weights and add trainable LoRA adapters through peft."""
    try:
        from peft import LoraConfig
    except ImportError as e:
        raise ImportError(
            "LoRA needs peft: pip install 'prosplat[lora]' (or pip install peft)"
        ) from e
    model.vae.requires_grad_(False)
    model.unet.requires_grad_(False)
    model.unet.add_adapter(
        LoraConfig(
            r=unet_rank,
            lora_alpha=unet_rank,
            init_lora_weights="gaussian",
            target_modules=list(UNET_LORA_TARGETS),
        )
    )
    model.vae.add_adapter(
        LoraConfig(
            r=vae_rank,
            lora_alpha=vae_rank,
            init_lora_weights="gaussian",
            target_modules=list(VAE_LORA_TARGETS),
        ),
        adapter_name="vae_skip",
    )


def merge_lora(model: ImproveModel) -> ImproveModel:
    """Fold the LoRA adapters into the VAE and U-Net weights and drop them (in place).

    The result is a plain :class:`ImproveModel` whose state dict has no ``lora_`` keys, so
    :func:`~prosplat.improve.io.save_improver` writes a checkpoint that
    :func:`~prosplat.improve.io.load_improver` (and ``ProSplat.from_pretrained``) load
    without peft. A model without adapters is returned unchanged.
    """
    for sub in (model.unet, model.vae):
        if any("lora_" in name for name, _ in sub.named_parameters()):
            sub.fuse_lora(lora_scale=1.0)
            sub.unload_lora()
    return model
