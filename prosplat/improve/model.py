"""The improvement model: a one-step diffusion image-to-image network built from diffusers.

    render ──VAE encoder──► z ──U-Net (t fixed)──► ε ──x0 = (z − √(1−ᾱ)ε)/√ᾱ──► VAE decoder ──► enhanced
    reference ──VAE encoder──► z_ref ──U-Net contracting path──┘ (DWEA at the bottleneck)

The VAE is diffusers' ``AutoencoderKL`` and the U-Net its ``UNet2DConditionModel``, so SD-Turbo's
weights load into the same code (:mod:`prosplat.improve.pretrained`). Three things are added
around them, each as modules composed in this file's forward (never by replacing a diffusers
module's ``forward``):

- pix2pix-turbo's skip connections: the input of each VAE encoder block goes, through a 1x1
  convolution that starts near zero, into the input of the matching decoder block.
- DWEA (:mod:`prosplat.improve.dwea`): the target's bottleneck features attend to the
  reference's along epipolar lines; the fused map replaces the bottleneck, and its 2x and 4x
  upsamplings go through depthwise-separable convolutions into the next two stages of the
  expansive path (zero-initialised, so an untrained DWEA changes nothing).
- no text encoder: the U-Net cross-attends to a fixed empty-prompt embedding buffer.

Images are ``[B,3,H,W]`` in [0,1]; H and W must be multiples of ``config.size_multiple``.
"""

from __future__ import annotations

import torch
from diffusers import AutoencoderKL, DDPMScheduler, UNet2DConditionModel
from torch import Tensor, nn

from prosplat.improve.config import ImproveConfig
from prosplat.improve.dwea import DWEA, DWEAInjection
from prosplat.render.hole_fill import fill_holes


def build_vae(config: ImproveConfig) -> AutoencoderKL:
    n = len(config.vae_channels)
    return AutoencoderKL(
        in_channels=3,
        out_channels=3,
        down_block_types=("DownEncoderBlock2D",) * n,
        up_block_types=("UpDecoderBlock2D",) * n,
        block_out_channels=config.vae_channels,
        layers_per_block=config.vae_layers,
        latent_channels=config.latent_channels,
        norm_num_groups=config.vae_groups,
        scaling_factor=config.scaling_factor,
    )


def build_unet(config: ImproveConfig) -> UNet2DConditionModel:
    flags = config.unet_cross_attention
    down = tuple("CrossAttnDownBlock2D" if a else "DownBlock2D" for a in flags)
    up = tuple("CrossAttnUpBlock2D" if a else "UpBlock2D" for a in reversed(flags))
    return UNet2DConditionModel(
        in_channels=config.latent_channels,
        out_channels=config.latent_channels,
        block_out_channels=config.unet_channels,
        down_block_types=down,
        up_block_types=up,
        mid_block_type="UNetMidBlock2DCrossAttn" if flags[-1] else "UNetMidBlock2D",
        layers_per_block=config.unet_layers,
        cross_attention_dim=config.cross_attention_dim,
        attention_head_dim=config.attention_head_dim,
        norm_num_groups=config.unet_groups,
    )


def build_scheduler() -> DDPMScheduler:
    """SD's noise schedule (scaled-linear betas 0.00085-0.012 over 1000 steps, ε-prediction)."""
    return DDPMScheduler(
        num_train_timesteps=1000,
        beta_start=0.00085,
        beta_end=0.012,
        beta_schedule="scaled_linear",
        prediction_type="epsilon",
        clip_sample=False,
    )


def _has_cross_attention(block: nn.Module) -> bool:
    return bool(getattr(block, "has_cross_attention", False))


class ImproveModel(nn.Module):
    """Stage 2 of ProSplat: enhances a render with the MORI reference view, in one step.

    ``ImproveModel(config)`` builds a randomly initialised model from ``config``;
    ``ImproveModel(config, vae=..., unet=...)`` wraps given diffusers modules (SD-Turbo).
    """

    def __init__(
        self,
        config: ImproveConfig,
        vae: AutoencoderKL | None = None,
        unet: UNet2DConditionModel | None = None,
        scheduler: DDPMScheduler | None = None,
        prompt_embedding: Tensor | None = None,
    ) -> None:
        super().__init__()
        self.config = config
        self.vae = vae if vae is not None else build_vae(config)
        self.unet = unet if unet is not None else build_unet(config)
        self.scheduler = scheduler if scheduler is not None else build_scheduler()
        if prompt_embedding is None:
            prompt_embedding = torch.zeros(1, config.prompt_tokens, config.cross_attention_dim)
        # [1,L,D] the U-Net's cross-attention context: a fixed empty prompt, no text encoder
        self.register_buffer("prompt_embedding", prompt_embedding.float().clone())
        self.register_buffer(
            "alphas_cumprod", self.scheduler.alphas_cumprod.float().clone(), persistent=False
        )

        enc_in = self._encoder_block_inputs()
        dec_in = self._decoder_block_inputs()
        self.skip_convs = nn.ModuleList()
        if config.vae_skip:
            for k, c_dec in enumerate(dec_in):
                conv = nn.Conv2d(enc_in[len(enc_in) - 1 - k], c_dec, 1, bias=False)
                nn.init.constant_(conv.weight, config.skip_init)
                self.skip_convs.append(conv)
        self.alpha_in = None
        if config.alpha_input:
            # [B,1,H,W] alpha -> the encoder's first features; zero start = "alpha unknown"
            self.alpha_in = nn.Conv2d(1, self.vae.config.block_out_channels[0], 3, padding=1)
            nn.init.zeros_(self.alpha_in.weight)
            nn.init.zeros_(self.alpha_in.bias)
        self.warp_in = None
        if config.warp_input:
            # [B,4,H,W] warped reference (RGB in [-1,1]) + validity -> the first features; zero
            # start = "no warp", so weights trained without it behave the same
            self.warp_in = nn.Conv2d(4, self.vae.config.block_out_channels[0], 3, padding=1)
            nn.init.zeros_(self.warp_in.weight)
            nn.init.zeros_(self.warp_in.bias)
        if config.residual:
            nn.init.zeros_(self.vae.decoder.conv_out.weight)
            nn.init.zeros_(self.vae.decoder.conv_out.bias)

        unet_out = list(reversed(self.unet.config.block_out_channels))
        bottleneck = unet_out[0]
        if config.reference:
            self.dwea = DWEA(bottleneck, heads=config.dwea_heads)
            # the inputs of up blocks 1 and 2 are the outputs of up blocks 0 and 1
            self.injection = DWEAInjection(bottleneck, unet_out[:2], scales=(2, 4))
        else:
            self.dwea = None
            self.injection = None
        self.set_padding(config.padding)

    def set_padding(self, mode: str) -> None:
        """Pad every padded convolution with ``mode`` ("zeros" or "replicate"; see
        ``ImproveConfig.padding``) and record it in the config.

        ``padding_mode`` is ``nn.Conv2d``'s own attribute, read on every forward. The VAE's
        stride-2 convolutions pad one zero row and column on the bottom and right instead
        (diffusers' ``Downsample2D`` with ``padding=0``), which marks the image's corner at
        every level; "replicate" gives them a symmetric replicate padding of 1 (a half-pixel
        shift of that level, which fine-tuning absorbs). Going back to "zeros" is refused:
        those convolutions would not be the ones the weights were trained with.
        """
        if mode == self.config.padding and mode == "zeros":
            return
        if mode != "replicate":
            raise ValueError(
                f"set_padding: a model can only go from zero to replicate padding, not to {mode!r}"
            )
        from diffusers.models.downsampling import Downsample2D

        self.config = self.config.with_(padding=mode)
        for m in list(self.modules()):
            if isinstance(m, Downsample2D) and m.use_conv and m.padding == 0:
                old = m.conv
                conv = nn.Conv2d(
                    old.in_channels, old.out_channels, old.kernel_size, old.stride, padding=1,
                    bias=old.bias is not None, padding_mode=mode,
                )  # fmt: skip
                conv.weight, conv.bias = old.weight, old.bias
                m.conv, m.padding = conv, 1
                if getattr(m, "Conv2d_0", None) is old:  # diffusers keeps a second name for it
                    m.Conv2d_0 = conv
        for m in self.modules():
            if isinstance(m, nn.Conv2d) and any(int(p) > 0 for p in m.padding):
                m.padding_mode = mode

    # ---- layout helpers ---------------------------------------------------------------------
    def _encoder_block_inputs(self) -> list[int]:
        """Channels entering each VAE encoder block (conv_in's, then each block's output)."""
        widths = list(self.vae.config.block_out_channels)
        return [widths[0]] + widths[:-1]

    def _decoder_block_inputs(self) -> list[int]:
        """Channels entering each VAE decoder block (mid block's, then each block's output)."""
        widths = list(reversed(self.vae.config.block_out_channels))
        return [widths[0]] + widths[:-1]

    def num_parameters(self) -> dict[str, int]:
        parts = {"vae": self.vae, "unet": self.unet, "skip_convs": self.skip_convs}
        if self.alpha_in is not None:
            parts["alpha_in"] = self.alpha_in
        if self.warp_in is not None:
            parts["warp_in"] = self.warp_in
        if self.dwea is not None:
            parts.update(dwea=self.dwea, injection=self.injection)
        return {k: sum(p.numel() for p in m.parameters()) for k, m in parts.items()}

    # ---- VAE with skips ---------------------------------------------------------------------
    def encode(
        self, images: Tensor, alpha: Tensor | None = None, warp: Tensor | None = None
    ) -> tuple[Tensor, list[Tensor]]:
        """images [B,3,H,W] in [0,1] (+ alpha [B,1,H,W] with ``config.alpha_input``, + warp
        [B,4,H,W] with ``config.warp_input``) -> (scaled latent mode [B,c,h,w], encoder block
        inputs)."""
        enc = self.vae.encoder
        x = enc.conv_in(images * 2.0 - 1.0)
        if alpha is not None and self.alpha_in is not None:
            x = x + self.alpha_in(alpha.to(x.dtype))
        if warp is not None and self.warp_in is not None:
            w = warp.to(x.dtype)
            x = x + self.warp_in(torch.cat([w[:, :3] * 2.0 - 1.0, w[:, 3:]], dim=1))
        skips = []
        for block in enc.down_blocks:
            skips.append(x)
            x = block(x)
        x = enc.mid_block(x)
        x = enc.conv_out(enc.conv_act(enc.conv_norm_out(x)))
        if self.vae.quant_conv is not None:
            x = self.vae.quant_conv(x)
        mean = x[:, : self.config.latent_channels]  # the posterior's mode; no sampling
        return mean * self.vae.config.scaling_factor, skips

    def decode(self, z: Tensor, skips: list[Tensor] | None) -> Tensor:
        """Scaled latent [B,c,h,w] (+ encoder skips) -> image in [-1,1]-ish units [B,3,H,W]."""
        dec = self.vae.decoder
        z = z / self.vae.config.scaling_factor
        if self.vae.post_quant_conv is not None:
            z = self.vae.post_quant_conv(z)
        x = dec.mid_block(dec.conv_in(z), None)
        for k, block in enumerate(dec.up_blocks):
            if skips is not None and len(self.skip_convs):
                x = x + self.skip_convs[k](skips[len(skips) - 1 - k])
            x = block(x, None)
        return dec.conv_out(dec.conv_act(dec.conv_norm_out(x)))

    # ---- U-Net with DWEA --------------------------------------------------------------------
    def _time_embedding(self, z: Tensor) -> Tensor:
        t = torch.full((z.shape[0],), self.config.timestep, device=z.device, dtype=torch.long)
        return self.unet.time_embedding(self.unet.get_time_embed(sample=z, timestep=t), None)

    def _contract(self, z: Tensor, emb: Tensor, context: Tensor) -> tuple[Tensor, tuple]:
        """conv_in, down blocks and mid block: (bottleneck [B,C,h/2^k,w/2^k], skip tensors)."""
        unet = self.unet
        x = unet.conv_in(z)
        res: tuple[Tensor, ...] = (x,)
        for block in unet.down_blocks:
            if _has_cross_attention(block):
                x, r = block(hidden_states=x, temb=emb, encoder_hidden_states=context)
            else:
                x, r = block(hidden_states=x, temb=emb)
            res += r
        if unet.mid_block is not None:
            if _has_cross_attention(unet.mid_block):
                x = unet.mid_block(x, emb, encoder_hidden_states=context)
            else:
                x = unet.mid_block(x, emb)
        return x, res

    def _expand(
        self, x: Tensor, res: tuple, emb: Tensor, context: Tensor, inject: list[Tensor]
    ) -> Tensor:
        """Up blocks (``inject[k]`` added to the input of up block k+1) and the output head."""
        unet = self.unet
        n = len(unet.up_blocks)
        for i, block in enumerate(unet.up_blocks):
            if 1 <= i <= len(inject):
                extra = inject[i - 1]
                if extra.shape != x.shape:
                    raise ValueError(
                        f"DWEA injection {tuple(extra.shape)} does not fit U-Net stage {i} "
                        f"{tuple(x.shape)}; the U-Net must upsample 2x per stage"
                    )
                x = x + extra
            skips = res[-len(block.resnets) :]
            res = res[: -len(block.resnets)]
            size = res[-1].shape[2:] if i < n - 1 else None
            kwargs = dict(
                hidden_states=x, temb=emb, res_hidden_states_tuple=skips, upsample_size=size
            )
            if _has_cross_attention(block):
                kwargs["encoder_hidden_states"] = context
            x = block(**kwargs)
        if unet.conv_norm_out is not None:
            x = unet.conv_act(unet.conv_norm_out(x))
        return unet.conv_out(x)

    def one_step(self, z: Tensor, eps: Tensor) -> Tensor:
        """x0 = (z - sqrt(1 - abar_t) eps) / sqrt(abar_t), the scheduler's ε-parameterisation."""
        abar = self.alphas_cumprod[self.config.timestep].to(z.dtype)
        return (z - (1 - abar).sqrt() * eps) / abar.sqrt()

    # ---- forward ----------------------------------------------------------------------------
    def forward(
        self,
        render: Tensor,
        reference: Tensor | None = None,
        fundamental: Tensor | None = None,
        alpha: Tensor | None = None,
        warp: Tensor | None = None,
    ) -> Tensor:
        """Enhance ``render [B,3,H,W]`` in [0,1].

        Args:
            reference: the MORI reference views [B,3,H,W] (required when config.reference).
            fundamental: F [B,3,3] with x_refᵀ F x_render = 0 in pixels; None or all-zero
                (pure rotation, coincident cameras) makes DWEA plain attention.
            alpha: the render's alpha [B,1,H,W] (used with ``config.alpha_input`` and
                ``config.fill_input``; None there is read as fully covered).
            warp: the reference warped into the render's view, RGB in [0,1] + validity
                [B,4,H,W] (used with ``config.warp_input``; None there is read as no warp).

        Returns:
            The enhanced images [B,3,H,W], clamped to [0,1].
        """
        self._check(render, reference)
        if self.config.fill_input and alpha is not None:
            render = fill_holes(render, alpha)  # [B,3,H,W]: the holes continued, not black
        if self.alpha_in is not None and alpha is None:
            alpha = torch.ones_like(render[:, :1])
        if self.warp_in is not None and warp is None:
            warp = torch.zeros_like(render[:, :1]).expand(-1, 4, -1, -1)
        z, skips = self.encode(render, alpha, warp)
        emb = self._time_embedding(z)
        context = self.prompt_embedding.to(z.dtype).expand(z.shape[0], -1, -1)
        x, res = self._contract(z, emb, context)
        inject: list[Tensor] = []
        if self.dwea is not None:
            z_ref, _ = self.encode(reference)
            x_ref, _ = self._contract(z_ref, emb, context)
            # F stays in its own (float32/64) precision: DWEA computes distances in float64;
            # none: plain attention (the epipolar ablation)
            f = fundamental if self.config.epipolar else None
            x = self.dwea(x, x_ref, f, float(self.config.bottleneck_stride))
            inject = self.injection(x)
        eps = self._expand(x, res, emb, context, inject)
        z_out = self.one_step(z, eps) if self.config.denoise else eps
        out = self.decode(z_out, skips if self.config.vae_skip else None)
        if self.config.residual:
            return (render + 0.5 * out).clamp(0.0, 1.0)
        return ((out + 1.0) * 0.5).clamp(0.0, 1.0)

    def _check(self, render: Tensor, reference: Tensor | None) -> None:
        if render.ndim != 4 or render.shape[1] != 3:
            raise ValueError(f"render must be [B,3,H,W], got {list(render.shape)}")
        m = self.config.size_multiple
        h, w = render.shape[-2:]
        if h % m or w % m:
            raise ValueError(
                f"the improvement model needs image sizes that are multiples of {m}, got {w}x{h}; "
                "render at a padded size or resize the camera (Camera.resized)"
            )
        if self.config.reference:
            if reference is None:
                raise ValueError(
                    "this improvement model uses a reference view (MORI); pass reference="
                )
            if reference.shape != render.shape:
                raise ValueError(
                    f"reference {list(reference.shape)} must have the render's shape {list(render.shape)}"
                )
