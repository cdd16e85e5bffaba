"""The stage-2 subcommands: ``prosplat train curate|improve|joint|blend`` and ``prosplat eval improve``.

:mod:`prosplat.cli.train` and :mod:`prosplat.cli.eval` add them with :func:`add_train_parsers`
and :func:`add_eval_parser`. ``train improve`` and ``train joint`` take their options from
their config dataclasses (:mod:`prosplat.cli.config_args`).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from prosplat.cli import recipes
from prosplat.cli.config_args import add_config_arguments, config_from_args
from prosplat.pipeline.enhance import MAX_SPLAT_RADIUS, OTHER_VIEWS_OPACITY
from prosplat.train.improve import ImproveTrainConfig, JointTrainConfig


def cmd_curate(args: argparse.Namespace) -> int:
    from prosplat.pipeline.model import ProSplat, is_depthsplat_file
    from prosplat.train.curate import curate

    if is_depthsplat_file(args.generator):  # stage 2 trained on DepthSplat's renders (issue 17)
        model = ProSplat.from_pretrained(generator=args.generator, improve=False)
    else:
        # depth_sweep None: the pipeline's default (on for prosplat weights)
        sweep = None if args.depth_sweep else False
        model = ProSplat.from_pretrained(args.generator, improve=False, depth_sweep=sweep)
    views = [int(v) for v in args.views.split(",")]
    cmd = "prosplat train curate " + " ".join(sys.argv[3:])
    if args.refine_steps < 0:
        print("prosplat train curate: --refine-steps must be >= 0 (0: off)", file=sys.stderr)
        return 2
    if not 0 < args.splat_scale < float("inf"):
        print("prosplat train curate: --splat-scale must be finite and > 0", file=sys.stderr)
        return 2
    if not 0 <= args.max_splat_radius < float("inf"):
        print(
            "prosplat train curate: --max-splat-radius must be finite and >= 0 (0: off)",
            file=sys.stderr,
        )
        return 2
    if not 0 <= args.other_views_opacity <= 1:
        print("prosplat train curate: --other-views-opacity must lie in [0, 1]", file=sys.stderr)
        return 2
    path = curate(
        model, args.data, args.out, views=views, overwrite=args.overwrite, command=cmd,
        refine_steps=args.refine_steps, height=args.size, generator_height=args.generator_size,
        splat_scale=args.splat_scale, max_splat_radius=args.max_splat_radius or None,
        other_views_opacity=args.other_views_opacity, first=args.first, count=args.count,
    )  # fmt: skip
    print(f"curated set: {path.resolve()}")
    return 0


def cmd_train_improve(args: argparse.Namespace) -> int:
    if args.recipe:
        return recipes.run_recipe_command(args, ImproveTrainConfig, "train improve")
    refused = recipes.no_recipe_without_data(args, "train improve")
    if refused is not None:
        return refused
    from prosplat.train.improve import train_improve

    cfg = config_from_args(ImproveTrainConfig, args)
    path = train_improve(cfg)
    print(f"improvement model: {path.resolve()}")
    # Ctrl-C saves the weights so far and returns; exit as an interrupted command does (130),
    # so `train improve ... && next` stops there. Only the rank that saved the file reads it
    # (torchrun's other ranks return while it is written).
    if int(os.environ.get("RANK", "0")) != 0:
        return 0
    from prosplat.train.common import weights_step

    steps = weights_step(path, key="steps")
    return 130 if steps is not None and steps < cfg.steps else 0


def cmd_train_joint(args: argparse.Namespace) -> int:
    from prosplat.train.improve import train_joint

    cfg = config_from_args(JointTrainConfig, args)
    gen, imp = train_joint(cfg)
    print(f"generator: {gen.resolve()}\nimprovement model: {imp.resolve()}")
    return 0


def cmd_blend(args: argparse.Namespace) -> int:
    from prosplat.train.blend import blend_files

    try:
        path = blend_files(
            args.a, args.b, args.weight, args.out, overwrite=args.overwrite,
            fill_input=args.fill_input,
        )  # fmt: skip
    except (ValueError, FileExistsError) as e:
        print(f"prosplat train blend: {e}", file=sys.stderr)
        return 2
    print(f"blended improvement model: {path.resolve()}")
    return 0


def cmd_eval_improve(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from prosplat.data import find_scenes, load_scene
    from prosplat.eval.generator import write_scores
    from prosplat.eval.improve import Row, evaluate_rows
    from prosplat.improve.io import load_improver
    from prosplat.pipeline.model import ProSplat

    gen = ProSplat.from_pretrained(args.generator, improve=False)
    rows = {"generator only": Row(gen)}
    for spec in args.row:
        label, _, path = spec.rpartition("=")  # labels may hold "=", paths rarely do
        method = "paper"
        head, _, tail = path.rpartition(":")
        if tail in ("paper", "overlap"):  # a trailing :METHOD, not a drive letter
            path, method = head, tail
        if not label or not path:
            print(
                f"prosplat eval improve: --row {spec!r} is not LABEL=PATH[:paper|overlap]",
                file=sys.stderr,
            )
            return 2
        generator = gen
        if "+" in path:  # joint rows: GENERATOR+IMPROVER
            g_path, path = path.split("+", 1)
            generator = ProSplat.from_pretrained(g_path, improve=False)
        rows[label] = Row(generator, load_improver(path), method)
    dtype = torch.bfloat16 if args.bf16 else torch.float32
    scores = []
    for folder in tqdm(find_scenes(args.data)[: args.scenes], desc="ablation", unit="scene"):
        # depth maps only for the true-depth row; scenes without them skip that row
        depth = "true-depth" in args.references and (folder / "depth").is_dir()
        scene = load_scene(folder, load_depth=depth)
        scores += evaluate_rows(scene, rows, args.views, dtype, args.references)
    return write_scores(scores, args.out)


def add_train_parsers(train_sub) -> None:
    """``train curate|improve|joint|blend`` into the ``train`` subparsers."""
    cu = train_sub.add_parser(
        "curate",
        help="render curated stage-2 samples with a trained generator",
        description="For every scene under --data and every input-view count in --views, "
        "reconstruct with the generator, render each target view, and store the render, "
        "the MORI reference (paper score and geometric overlap) with its fundamental "
        "matrix, and the ground truth in one safetensors file (a cache: not committed).",
    )
    cu.add_argument(
        "--data",
        required=True,
        help="dataset folder of rendered scenes, or scene packs (.npz, `prosplat scenes pack`, "
        "depth not needed), comma-separated",
    )
    cu.add_argument("--out", required=True, help="curated file to write (.safetensors)")
    cu.add_argument("--generator", default=None,
                    help="generator checkpoint (default: shipped); a DepthSplat .pth (released or "
                    "fine-tuned by train generator --init) curates its renders")  # fmt: skip
    cu.add_argument(
        "--views", default="2,4", help="input-view counts, comma-separated (default 2,4)"
    )
    cu.add_argument(
        "--refine-steps",
        type=int,
        default=0,
        help="render refined scenes: N steps of prosplat.pipeline.refine after the automatic budget "
        "(default 0: the generator's raw Gaussians)",
    )
    cu.add_argument(
        "--splat-scale",
        type=float,
        default=1.0,
        help="render the Gaussians with their scales multiplied by this (default 1; "
        "prosplat.pipeline.enhance.SPLAT_SCALE for a model that enhances smaller splats)",
    )
    cu.add_argument(
        "--max-splat-radius",
        type=float,
        default=MAX_SPLAT_RADIUS,
        help="each target view leaves out the splats it would draw wider than this fraction of "
        f"its shorter side, as enhanced views do (default {MAX_SPLAT_RADIUS:g}, "
        "prosplat.pipeline.enhance.MAX_SPLAT_RADIUS; 0: draw every splat)",
    )
    cu.add_argument(
        "--other-views-opacity",
        type=float,
        default=OTHER_VIEWS_OPACITY,
        help="each target's render favours the input MORI picks for it, the other views' "
        "Gaussians entering the colour at up to this fraction of their opacity, less the "
        "farther they are, as every view does at inference (default "
        f"{OTHER_VIEWS_OPACITY:g}, prosplat.pipeline.enhance.OTHER_VIEWS_OPACITY; 1: all alike, as "
        "sets curated before 2026-11-28 were; sets curated on 2026-11-28 used a constant)",
    )
    cu.add_argument(
        "--size",
        type=int,
        default=None,
        help="resize the views to this height first (e.g. 64 from 128-px scenes; default: as "
        "rendered)",
    )
    cu.add_argument(
        "--generator-size",
        type=int,
        default=None,
        help="run the generator at most this high and render at the views' size (default: "
        "the weights' trained size, 64 for the shipped ones, as the pipeline runs it; 0: the "
        "views' size)",
    )
    cu.add_argument("--first", type=int, default=0, help="skip the first N scenes (sorted)")
    cu.add_argument(
        "--count",
        type=int,
        default=None,
        help="curate at most N scenes: processes sharing a set each take a slice, and "
        "`train improve --data a,b,...` takes the files together",
    )
    cu.add_argument(
        "--depth-sweep",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="move the generator's depth to where the inputs match first, as the pipeline "
        "does (prosplat.pipeline.depth_sweep; on by default for prosplat weights); "
        "--no-depth-sweep renders the generator's own depth, as sets curated before "
        "2026-11-26 were",
    )
    cu.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    cu.set_defaults(func=cmd_curate)

    ti = train_sub.add_parser(
        "improve",
        help="train the stage-2 improvement model on a curated set",
        description="Independent stage-2 training (MSE + 5 LPIPS) on a file from `prosplat train "
        "curate`. --no-denoise / --no-reference give the ablation rows. Re-running with "
        "the same --out resumes; several GPUs: torchrun --nproc_per_node K -m prosplat "
        "train improve ... With --recipe NAME, the stages of a shipped weight's recipe "
        "instead (prosplat train recipes lists them).",
    )
    add_config_arguments(ti, ImproveTrainConfig, optional=("data", "out"))
    recipes.add_recipe_arguments(ti, "improve")
    ti.set_defaults(func=cmd_train_improve)

    tj = train_sub.add_parser(
        "joint",
        help="jointly fine-tune generator adapter + improvement VAE",
        description="Joint training: the generator frozen but its Gaussian adapter, the "
        "improvement model frozen but its VAE encoder (and decoder unless --no-train-decoder); "
        "loss summed over the target views of one forward pass.",
    )
    add_config_arguments(tj, JointTrainConfig)
    tj.set_defaults(func=cmd_train_joint)

    bl = train_sub.add_parser(
        "blend",
        help="interpolate the weights of two fine-tunes of one improvement model",
        description="Write (1 - W) * A + W * B, weight by weight, for two improvement models "
        "with the same architecture (fine-tunes from the same start; prosplat.train.blend): "
        "a trade between them, e.g. LPIPS against flicker, set without training.",
    )
    bl.add_argument("a", help="improvement-model checkpoint A (its working size is kept)")
    bl.add_argument("b", help="improvement-model checkpoint B")
    bl.add_argument("--weight", type=float, required=True, help="B's share, in [0, 1]")
    bl.add_argument("--out", required=True, help="checkpoint to write (.safetensors)")
    bl.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    bl.add_argument(
        "--fill-input",
        action="store_true",
        help="load both as models that see the filled render (ImproveConfig.fill_input), so "
        "a --fill fine-tune blends with the model it started from",
    )
    bl.set_defaults(func=cmd_blend)


def add_eval_parser(ev_sub) -> None:
    ei = ev_sub.add_parser(
        "improve",
        help="the stage-2 ablation (Table IV) in one run",
        description="Score 'generator only' and every --row LABEL=IMPROVER[:paper|overlap] "
        "(or LABEL=GENERATOR+IMPROVER for jointly trained pairs) on the same scenes, "
        "input views and targets; one table per view count and target kind.",
    )
    ei.add_argument("--data", type=Path, required=True, help="test dataset folder")
    ei.add_argument("--generator", default=None, help="generator checkpoint (default: shipped)")
    ei.add_argument("--row", action="append", default=[], help="LABEL=PATH[:paper|overlap]")
    ei.add_argument("--views", type=int, nargs="+", default=[2, 4, 6], help="input-view counts")
    ei.add_argument(
        "--references",
        nargs="*",
        default=["flat", "paste", "true-depth"],
        choices=["flat", "paste", "true-depth"],
        help="ladder reference rows on the same targets (default all; none: --references)",
    )
    ei.add_argument("--scenes", type=int, default=None, help="only the first N scenes")
    ei.add_argument("--bf16", action="store_true", help="run stage 2 under bfloat16 autocast")
    ei.add_argument("--out", type=Path, default=Path("out/eval-improve"), help="where scores go")
    ei.set_defaults(func=cmd_eval_improve)
