"""``prosplat eval ladder``: every rung of the evaluation ladder on rendered test scenes.

For each evaluation size and input-view count, every scene's chosen inputs are reconstructed
once per rung and every target is scored (whole image and valid region). Prints the ladder and
writes ``ladder.md``, ``ladder.csv`` (the summary), ``ladder.json`` (settings, every
per-target score and the summary) and ``speed.png`` (time per view against PSNR) into a fresh
folder at ``--out`` (``OUT-2``, ... when it holds results, unless ``--overwrite``).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

#: the rows run by default (per-scene optimisation joins when --opt-steps is given)
DEFAULT_ROWS = (
    "flat", "paste", "optimize", "generator", "enhanced", "fill", "splat", "cull", "favour", "warp",
    "refine", "distill", "true-depth", "depthsplat",
)  # fmt: skip
#: rows that run only when named: the cross-view check (not shipped) and stage 2's change
#: carried onto the render on black (the way before 2026-11-29)
OPT_IN_ROWS = ("consistent", "carry")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, nargs="+", required=True,
                        help="dataset folders (or scene folders) rendered by prosplat scenes render")  # fmt: skip
    parser.add_argument("--sizes", type=int, nargs="+", default=[64],
                        help="evaluation heights in px, e.g. 540 for 960x540 scenes (default 64); the "
                        "generator runs at its own size, so only --generator-size 0 needs "
                        "multiples of 32")  # fmt: skip
    parser.add_argument("--views", type=int, nargs="+", default=[4],
                        help="input-view counts, 2-6 (default 4)")  # fmt: skip
    parser.add_argument("--rows", nargs="+", default=list(DEFAULT_ROWS),
                        help=f"ladder rows to run, from {', '.join(DEFAULT_ROWS)} (default all of these) "
                        f"and {', '.join(OPT_IN_ROWS)}")  # fmt: skip
    parser.add_argument("--opt-steps", type=int, nargs="*", default=[],
                        help="per-scene optimisation step counts, e.g. 300 1000 (slow; default none)")  # fmt: skip
    parser.add_argument("--refine-steps", type=int, nargs="*", default=[],
                        help="refinement step counts, e.g. 100 300: rows 'refine N' (+ enhanced)")  # fmt: skip
    parser.add_argument("--refine-seconds", type=float, nargs="*", default=[],
                        help="refinement time budgets in seconds, e.g. 10: rows 'refine S s'")  # fmt: skip
    parser.add_argument("--distill-steps", type=int, nargs="*", default=[],
                        help="distillation step counts, e.g. 400 800: rows 'distill N': "
                        "every target enhanced, then the Gaussians refined against the inputs and "
                        "them (prosplat.pipeline.distill)")  # fmt: skip
    parser.add_argument("--splat-scales", type=float, nargs="*", default=[],
                        help="the generator's Gaussians drawn at these multiples of their "
                        "scales in filled and enhanced views, e.g. 0.5: rows 'generator filled "
                        "×S', 'enhanced ×S', 'enhanced filled ×S'")  # fmt: skip
    parser.add_argument("--max-splat-radius", type=float, nargs="*", default=[],
                        help="with the 'cull' rows: leave out the splats a target would see "
                        "wider than these fractions of its shorter side, e.g. 0.1: rows "
                        "'generator filled ≤R', 'enhanced ≤R'")  # fmt: skip
    parser.add_argument("--other-views-opacity", type=float, nargs="*", default=[],
                        help="with the 'favour' rows: the views drawn with the other input "
                        "views' Gaussians at up to these fractions of their opacity in the "
                        "colour, falling with distance (the input MORI picks at full), e.g. 1 "
                        "for all alike: rows 'generator filled ◇W', 'enhanced ◇W', 'enhanced "
                        "filled ◇W'")  # fmt: skip
    parser.add_argument("--generator", default=None, help="generator checkpoint (default shipped)")
    parser.add_argument("--generator-size", type=int, default=None,
                        help="run the generator at most this high (px, a multiple of 32; default: "
                        "the size its weights were trained at, 128 for the shipped ones; 0: the "
                        "evaluation size); its Gaussians render at the evaluation size")  # fmt: skip
    parser.add_argument("--low-res-gaussians", action="store_true",
                        help="the generator's Gaussians at the size it runs at, not at the "
                        "evaluation size (the pipeline before 2026-11-24; ProSplat.full_res_gaussians)")  # fmt: skip
    parser.add_argument("--no-depth-sweep", action="store_true",
                        help="the generator's depth as it predicts it, without the local plane "
                        "sweep that moves it to where the inputs match (prosplat.pipeline.depth_sweep; "
                        "on by default for prosplat generators)")  # fmt: skip
    parser.add_argument("--depth-edges", choices=("drop", "snap", "off"), default=None,
                        help="the Gaussians of pixels inside a depth ramp between two surfaces "
                        "(a curtain) are dropped, snapped onto the nearer surface, or left "
                        "(prosplat.geometry.depth_edges; default: the model's own)")  # fmt: skip
    parser.add_argument("--gaussian-scale", type=float, default=None,
                        help="Gaussians at most this many times the generator's matching "
                        "height (default: ProSplat.max_gaussian_scale)")  # fmt: skip
    parser.add_argument("--improve", default=None,
                        help="improvement-model checkpoint (default shipped)")  # fmt: skip
    parser.add_argument("--compare-improve", action="append", default=[], metavar="LABEL=PATH",
                        help="another improvement model scored on the same reconstructions: "
                        "rows 'enhanced (LABEL)' etc. (repeatable)")  # fmt: skip
    parser.add_argument("--depthsplat", default=None, help="DepthSplat checkpoint (optional row)")
    parser.add_argument("--budget", type=float, default=None,
                        help="generator Gaussian budget: a count or a fraction (default automatic)")  # fmt: skip
    parser.add_argument("--bf16", action="store_true", help="stage 2 under bfloat16 autocast")
    parser.add_argument("--scenes", type=int, default=None, help="at most N scenes per folder")
    parser.add_argument("--seed", type=int, default=0, help="bootstrap seed (default 0)")
    parser.add_argument("--resample", choices=["targets", "scenes"], default="targets",
                        help="what the bootstrap draws: targets (default) or whole scenes")  # fmt: skip
    parser.add_argument("--out", type=Path, default=Path("out/ladder"), help="output folder")
    parser.add_argument("--overwrite", action="store_true", help="replace earlier results in --out")


def _check(args: argparse.Namespace) -> None:
    if bad := [s for s in args.sizes if s < 32]:
        raise ValueError(f"--sizes: {bad} are below 32 px")
    if args.generator_size == 0 and (bad := [s for s in args.sizes if s % 32]):
        raise ValueError(
            f"--sizes: {bad} are not multiples of 32 (the generator's stride), which "
            "--generator-size 0 (the generator at the evaluation size) needs"
        )
    if bad := [v for v in args.views if not 2 <= v <= 6]:
        raise ValueError(f"--views: {bad} outside 2-6 input views")
    if bad := [s for s in args.opt_steps if s < 1]:
        raise ValueError(f"--opt-steps: {bad} must be >= 1")
    if bad := [s for s in args.refine_steps if s < 1]:
        raise ValueError(f"--refine-steps: {bad} must be >= 1")
    if bad := [s for s in args.distill_steps if s < 1]:
        raise ValueError(f"--distill-steps: {bad} must be >= 1")
    if bad := [r for r in args.max_splat_radius if not 0 < r < float("inf")]:
        raise ValueError(f"--max-splat-radius: {bad} must be finite and > 0")
    if bad := [w for w in args.other_views_opacity if not 0 <= w <= 1]:
        raise ValueError(f"--other-views-opacity: {bad} must lie in [0, 1]")
    if bad := [s for s in args.splat_scales if not 0 < s < float("inf")]:
        raise ValueError(f"--splat-scales: {bad} must be finite and > 0")
    if bad := [s for s in args.refine_seconds if not s > 0]:
        raise ValueError(f"--refine-seconds: {bad} must be > 0")
    if args.generator_size and (args.generator_size < 32 or args.generator_size % 32):
        raise ValueError(f"--generator-size {args.generator_size} is not a multiple of 32")
    if args.budget is not None and not args.budget > 0:
        raise ValueError(f"--budget must be a count or a fraction in (0, 1], got {args.budget}")


def _commit() -> str:
    try:
        root = Path(__file__).resolve().parents[3]
        out = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, timeout=10)  # fmt: skip
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10)  # fmt: skip
        return out.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "") or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _machine() -> str:
    """The CPU's model name and core count (and the GPU when one is used), for the report."""
    import os

    import torch

    from prosplat.eval.bench.machine import cpu_name

    cpu = cpu_name()
    gpu = f", {torch.cuda.get_device_name()}" if torch.cuda.is_available() else ", no GPU"
    return f"{cpu}, {os.cpu_count()} cores{gpu}"


def command(args: argparse.Namespace) -> str:
    """The command line that reproduces this run (from the parsed options, not sys.argv, so
    it is right when called from Python too)."""
    parts = ["prosplat eval ladder", "--data", *map(str, args.data)]
    parts += ["--sizes", *map(str, args.sizes), "--views", *map(str, args.views)]
    if list(args.rows) != list(DEFAULT_ROWS):
        parts += ["--rows", *args.rows]
    for flag in (
        "opt_steps", "refine_steps", "refine_seconds", "distill_steps", "splat_scales",
        "max_splat_radius", "other_views_opacity",
    ):  # fmt: skip
        if getattr(args, flag):
            parts += [f"--{flag.replace('_', '-')}", *(f"{v:g}" for v in getattr(args, flag))]
    for flag in (
        "generator", "generator_size", "improve", "depthsplat", "budget", "scenes",
        "depth_edges", "gaussian_scale",
    ):  # fmt: skip
        if getattr(args, flag) is not None:
            parts += [f"--{flag.replace('_', '-')}", str(getattr(args, flag))]
    for spec in args.compare_improve:
        parts += ["--compare-improve", spec]
    if args.bf16:
        parts.append("--bf16")
    if args.low_res_gaussians:
        parts.append("--low-res-gaussians")
    if getattr(args, "no_depth_sweep", False):
        parts.append("--no-depth-sweep")
    if args.resample != "targets":
        parts += ["--resample", args.resample]
    return " ".join(parts + ["--out", str(args.out)])


def run(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from prosplat.core.paths import fresh_folder, staged_folder
    from prosplat.data import find_scenes, load_scene
    from prosplat.eval.ladder import report
    from prosplat.eval.ladder.run import evaluate_scene, warm_up
    from prosplat.eval.ladder.rungs import LadderContext, build_rungs
    from prosplat.geometry.budget import budget_arg

    def fail(message: str) -> int:
        print(f"prosplat eval ladder: {message}", file=sys.stderr)
        return 2

    try:
        _check(args)
        folders = []
        for root in args.data:
            found = find_scenes(root)[: args.scenes]
            if not found:
                raise FileNotFoundError(f"no scene folders in {root} (no */transforms.json)")
            folders += found
        options = dict(vars(args), budget=budget_arg(args.budget))
        rungs = build_rungs(args.rows, LadderContext(options), log=print)
        if not rungs:
            raise ValueError("no ladder row can run")
        scenes = [load_scene(f) for f in folders]
        for scene in scenes:  # every scene fits every setting, before any work
            if (h := scene.images.shape[-2]) < max(args.sizes):
                raise ValueError(
                    f"{scene.folder} is {h} px high, cannot evaluate at {max(args.sizes)} px; "
                    "lower --sizes"
                )
            if (n := len(scene.input_indices)) < max(args.views):
                raise ValueError(
                    f"{scene.folder} has {n} input views, cannot evaluate {max(args.views)}; "
                    "lower --views"
                )
            if scene.depths is None or not scene.target_indices:
                raise ValueError(f"{scene.folder} needs depth maps and target views")
    except (ValueError, FileNotFoundError) as e:
        return fail(str(e))
    started = time.perf_counter()
    commit = _commit()  # the code that runs, taken before a long run (the tree may move on)
    scores = []
    for size in args.sizes:
        for views in args.views:
            warm_up(scenes[0], rungs, views, size)
            bar = tqdm(scenes, desc=f"ladder {size} px, {views} views", unit="scene")
            for scene in bar:
                scores += evaluate_scene(scene, rungs, views, size)
    by_scene = args.resample == "scenes"
    summary = report.summarise(scores, seed=args.seed, by_scene=by_scene)
    deltas = report.paired_deltas(scores, seed=args.seed, by_scene=by_scene)
    machine = _machine()
    meta = dict(
        command=command(args),
        commit=commit,
        machine=machine,
        torch=torch.__version__,
        threads=torch.get_num_threads(),
        seconds=round(time.perf_counter() - started, 1),
        rows=[r.name for r in rungs],
        scenes=[str(f) for f in folders],
        args={k: str(v) for k, v in vars(args).items() if k != "func"},
    )
    table = report.markdown(summary, deltas, by_scene)
    header = (
        f"# Evaluation ladder\n\n`{command(args)}` at commit "
        f"{meta['commit']} on {machine} (torch {meta['torch']}, {meta['threads']} threads), "
        f"{meta['seconds']:.0f} s.\n\n"
    )
    out = fresh_folder(args.out, args.overwrite)
    with staged_folder(out) as partial:  # moved to --out only when complete
        (partial / "ladder.md").write_text(header + table)
        report.write_csv(summary, partial / "ladder.csv")
        report.write_json(scores, summary, meta, partial / "ladder.json", deltas)
        report.plot(summary, partial / "speed.png", f"evaluation ladder ({machine})")
    print(table)
    print(f"wrote {out / 'ladder.md'}, ladder.csv, ladder.json and speed.png")
    return 0
