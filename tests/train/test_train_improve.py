"""Stage-2 curation, independent training and joint training on tiny synthetic scenes."""

from __future__ import annotations

import json

import pytest
import torch
from improve_configs import SMALL
from synthetic_scenes import write_synthetic_scene

from prosplat import ProSplat
from prosplat.core.checkpoints import read_checkpoint, write_checkpoint
from prosplat.generator import GeneratorConfig
from prosplat.improve.io import load_improver, save_improver
from prosplat.improve.model import ImproveModel
from prosplat.train.curate import curate, curated_batch, load_curated
from prosplat.train.improve import (
    ImproveTrainConfig,
    JointTrainConfig,
    joint_parameters,
    train_improve,
    train_joint,
)

GEN = GeneratorConfig(feature_channels=16, num_depth_candidates=8, attention_layers=1,
                      mono_channels=8, mono_blocks=1, unet_channels=(8, 8, 8), refine_channels=8)  # fmt: skip


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("improve")
    for k in range(2):
        write_synthetic_scene(root / "scenes" / f"scene_{k}", size=32, n_views=7)
    torch.manual_seed(0)
    gen = ProSplat(GEN)
    gen_path = gen.save(root / "gen.safetensors")
    curated = curate(
        gen, root / "scenes", root / "curated.safetensors", views=(2, 3), progress=False
    )
    return root, gen_path, curated


def test_curation_stores_render_reference_and_truth(setup) -> None:
    root, gen_path, curated = setup
    data = load_curated(curated)
    # 2 scenes x (2 and 3 inputs) x 3 targets
    assert data["render"].shape == (12, 3, 32, 32)
    assert set(data["inputs"].tolist()) == {2, 3}
    for key in ("target", "ref_paper", "ref_overlap"):
        assert data[key].shape == data["render"].shape
    assert data["F_paper"].shape == (12, 3, 3) and torch.isfinite(data["F_paper"]).all()
    # the stored render is what the generator renders (float16 rounding aside)
    assert 0 <= float(data["render"].float().min()) and float(data["render"].float().max()) <= 1
    # the warped reference: RGB from the reference where valid, validity 0/1, never outside
    # the render's cover
    for method in ("paper", "overlap"):
        warp = data[f"warp_{method}"].float()
        assert warp.shape == (12, 4, 32, 32)
        valid = warp[:, 3]
        assert set(valid.unique().tolist()) <= {0.0, 1.0}
        assert not (valid.bool() & (data["alpha"].float() < 0.5)).any()
    assert data["warp_paper"][:, 3].float().mean() > 0.05  # the inputs see part of the targets
    raw, ref, fund, gt = curated_batch(data, torch.tensor([0, 5]), "overlap", "cpu")
    assert raw.dtype == torch.float32 and raw.shape == (2, 3, 32, 32)
    with pytest.raises(FileExistsError):
        curate(
            ProSplat.from_pretrained(gen_path, improve=False),
            root / "scenes",
            curated,
            progress=False,
        )
    with pytest.raises(ValueError, match="reference method"):
        curated_batch(data, torch.tensor([0]), "nearest", "cpu")


def test_curation_renders_smaller_splats_as_render_view_draws_them(setup) -> None:
    """``splat_scale``: the stored render and alpha are the Gaussians drawn at that multiple
    of their scales, what ``render_view(..., splat_scale=)`` gives the model at run time."""
    from prosplat.data import load_scene
    from prosplat.data.rigs import pick_inputs
    from prosplat.pipeline.enhance import render_view
    from prosplat.train.curate import curate_scene

    root, gen_path, _ = setup
    model = ProSplat.from_pretrained(gen_path, improve=False)
    scene = load_scene(root / "scenes" / "scene_0", load_depth=False)
    small = curate_scene(model, scene, [2], splat_scale=0.5, max_splat_radius=None)
    plain = curate_scene(model, scene, [2], max_splat_radius=None)
    idx = pick_inputs(scene, 2)
    cams = [scene.cameras[i] for i in idx]
    full = model.reconstruct(scene.images[idx], cams, float(scene.near[idx].min()),
                             float(scene.far[idx].max()), budget="all")  # fmt: skip
    t = scene.target_indices[0]
    # with the inputs, as the pipeline renders: the colour favours MORI's pick
    images = scene.images[idx]
    view = render_view(full.gaussians, scene.cameras[t], images, cams, splat_scale=0.5)
    assert torch.allclose(small["render"][0].float(), view.raw, atol=1e-3)
    alike = curate_scene(model, scene, [2], splat_scale=0.5, max_splat_radius=None,
                         other_views_opacity=1)  # fmt: skip
    plain_view = render_view(full.gaussians, scene.cameras[t], splat_scale=0.5)
    assert torch.allclose(alike["render"][0].float(), plain_view.raw, atol=1e-3)
    assert not torch.allclose(alike["render"][0].float(), view.raw, atol=1e-3)
    assert torch.allclose(small["alpha"][0].float(), view.alpha, atol=1e-3)
    assert float(small["alpha"][0].float().mean()) < float(plain["alpha"][0].float().mean())


def test_curation_leaves_out_oversized_splats_as_an_enhanced_view_does(setup) -> None:
    """``max_splat_radius``: each stored render, alpha and warp come from the Gaussians that
    view keeps, what ``render_view`` hands stage 2 at run time (a radius small enough that
    the tiny generator's splats are cut on every view)."""
    from prosplat.data import load_scene
    from prosplat.data.rigs import pick_inputs
    from prosplat.improve.warp import reference_warp
    from prosplat.pipeline.enhance import oversized_splats, render_view
    from prosplat.render import render
    from prosplat.train.curate import curate_scene

    root, gen_path, _ = setup
    model = ProSplat.from_pretrained(gen_path, improve=False)
    scene = load_scene(root / "scenes" / "scene_0", load_depth=False)
    radius = 0.04
    capped = curate_scene(model, scene, [2], max_splat_radius=radius)
    every = curate_scene(model, scene, [2], max_splat_radius=None)
    idx = pick_inputs(scene, 2)
    cams = [scene.cameras[i] for i in idx]
    g = model.reconstruct(scene.images[idx], cams, float(scene.near[idx].min()),
                          float(scene.far[idx].max()), budget="all").gaussians  # fmt: skip
    for k, t in enumerate(scene.target_indices):
        cam = scene.cameras[t]
        cut = oversized_splats(g, cam, radius)
        assert 0 < int(cut.sum()) < len(g)
        view = render_view(
            g, cam, scene.images[idx], cams, fill_holes=True, max_splat_radius=radius
        )
        assert torch.allclose(capped["render"][k].float(), view.raw, atol=1e-3)
        assert torch.allclose(capped["alpha"][k].float(), view.alpha, atol=1e-3)
        # the warp: the same Gaussians' depth at the reference camera, not every splat's
        kept = g[~cut]
        ref = capped["ref_paper"][k]
        j = next(i for i in range(len(cams)) if torch.equal(scene.images[idx[i]].half(), ref))
        with torch.no_grad():
            ref_depth = render(kept, cams[j]).depth
        warp = reference_warp(
            kept, cam, view.depth, view.alpha, scene.images[idx[j]], cams[j], ref_depth
        )
        assert torch.allclose(capped["warp_paper"][k].float(), warp, atol=2e-3)
    # the cut splats held coverage that every-splat curation kept
    assert torch.stack(capped["alpha"]).float().mean() < torch.stack(every["alpha"]).float().mean()


def test_train_improve_logs_resumes_and_saves(setup, tmp_path) -> None:
    _, _, curated = setup
    cfg = ImproveTrainConfig(data=str(curated), out=str(tmp_path / "run"), val=str(curated), steps=4,
                             batch=4, save_every=2, log_every=1, val_every=2, lpips_weight=1.0,
                             device="cpu")  # fmt: skip
    path = train_improve(cfg, progress=False, model_config=SMALL)
    model = load_improver(path)
    # the working size records the views' size the model was trained on
    assert model.config == SMALL.with_(timestep=199, working_size=32)
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2, 3, 4]
    assert "val_psnr" in log[1] and "val_psnr_raw" in log[1]
    # crops, flips and the alpha input train too (the curated set carries alpha)
    aug = ImproveTrainConfig(data=str(curated), out=str(tmp_path / "aug"), steps=2, batch=2,
                             lpips_weight=0.0, crop=16, flip=True, alpha=True, device="cpu")  # fmt: skip
    model = load_improver(train_improve(aug, progress=False, model_config=SMALL))
    assert model.config.alpha_input and model.config.working_size == 32
    # and the warped reference (crops and flips move it with the render)
    wcfg = ImproveTrainConfig(**{**aug.__dict__, "out": str(tmp_path / "warp"), "warp": True})
    warp_path = train_improve(wcfg, progress=False, model_config=SMALL)
    model = load_improver(warp_path)
    assert model.config.warp_input and model.config.alpha_input
    # a warp model is not fine-tuned without its warp, nor on sets that lack it
    nowarp = ImproveTrainConfig(
        **{**aug.__dict__, "out": str(tmp_path / "nw"), "init": str(warp_path)}
    )
    with pytest.raises(ValueError, match="pass --warp"):
        train_improve(nowarp, progress=False)
    data = load_curated(curated)
    bare = tmp_path / "bare.safetensors"
    write_checkpoint(
        {k: v for k, v in data.items() if not k.startswith("warp_")}, bare,
        {"format": "prosplat-curated"},
    )  # fmt: skip
    noset = ImproveTrainConfig(**{**wcfg.__dict__, "data": str(bare), "out": str(tmp_path / "ns")})
    with pytest.raises(ValueError, match="warped references"):
        train_improve(noset, progress=False, model_config=SMALL)
    # the injection ablation rows start from the same weights: DWEA dropped ("warp": the warp
    # alone) or its epipolar weighting off ("plain"), recorded in the saved config
    only = ImproveTrainConfig(**{**wcfg.__dict__, "out": str(tmp_path / "wo"),
                                 "init": str(warp_path), "reference": False})  # fmt: skip
    model = load_improver(train_improve(only, progress=False))
    assert not model.config.reference and model.config.warp_input and model.dwea is None
    plain = ImproveTrainConfig(**{**wcfg.__dict__, "out": str(tmp_path / "pl"),
                                  "init": str(warp_path), "epipolar": False})  # fmt: skip
    model = load_improver(train_improve(plain, progress=False))
    assert model.config.reference and not model.config.epipolar
    with pytest.raises(ValueError, match="save-every"):
        ImproveTrainConfig(data=str(curated), out=str(tmp_path / "x"), save_every=0)
    # resume to 6 steps: continues at step 4
    cfg6 = ImproveTrainConfig(**{**cfg.__dict__, "steps": 6})
    train_improve(cfg6, progress=False, model_config=SMALL)
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log][-2:] == [5, 6]


def test_an_interrupted_run_saves_its_weights_and_resumes(setup, tmp_path, monkeypatch) -> None:
    """Ctrl-C (or `timeout --signal=INT` on a time-boxed GPU machine) keeps what was trained:
    improve.safetensors at the step reached, and a checkpoint the same command resumes from."""
    import prosplat.train.improve as improve_mod

    _, _, curated = setup
    cfg = ImproveTrainConfig(data=str(curated), out=str(tmp_path / "run"), steps=5, batch=2,
                             save_every=100, log_every=1, lpips_weight=0.0, device="cpu")  # fmt: skip
    real, calls = improve_mod.enhance_loss, []

    def stop_at_third_step(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(improve_mod, "enhance_loss", stop_at_third_step)
    path = train_improve(cfg, progress=False, model_config=SMALL)
    assert read_checkpoint(path, "stage 2")[1]["steps"] == "2"
    monkeypatch.setattr(improve_mod, "enhance_loss", real)
    train_improve(cfg, progress=False, model_config=SMALL)  # resumes at step 2, not from 0
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2, 3, 4, 5]
    assert read_checkpoint(path, "stage 2")[1]["steps"] == "5"


def test_the_cli_exits_130_when_interrupted_and_0_when_done(setup, tmp_path, monkeypatch) -> None:
    """`prosplat train improve ... && next` must stop at Ctrl-C, as after any interrupted
    command, though the weights so far are saved; the resumed run that finishes exits 0."""
    import prosplat.train.improve as improve_mod
    from prosplat.cli import main

    _, _, curated = setup
    argv = ["train", "improve", "--data", str(curated), "--out", str(tmp_path / "run"),
            "--steps", "3", "--batch", "2", "--lpips-weight", "0", "--device", "cpu"]  # fmt: skip
    real = improve_mod.enhance_loss

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(improve_mod, "enhance_loss", interrupted)
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    assert stopped.value.code == 130
    assert (tmp_path / "run" / "improve.safetensors").is_file()
    monkeypatch.setattr(improve_mod, "enhance_loss", real)
    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 0


def test_training_lowers_the_loss(setup, tmp_path) -> None:
    _, _, curated = setup
    data = load_curated(curated)
    cfg = ImproveTrainConfig(data=str(curated), out=str(tmp_path / "r"), steps=30, batch=12, lr=2e-3,
                             warmup=1, lpips_weight=0.0, save_every=100, device="cpu")  # fmt: skip
    torch.manual_seed(0)
    path = train_improve(cfg, progress=False, model_config=SMALL)
    raw, ref, fund, gt = curated_batch(data, torch.arange(12), "paper", "cpu")
    with torch.no_grad():
        after = (load_improver(path)(raw, ref, fund) - gt).square().mean()
    before = (raw - gt).square().mean()  # the untrained model is the identity
    assert after < before


def test_joint_training_changes_only_adapter_and_vae(setup, tmp_path) -> None:
    root, gen_path, _ = setup
    torch.manual_seed(0)
    imp = ImproveModel(SMALL)
    torch.nn.init.normal_(imp.vae.decoder.conv_out.weight, std=0.05)  # as after stage-2 training
    imp_path = save_improver(imp, tmp_path / "imp.safetensors")
    cfg = JointTrainConfig(data=str(root / "scenes"), out=str(tmp_path / "joint"), generator=str(gen_path),
                           improver=str(imp_path), steps=2, inputs=2, targets=2, lr=1e-3, warmup=1,
                           lpips_weight=0.5, save_every=1, log_every=1, train_decoder=False,
                           device="cpu")  # fmt: skip
    g_out, i_out = train_joint(cfg, progress=False)
    before_g = ProSplat.from_pretrained(gen_path, improve=False).generator.state_dict()
    after_g = ProSplat.from_pretrained(g_out, improve=False).generator.state_dict()
    changed = {k for k in before_g if not torch.equal(before_g[k], after_g[k])}
    assert changed and all(k.startswith("adapter.") for k in changed)
    before_i, after_i = load_improver(imp_path).state_dict(), load_improver(i_out).state_dict()
    changed = {k for k in before_i if not torch.equal(before_i[k], after_i[k])}
    assert changed and all(k.startswith(("vae.encoder.", "vae.quant_conv.")) for k in changed)


@pytest.mark.parametrize("decoder", [False, True])
def test_joint_parameters_freeze_the_rest(decoder: bool) -> None:
    pipe = ProSplat(GEN)
    imp = ImproveModel(SMALL)
    params = {id(p) for p in joint_parameters(pipe, imp, decoder)}
    names = [n for n, p in imp.named_parameters() if id(p) in params]
    assert any(n.startswith("vae.encoder.") for n in names)
    assert any(n.startswith("vae.decoder.") for n in names) == decoder
    assert not any(n.startswith(("unet.", "dwea.")) for n in names)
    gen_names = [n for n, p in pipe.generator.named_parameters() if p.requires_grad]
    assert gen_names and all(n.startswith("adapter.") for n in gen_names)


def test_ablation_rows_score_the_same_views(setup, tmp_path) -> None:
    """`prosplat eval improve`'s engine: every row scores the same targets; an untrained
    (identity) improver scores exactly what the generator alone does."""
    from prosplat.data.scene import load_scene
    from prosplat.eval.improve import Row, evaluate_rows

    root, gen_path, _ = setup
    gen = ProSplat.from_pretrained(gen_path, improve=False)
    rows = {"generator only": Row(gen), "identity": Row(gen, ImproveModel(SMALL), "overlap")}
    scene = load_scene(root / "scenes" / "scene_0", load_depth=False)
    scores = evaluate_rows(scene, rows, [2, 3])
    assert len(scores) == 2 * 2 * len(scene.target_indices)
    gen_psnr = [s.psnr for s in scores if s.method == "generator only"]
    id_psnr = [s.psnr for s in scores if s.method == "identity"]
    assert gen_psnr == pytest.approx(id_psnr, abs=1e-4)
    assert {s.views for s in scores} == {2, 3} and all(s.gaussians > 0 for s in scores)


def test_train_improve_on_a_local_sd_turbo_saves_merged_lora(setup, tmp_path) -> None:
    """--pretrained trains LoRA on a diffusers-format model; the saved file has the adapters
    folded in, loads without peft and enhances exactly like the trained model."""
    pytest.importorskip("peft")
    from safetensors.torch import save_file

    from prosplat.improve.model import build_unet, build_vae

    _, _, curated = setup
    torch.manual_seed(0)
    sd = SMALL.with_(unet_cross_attention=(True, True, False), scaling_factor=0.18215)
    build_vae(sd).save_pretrained(tmp_path / "sd" / "vae")
    build_unet(sd).save_pretrained(tmp_path / "sd" / "unet")
    emb = torch.randn(1, 77, sd.cross_attention_dim)
    save_file({"prompt_embedding": emb}, str(tmp_path / "sd" / "empty_prompt.safetensors"))
    cfg = ImproveTrainConfig(data=str(curated), out=str(tmp_path / "run"), steps=3, batch=4,
                             lr=1e-2, save_every=3, lpips_weight=0.0, timestep=999,
                             pretrained=str(tmp_path / "sd"), device="cpu")  # fmt: skip
    path = train_improve(cfg, progress=False)
    merged = load_improver(path)
    assert not any("lora" in k for k in merged.state_dict())
    assert merged.config.timestep == 999 and merged.config.residual is False
    # the run's own checkpoint keeps the adapters (that is what a resume loads)
    from safetensors import safe_open

    with safe_open(str(tmp_path / "run" / "checkpoint.safetensors"), "pt") as f:
        lora_keys = [k for k in f.keys() if "lora_B" in k]
    assert lora_keys
    # the merged file computes what base + trained adapters compute
    from prosplat.improve.pretrained import from_diffusers

    with_lora = from_diffusers(tmp_path / "sd", timestep=999)
    with safe_open(str(tmp_path / "run" / "checkpoint.safetensors"), "pt") as f:
        with_lora.load_state_dict({k: f.get_tensor(k) for k in f.keys()})
    with_lora.eval()
    with safe_open(str(tmp_path / "run" / "checkpoint.safetensors"), "pt") as f:
        assert any(f.get_tensor(k).abs().max() > 0 for k in lora_keys)  # adapters trained
    data = load_curated(curated)
    raw, ref, fund, _ = curated_batch(data, torch.tensor([0, 1]), "paper", "cpu")
    with torch.no_grad():
        torch.testing.assert_close(
            merged(raw, ref, fund), with_lora(raw, ref, fund), atol=1e-4, rtol=0
        )
    with pytest.raises(ValueError, match="--pretrained"):
        train_improve(ImproveTrainConfig(**{**cfg.__dict__, "init": str(path),
                                            "out": str(tmp_path / "x")}), progress=False)  # fmt: skip


def test_curation_from_a_pack_in_slices_matches_the_folders(setup, tmp_path) -> None:
    """Processes sharing a set each curate a slice of a depth-free pack (what a lent GPU
    machine does, scripts/gpu_train_stage2.sh); together they hold every folder's samples."""
    from prosplat.data.packed import pack_scenes
    from prosplat.metrics import psnr

    root, gen_path, curated = setup
    whole = load_curated(curated)
    pack = pack_scenes(sorted((root / "scenes").iterdir()), tmp_path / "s.npz", depth=False)
    gen = ProSplat.from_pretrained(gen_path, improve=False)
    parts = [
        curate(
            gen,
            pack,
            tmp_path / f"part{k}.safetensors",
            views=(2, 3),
            progress=False,
            first=k,
            count=1,
        )  # fmt: skip
        for k in range(2)
    ]
    names = [json.loads(read_checkpoint(p, "curated set")[1]["scenes"]) for p in parts]
    assert names == [["scene_0"], ["scene_1"]]
    render = torch.cat([load_curated(p)["render"] for p in parts]).float()
    target = torch.cat([load_curated(p)["target"] for p in parts]).float()
    assert render.shape == whole["render"].shape
    assert float(psnr(target, whole["target"].float()).min()) > 35  # JPEG q95, same views
    assert float(psnr(render, whole["render"].float()).mean()) > 25  # the same scenes
    with pytest.raises(ValueError, match="no scenes left"):
        curate(gen, pack, tmp_path / "none.safetensors", progress=False, first=2)
    with pytest.raises(ValueError, match="count"):
        curate(gen, f"{pack},{root / 'scenes'}", tmp_path / "x.safetensors", count=0)


def test_curation_stores_alpha_and_resizes(setup, tmp_path) -> None:
    root, gen_path, curated = setup
    data = load_curated(curated)
    assert data["alpha"].shape == (12, 32, 32)
    assert 0 <= float(data["alpha"].float().min()) and float(data["alpha"].float().max()) <= 1
    torch.manual_seed(0)
    big = curate(
        ProSplat.from_pretrained(gen_path, improve=False), root / "scenes",
        tmp_path / "big.safetensors", views=(2,), progress=False, height=64,
    )  # fmt: skip
    assert load_curated(big)["render"].shape[-2:] == (64, 64)
    # which depth the renders were made from is recorded: swept by default from weights
    from prosplat.core.checkpoints import read_checkpoint

    assert read_checkpoint(big, "curated")[1]["depth_sweep"] == "on"
    assert read_checkpoint(curated, "curated")[1]["depth_sweep"] == "off"  # ProSplat(GEN)


def test_curation_at_a_smaller_generator_size_and_training_on_two_sizes(setup, tmp_path) -> None:
    """``generator_height``: the generator runs at 32 px and its Gaussians render at the
    64-px views (as the pipeline runs the shipped weights on larger cameras); training takes
    its batches from a 32-px and a 64-px set in turn, and records the larger as its working
    size."""
    root, gen_path, curated = setup
    model = ProSplat.from_pretrained(gen_path, improve=False)
    torch.manual_seed(0)
    big = curate(
        model, root / "scenes", tmp_path / "big.safetensors", views=(2,), progress=False,
        height=64, generator_height=32,
    )  # fmt: skip
    data = load_curated(big)
    assert data["render"].shape[-2:] == (64, 64)
    # the renders are the 32-px generator's Gaussians seen at 64 px: fewer, larger splats
    # than the 64-px run's, so the two sets differ
    same = curate(
        model, root / "scenes", tmp_path / "same.safetensors", views=(2,), progress=False,
        height=64,
    )  # fmt: skip
    diff = (load_curated(same)["render"].float() - data["render"].float()).abs().mean()
    assert float(diff) > 1e-3
    cfg = ImproveTrainConfig(data=f"{curated},{big}", out=str(tmp_path / "two"), steps=2,
                             batch=2, lpips_weight=0.0, crop=16, alpha=True, device="cpu")  # fmt: skip
    assert (
        load_improver(train_improve(cfg, progress=False, model_config=SMALL)).config.working_size
        == 64
    )
    # --working-size overrides it (256: 2-4x the training views, as the shipped v10 runs)
    wide = ImproveTrainConfig(**{**cfg.__dict__, "working_size": 256, "out": str(tmp_path / "w")})
    saved = load_improver(train_improve(wide, progress=False, model_config=SMALL))
    assert saved.config.working_size == 256
    with pytest.raises(ValueError, match="working-size"):
        ImproveTrainConfig(**{**cfg.__dict__, "working_size": -2})
    bad = ImproveTrainConfig(**{**cfg.__dict__, "crop": 48, "out": str(tmp_path / "bad")})
    with pytest.raises(ValueError, match="larger than the smallest curated views"):
        train_improve(bad, progress=False, model_config=SMALL)


def test_shift_term_trains_logs_and_asks_for_crops_and_an_even_batch(setup, tmp_path) -> None:
    """``shift_weight``: each step's batch is half windows, half their moved twins; the log
    carries the disagreement between them, and settings that cannot make twins are refused."""
    _, _, curated = setup
    cfg = ImproveTrainConfig(data=str(curated), out=str(tmp_path / "shift"), steps=2, batch=4,
                             lpips_weight=0.0, crop=24, shift_weight=10.0, log_every=1,
                             device="cpu")  # fmt: skip
    train_improve(cfg, progress=False, model_config=SMALL)
    log = [json.loads(line) for line in (tmp_path / "shift" / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2]
    # the model starts as the identity, which moves with its input: the twins line up exactly;
    # one step later it is not, and the term sees it
    assert log[0]["shift"] == 0.0 and log[1]["shift"] > 0
    for bad in ({"crop": 0}, {"crop": 16}, {"batch": 3}, {"crop": 32}):
        wrong = ImproveTrainConfig(**{**cfg.__dict__, **bad, "out": str(tmp_path / "bad")})
        with pytest.raises(ValueError, match="--shift-weight needs"):
            train_improve(wrong, progress=False, model_config=SMALL)
    # --subpixel-shift: the twins are moved by a fraction of a pixel too; the identity still
    # lines up with them (the first outputs are resampled the same way), one step later not
    sub = ImproveTrainConfig(
        **{**cfg.__dict__, "subpixel_shift": True, "out": str(tmp_path / "sub")}
    )
    train_improve(sub, progress=False, model_config=SMALL)
    log = [json.loads(line) for line in (tmp_path / "sub" / "log.jsonl").read_text().splitlines()]
    assert log[0]["shift"] < 1e-10 < log[1]["shift"]
    with pytest.raises(ValueError, match="--subpixel-shift needs --shift-weight"):
        ImproveTrainConfig(**{**cfg.__dict__, "shift_weight": 0.0, "subpixel_shift": True})
