"""``prosplat eval generator|improve|posed|ladder``: models scored on rendered test scenes
or posed sets, beside the ladder's reference rows."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from prosplat.cli import eval_posed, improve
from prosplat.cli.options import add_refine_arguments
from prosplat.eval import posed
from prosplat.eval.ladder import cli as ladder_cli


def cmd_eval_generator(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from prosplat.data import find_scenes, load_scene
    from prosplat.eval import generator as evaluate
    from prosplat.geometry.budget import budget_arg
    from prosplat.pipeline.model import ProSplat
    from prosplat.pipeline.refine import check_refine_args

    methods = {}
    budget = budget_arg(args.budget)
    try:
        check_refine_args(args.refine_steps, args.refine_seconds)
    except ValueError as e:
        print(f"prosplat eval generator: {e}", file=sys.stderr)
        return 2
    if not args.no_generator:
        model = ProSplat.from_pretrained(args.weights, improve=False)
        methods["generator"] = evaluate.generator_method(model)
        for steps in args.refine_steps:
            methods[evaluate.refine_label(steps=steps)] = evaluate.refine_method(
                model, steps=steps, budget=budget
            )
        for secs in args.refine_seconds:
            methods[evaluate.refine_label(seconds=secs)] = evaluate.refine_method(
                model, seconds=secs, budget=budget
            )
    if args.generator is not None:  # the ladder's "DepthSplat (user weights)" row
        ds = ProSplat.from_pretrained(generator=args.generator, improve=False)
        methods["DepthSplat (user weights)"] = evaluate.generator_method(ds)
    if "plane_sweep" in args.baselines:
        methods["plane sweep"] = evaluate.plane_sweep_method()
    if "optimize" in args.baselines:
        for steps in args.opt_steps:
            methods[f"3DGS opt {steps}"] = evaluate.optimize_method(steps)
    refs = args.references
    if not methods and not refs:
        print("prosplat eval generator: nothing to evaluate", file=sys.stderr)
        return 2
    folders = find_scenes(args.data)[: args.scenes]
    rows = []
    for folder in tqdm(folders, desc="evaluating scenes", unit="scene"):
        scene = load_scene(folder)
        rows += evaluate.evaluate_scene(scene, methods, args.views, budget=budget, references=refs)
    return evaluate.write_scores(rows, args.out)


def add_parser(sub) -> None:
    """``prosplat eval ...`` into the top-level subparsers ``sub``."""
    ev = sub.add_parser("eval", help="evaluate models on rendered test scenes or posed sets")
    ev_sub = ev.add_subparsers(dest="eval_command", required=True)
    eg = ev_sub.add_parser(
        "generator",
        help="PSNR/SSIM/LPIPS, depth AbsRel and timings of the generator and baselines",
        description="Evaluate the generator (and baselines in the same run) on scene folders: "
        "for each input-view count, reconstruct from that many of each scene's input "
        "views, render its targets, and print one table per view count and target "
        "kind (interpolation / extrapolation).",
    )
    eg.add_argument("--data", type=Path, required=True, help="test dataset folder")
    eg.add_argument("--weights", default=None, help="generator checkpoint (default: shipped)")
    eg.add_argument(
        "--generator",
        type=Path,
        default=None,
        help="also evaluate a DepthSplat checkpoint (depthsplat-gs-*.pth, README 'DepthSplat "
        "weights') as the row 'DepthSplat (user weights)'",
    )
    eg.add_argument("--views", type=int, nargs="+", default=[2, 4, 6], help="input-view counts")
    eg.add_argument(
        "--baselines",
        nargs="*",
        default=["plane_sweep", "optimize"],
        choices=["plane_sweep", "optimize"],
        help="baselines to run in the same table",
    )
    eg.add_argument(
        "--opt-steps",
        type=int,
        nargs="+",
        default=[300, 1000, 3000],
        help="step counts of the per-scene 3DGS optimisation baseline",
    )
    eg.add_argument(
        "--budget",
        type=float,
        default=None,
        help="Gaussian budget: a count (>1) or a fraction (<=1); default: automatic",
    )
    eg.add_argument(
        "--references",
        nargs="*",
        default=["flat", "paste", "true-depth"],
        choices=["flat", "paste", "true-depth"],
        help="ladder reference rows on the same targets (flat colour, MORI paste, Gaussians "
        "at the true input depth; default all; none: --references)",
    )
    add_refine_arguments(eg, many=True)
    eg.add_argument("--scenes", type=int, default=None, help="evaluate only the first N scenes")
    eg.add_argument("--no-generator", action="store_true", help="baselines only")
    eg.add_argument("--out", type=Path, default=Path("out/eval"), help="where scores go")
    eg.set_defaults(func=cmd_eval_generator)
    improve.add_eval_parser(ev_sub)
    ep = ev_sub.add_parser(
        "posed",
        help="score flat / paste / generator / enhanced on the held-out frames of a posed set",
        description=posed.__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    eval_posed.add_arguments(ep)
    ep.set_defaults(func=eval_posed.run)
    el = ev_sub.add_parser(
        "ladder",
        help="every ladder row (flat, paste, optimisation, generator, enhanced, true depth) "
        "with intervals, per family / overlap bin / target kind",
        description=ladder_cli.__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ladder_cli.add_arguments(el)
    el.set_defaults(func=ladder_cli.run)
