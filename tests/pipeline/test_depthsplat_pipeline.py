"""DepthSplat through prosplat's pipeline: a random-weights file in the released format loads
with ProSplat.from_pretrained(generator=...) and gives prosplat.Gaussians that render."""

from __future__ import annotations

import pytest
import torch

from prosplat import Camera, ProSplat
from prosplat.core.rotations import rotmat_to_quat  # noqa: F401  (same helper the wrapper uses)
from prosplat.generator.depthsplat import random_encoder, save_released_format
from prosplat.generator.depthsplat.config import SMALL
from prosplat.generator.depthsplat.wrapper import DepthSplatGenerator, fit_size, prepare_views

NAME = "depthsplat-gs-small-re10k-256x256-view2-cfeab6b1.pth"


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).unflatten(-1, (3, 3))  # fmt: skip


def cameras(w: int, h: int) -> list[Camera]:
    return [
        Camera.look_at(
            eye=(x, -0.3, -3.0), target=(0, 0, 0), up=(0, -1, 0), fx=0.9 * w, width=w, height=h
        )
        for x in (-0.6, 0.1, 0.7)
    ]


@pytest.fixture(scope="module")
def released_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("ds") / NAME
    return save_released_format(random_encoder(SMALL, 7), path)


def test_from_pretrained_generator_gives_gaussians_that_render(released_file):
    model = ProSplat.from_pretrained(generator=released_file, improve=False)
    assert isinstance(model.generator, DepthSplatGenerator)
    g = torch.Generator().manual_seed(0)
    cams = cameras(70, 60)  # not multiples of 16: resized to 64x64
    images = torch.rand(3, 3, 60, 70, generator=g)
    out = model.run_generator(images, cams, near=1.0, far=8.0)
    assert out.depths.shape == (1, 3, 64, 64)
    gs = out.gaussians(0)
    assert gs.means.shape == (3 * 64 * 64, 3) and gs.sh.shape == (3 * 64 * 64, 9, 3)
    for t in (gs.means, gs.quats, gs.scales, gs.opacities, gs.sh):
        assert torch.isfinite(t).all()
    assert torch.allclose(gs.quats.norm(dim=-1), torch.ones(len(gs.quats)), atol=1e-5)
    view = model.render(gs, cams[1].resized(64, 64), enhance=False)
    assert torch.isfinite(view.image).all() and view.image.shape == (3, 64, 64)
    assert float(view.image.std()) > 0


def test_conventions_match_forward_reference(released_file):
    """quats/scales rebuild DepthSplat's covariances; each Gaussian lies at its pixel's depth,
    within half a pixel of the pixel centre in the (resized) input camera."""
    model = ProSplat.from_pretrained(generator=released_file, improve=False)
    gen = model.generator
    g = torch.Generator().manual_seed(1)
    cams = cameras(70, 60)
    images = torch.rand(1, 3, 3, 60, 70, generator=g)
    K = torch.stack([c.K.float() for c in cams])[None]
    w2c = torch.stack([c.world_to_cam.float() for c in cams])[None]
    with torch.no_grad():
        out = gen(images, K, w2c, 1.0, 8.0)
        imgs, Kr = prepare_views(images, K, (64, 64), "resize")
        Kn = Kr.clone()
        Kn[..., 0, :] /= 64
        Kn[..., 1, :] /= 64
        ref = gen.encoder.forward_reference(
            imgs, Kn, torch.linalg.inv(w2c), torch.ones(1, 3), torch.full((1, 3), 8.0)
        )
    R = quat_to_matrix(out.quats[0])
    cov = R @ torch.diag_embed(out.scales[0] ** 2) @ R.transpose(-1, -2)
    scale = ref["covariances"].abs().amax(dim=(-1, -2), keepdim=True)[0]
    assert torch.allclose(cov / scale, ref["covariances"][0] / scale, atol=1e-4)
    assert torch.equal(out.means, ref["means"])
    means = out.means[0].view(3, 64 * 64, 3)
    cam_pts = (w2c[0, :, None, :3, :3] @ means[..., None])[..., 0] + w2c[0, :, None, :3, 3]
    assert torch.allclose(cam_pts[..., 2], out.depths[0].reshape(3, -1), rtol=1e-4)
    pix = (Kr[0, :, None] @ (cam_pts / cam_pts[..., 2:])[..., None])[..., :2, 0]
    rows, cols = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
    centre = torch.stack([cols, rows], dim=-1).reshape(-1, 2) + 0.5
    assert (pix - centre).abs().max() <= 0.5 + 1e-3


def test_size_helpers():
    assert fit_size(60, 70, 16, "resize") == (64, 64)
    assert fit_size(60, 70, 16, "crop") == (48, 64)
    with pytest.raises(ValueError, match="mode"):
        fit_size(60, 70, 16, "stretch")
    images = torch.rand(1, 2, 3, 60, 70)
    K = torch.tensor([[50.0, 0, 35], [0, 50, 30], [0, 0, 1]]).expand(1, 2, 3, 3)
    cropped, Kc = prepare_views(images, K, (48, 64), "crop")
    assert cropped.shape[-2:] == (48, 64)
    assert torch.equal(cropped, images[..., 6:54, 3:67])
    assert Kc[0, 0, 0, 2] == 32 and Kc[0, 0, 1, 2] == 24
    _, Kr = prepare_views(images, K, (64, 64), "resize")
    assert torch.allclose(Kr[0, 0, 0], torch.tensor([50 * 64 / 70, 0, 35 * 64 / 70]))


def test_pipeline_errors(released_file, tmp_path):
    with pytest.raises(ValueError, match="either"):
        ProSplat.from_pretrained(tmp_path / "x.safetensors", generator=released_file, improve=False)
    with pytest.raises(FileNotFoundError):
        ProSplat.from_pretrained(generator=tmp_path / "missing.pth", improve=False)
    model = ProSplat.from_pretrained(generator=released_file, improve=False)
    with pytest.raises(ValueError, match="DepthSplat"):
        model.save(tmp_path / "out.safetensors")


def test_eval_cli_adds_a_depthsplat_row(released_file, tmp_path):
    import subprocess
    import sys

    from synthetic_scenes import write_synthetic_scene

    folder = tmp_path / "scene_a"
    write_synthetic_scene(folder, size=32, n_views=5)
    cmd = [sys.executable, "-m", "prosplat", "eval", "generator", "--data", str(tmp_path)]
    cmd += ["--views", "2", "--no-generator", "--baselines", "--generator", str(released_file)]
    cmd += ["--out", str(tmp_path / "eval")]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "DepthSplat (user weights)" in res.stdout


def test_reconstruct_and_demo_take_a_depthsplat_checkpoint(released_file, tmp_path):
    """`prosplat reconstruct --generator FILE.pth` runs DepthSplat as stage 1; --weights with it
    is refused in one line."""
    from posed_data import scene_cameras, write_colmap_project

    from prosplat.cli import build_parser
    from prosplat.cli.demo import DemoConfig
    from prosplat.core.ply import read_ply

    def cli(argv: list[str]) -> int:
        args = build_parser().parse_args(argv)
        return args.func(args)

    colmap = write_colmap_project(tmp_path / "proj", scene_cameras(2))
    out = tmp_path / "out"
    code = cli(["reconstruct", str(colmap), "--out", str(out), "--size", "32",
                "--generator", str(released_file), "--render", "none"])  # fmt: skip
    assert code == 0
    g = read_ply(out / "gaussians.ply")
    assert len(g) > 100 and torch.isfinite(g.means).all()
    code = cli(["reconstruct", str(colmap), "--out", str(tmp_path / "o2"), "--weights", "x",
                "--generator", str(released_file)])  # fmt: skip
    assert code == 2
    with pytest.raises(ValueError, match="either --weights"):
        DemoConfig(weights="a.safetensors", generator=str(released_file)).check()


def test_a_file_prosplat_wrote_keeps_its_settings_when_renamed(tmp_path):
    """gaussian_scale_max is not in the weights: a released 448x768 file gets 0.1 from its
    name; a fine-tune that prosplat wrote carries it inside, so any name loads right."""
    from prosplat.generator.depthsplat import load_depthsplat
    from prosplat.generator.depthsplat.config import SMALL_448

    enc = random_encoder(SMALL_448, 3)
    plain = save_released_format(enc, tmp_path / "renamed.pth")
    assert load_depthsplat(plain).cfg.gaussian_scale_max == 3.0  # unknown name: the default
    tuned = save_released_format(enc, tmp_path / "my-finetune.pth", config=True, meta={"step": 5})
    cfg = load_depthsplat(tuned).cfg
    assert cfg == SMALL_448 and cfg.gaussian_scale_max == 0.1
    assert load_depthsplat(tuned, gaussian_scale_max=0.5).cfg.gaussian_scale_max == 0.5
