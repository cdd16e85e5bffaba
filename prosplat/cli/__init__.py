"""The ``prosplat`` command line. Each subcommand documents itself (``prosplat CMD --help``)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from prosplat.core.paths import fresh_folder

# Moved to prosplat.core.paths (bench/, demo and the ladder import it from there, not from the CLI
# that imports them); the old name stays for code written against it.
_fresh_folder = fresh_folder


def cmd_demo(args: argparse.Namespace) -> int:
    from prosplat.cli.demo import DemoConfig, run_demo

    cfg = DemoConfig(
        out=args.out,
        scene=args.scene,
        seed=args.seed,
        size=args.size,
        render_scale=args.render_scale,
        inputs=args.inputs,
        targets=args.targets,
        samples=args.samples,
        budget=args.budget,
        bf16=args.bf16,
        refine_steps=args.refine_steps,
        refine_seconds=args.refine_seconds,
        weights=args.weights,
        generator=args.generator,
        improve=args.improve,
        overwrite=args.overwrite,
    )
    try:
        cfg.check()
        result = run_demo(cfg)
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"prosplat demo: {e}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as e:
        print(
            f"prosplat demo: {e.name} is missing; `make demo` installs everything "
            "(pip install -e '.[blender,bench]')",
            file=sys.stderr,
        )
        return 2
    from prosplat.cli.demo_report import summary_rows

    total = summary_rows(result.views)[-1]
    raw = "refined" if cfg.refine_steps or cfg.refine_seconds is not None else "generator"
    print(
        f"PSNR over {total['n']} new views: {raw} (holes filled) {total['psnr_raw']:.2f} dB -> "
        f"enhanced "
        f"{total['psnr_enhanced']:.2f} dB; LPIPS {total['lpips_raw']:.3f} -> "
        f"{total['lpips_enhanced']:.3f}; demo took {result.timings['total']:.0f} s"
    )
    print(f"report: {(result.out / 'report.md').resolve()}")
    return 0


def render_worker_command(args: argparse.Namespace) -> list[str]:
    """The command line of one long-lived Blender worker of ``prosplat scenes render``: Cycles
    gets ``--threads`` threads, by default the machine's cores shared by the workers."""
    import os

    threads = args.threads or max(1, (os.cpu_count() or 1) // args.workers)
    return [
        sys.executable,
        "-m",
        "scenes.render",
        "--jobs-from-stdin",
        "--out",
        str(args.out),
        "--size",
        str(args.size),
        "--inputs",
        str(args.inputs),
        "--targets",
        str(args.targets),
        "--samples",
        str(args.samples),
        "--threads",
        str(threads),
    ] + (["--denoise", "--denoise-quality", args.denoise_quality] if args.denoise else [])


def cmd_scenes_render(args: argparse.Namespace) -> int:
    """Render scenes ``seed .. seed+count-1`` with ``--workers`` long-lived Blender processes
    (``scenes.render --jobs-from-stdin``), each fed the next missing scene as it finishes one."""
    import subprocess
    import threading
    from queue import Empty, Queue

    from tqdm import tqdm

    from prosplat.data.splits import family_for_seed, split_of
    from scenes.jobs import read_answer

    if args.count < 1 or args.workers < 1 or args.size < 8 or args.samples < 1:
        print(
            "prosplat scenes render: --count, --workers, --samples must be >= 1 and --size >= 8",
            file=sys.stderr,
        )
        return 2
    if args.threads is not None and args.threads < 1:
        print("prosplat scenes render: --threads must be >= 1", file=sys.stderr)
        return 2
    if args.denoise_quality != "high" and not args.denoise:
        print("prosplat scenes render: --denoise-quality needs --denoise", file=sys.stderr)
        return 2
    for s in (args.seed, args.seed + args.count - 1):
        split_of(s)  # raises with the valid range for seeds outside every split
    jobs = []
    for seed in range(args.seed, args.seed + args.count):
        name = args.scene or family_for_seed(seed)
        if (args.out / f"{name}_{seed:06d}").is_dir():
            continue  # complete: folders only appear when finished
        jobs.append((name, seed))
    skipped = args.count - len(jobs)
    if skipped:
        print(f"{skipped} of {args.count} scenes already rendered in {args.out}; skipping them")
    if not jobs:
        return 0
    cmd = render_worker_command(args)
    queue: Queue = Queue()
    for job in jobs:
        queue.put(job)
    failures: list[tuple[str, int, list[str]]] = []
    bar = tqdm(total=len(jobs), desc="rendering scenes", unit="scene")
    lock = threading.Lock()
    stop = threading.Event()  # Ctrl-C: no worker takes another scene

    def worker() -> None:
        """One long-lived Blender process fed scene after scene (start-up paid once); a
        process that dies fails its current scene and is replaced for the next."""
        proc = None
        while not stop.is_set():
            try:
                name, seed = queue.get_nowait()
            except Empty:
                break
            if proc is None:
                proc = subprocess.Popen(
                    cmd,
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    stderr=subprocess.STDOUT,
                    text=True,
                )
            proc.stdin.write(f"{name} {seed}\n")
            proc.stdin.flush()
            answer, tail = read_answer(proc.stdout)
            if answer is None:  # the process died mid-scene: a fresh one takes the next
                answer = {"error": tail + [f"(the Blender worker exited with {proc.wait()})"]}
                proc = None
            with lock:
                if "folder" not in answer:
                    failures.append((name, seed, answer.get("error", [])))
                bar.update()
        if proc is not None:
            proc.stdin.close()
            proc.wait()

    feeders = [
        threading.Thread(target=worker, daemon=True) for _ in range(min(args.workers, len(jobs)))
    ]
    for t in feeders:
        t.start()
    try:
        for t in feeders:
            t.join()
    except KeyboardInterrupt:
        # the terminal's SIGINT reaches the Blender workers too: each removes its half-made
        # scene folder and exits; a worker stopped otherwise ends when its stdin closes
        stop.set()
        raise
    bar.close()
    for name, seed, tail in failures:
        print(f"scene {name} seed {seed} failed:\n  " + "\n  ".join(tail), file=sys.stderr)
    print(
        f"rendered {len(jobs) - len(failures)} scenes into {args.out.resolve()}"
        + (f"; {len(failures)} failed (re-run the same command to retry them)" if failures else "")
    )
    return 1 if failures else 0


def cmd_scenes_list(args: argparse.Namespace) -> int:
    """One line per scene folder: split, family, tags, views and input overlap (for binning)."""
    import json

    from prosplat.data.dataset import find_scenes

    folders = find_scenes(args.out)
    if not folders:
        print(f"no scene folders in {args.out}", file=sys.stderr)
        return 1
    print(
        "| scene | split | family | tags | inputs | targets (interp/extrap) | mean input overlap | near | far |"
    )
    print("|---|---|---|---|---:|---|---:|---:|---:|")
    for folder in folders:
        meta = json.loads((folder / "transforms.json").read_text())
        frames = meta["frames"]
        n_in = sum(f.get("split") == "input" for f in frames)
        kinds = [f.get("target_kind") for f in frames if f.get("split") == "target"]
        print(
            f"| {folder.name} | {meta.get('split_set', '?')} | {meta.get('family', '?')} | "
            f"{','.join(meta.get('tags', [])) or '-'} | {n_in} | {len(kinds)} "
            f"({kinds.count('interpolation')}/{kinds.count('extrapolation')}) | "
            f"{meta.get('mean_input_overlap', float('nan')):.2f} | {meta['near']:.3g} | {meta['far']:.3g} |"
        )
    return 0


def _int_between(lo: int, hi: int):
    """An argparse type: a whole number in [lo, hi], refused with a one-line usage error."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be {lo}-{hi}, got {value}")
        return value

    return parse


def cmd_scenes_pack(args: argparse.Namespace) -> int:
    """Pack scene folders into size-bounded .npz files (:mod:`prosplat.data.packed`)."""
    from tqdm import tqdm

    from prosplat.data.dataset import find_scenes
    from prosplat.data.packed import pack_scenes

    folders = find_scenes(args.data)[args.first :]
    if args.count is not None:
        folders = folders[: args.count]
    if not folders:
        print(f"prosplat scenes pack: no scene folders under {args.data}", file=sys.stderr)
        return 2
    # estimate the scenes per pack from the first one, then fill each pack up to the bound
    depth = not args.no_depth
    probe_path = args.out.with_name(f".{args.out.name}.probe.npz")
    opts = dict(depth=depth, jpeg_quality=args.jpeg_quality, depth_bits=args.depth_bits)
    probe = pack_scenes(folders[:1], probe_path, True, **opts)
    per_scene = probe.stat().st_size
    probe.unlink()
    per_pack = max(1, int(args.max_mb * 2**20 * 0.9 // per_scene))
    chunks = [folders[i : i + per_pack] for i in range(0, len(folders), per_pack)]
    for i, chunk in enumerate(tqdm(chunks, desc="packing", unit="pack")):
        path = args.out.with_name(f"{args.out.name}_{i:03d}.npz")
        pack_scenes(chunk, path, **opts)
        print(f"{path}: {len(chunk)} scenes, {path.stat().st_size / 2**20:.1f} MB")
    return 0


def cmd_train_generator(args: argparse.Namespace) -> int:
    from dataclasses import fields

    from prosplat.train.generator import TrainConfig, train

    cfg = TrainConfig(**{f.name: getattr(args, f.name) for f in fields(TrainConfig)})
    path = train(cfg)
    if int(os.environ.get("RANK", "0")) == 0:  # once, not once per torchrun process
        print(f"checkpoint: {path.resolve()}")
        if path.suffix == ".pth":  # a DepthSplat fine-tune
            print(f"use it with: prosplat reconstruct --generator {path.resolve()} ...")
    return 0


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


def add_refine_arguments(parser: argparse.ArgumentParser, many: bool = False) -> None:
    """``--refine-steps`` / ``--refine-seconds``: fit the generator's Gaussians to the inputs
    (prosplat.pipeline.refine) for a step count or a time budget; ``many``: one row per value."""
    if many:
        parser.add_argument(
            "--refine-steps",
            type=int,
            nargs="*",
            default=[],
            help="add a 'generator+refine N' row per step count (refinement after the budget)",
        )
        parser.add_argument(
            "--refine-seconds",
            type=float,
            nargs="*",
            default=[],
            help="add a 'generator+refine Ss' row per time budget in seconds",
        )
        return
    from prosplat.pipeline.refine import RECOMMENDED_STEPS

    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--refine-steps",
        type=int,
        nargs="?",
        const=RECOMMENDED_STEPS,
        default=0,
        metavar="N",
        help="refine the Gaussians against the inputs for N steps after the budget (default 0: "
        f"off; the bare flag: {RECOMMENDED_STEPS}, the measured knee; README, 'Refinement')",
    )
    group.add_argument(
        "--refine-seconds",
        type=float,
        default=None,
        help="refine for this many seconds instead of a step count",
    )


def add_bench_parsers(sub) -> None:
    """``prosplat bench points`` (speed against error) and ``prosplat bench hard`` (hard cases);
    the options live beside their engines in :mod:`prosplat.eval.bench`."""
    from prosplat.eval.bench import hard, points

    bench = sub.add_parser("bench", help="speed against error, and the hard-case suite")
    bench_sub = bench.add_subparsers(dest="bench_command", required=True)
    for name, module, text in (
        ("points", points, "time per view against PSNR/SSIM/LPIPS over operating points"),
        ("hard", hard, "the whole pipeline on hard cases: finite outputs or clear errors"),
    ):
        p = bench_sub.add_parser(name, help=text, description=module.__doc__)
        p.formatter_class = argparse.RawDescriptionHelpFormatter
        module.add_arguments(p)
        p.set_defaults(func=module.run)


def add_posed_parsers(sub, eval_sub=None) -> None:
    """``prosplat reconstruct`` (into ``sub``) or ``prosplat eval posed`` (into ``eval_sub``):
    your own posed images; options live beside their engines."""
    from prosplat.cli import reconstruct
    from prosplat.eval import posed as evaluate_posed

    if eval_sub is None:
        name, module, parent = "reconstruct", reconstruct, sub
        text = "your own posed images (transforms.json, COLMAP) -> Gaussians + enhanced renders"
    else:
        name, module, parent = "posed", evaluate_posed, eval_sub
        text = "score flat / paste / generator / enhanced on the held-out frames of a posed set"
    p = parent.add_parser(name, help=text, description=module.__doc__)
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    module.add_arguments(p)
    p.set_defaults(func=module.run)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="prosplat", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser(
        "demo",
        help="the main job end to end on the built-in Blender demo scene",
        description="Build the demo scene in Blender, render its wide-baseline inputs and new "
        "target views, reconstruct Gaussians, render enhanced views and write side-by-side "
        "images, metrics and report.md into --out (a new out-N folder if --out already has "
        "results, unless --overwrite).",
    )
    demo.add_argument("--out", type=Path, default=Path("out/demo"), help="(default out/demo)")
    demo.add_argument("--scene", default="tabletop", help="scene family or hard scene name")
    demo.add_argument("--seed", type=int, default=950002, help="scene seed (default: a test one)")
    from prosplat.cli.demo import DEMO_SIZE
    from prosplat.pipeline.model import TRAINED_SIZE

    demo.add_argument(
        "--size",
        type=int,
        default=DEMO_SIZE,
        help=f"model resolution, multiple of 32 (default {DEMO_SIZE}, fast; the shipped "
        f"generator runs up to {TRAINED_SIZE})",
    )
    demo.add_argument(
        "--render-scale", type=int, default=2, help="Blender renders at size x this (default 2)"
    )
    demo.add_argument("--inputs", type=int, default=4, help="input views, 2-6 (default 4)")
    demo.add_argument("--targets", type=int, default=8, help="new target views (default 8)")
    demo.add_argument("--samples", type=int, default=16, help="Cycles samples (default 16)")
    demo.add_argument(
        "--budget",
        type=float,
        default=None,
        help="Gaussians to keep: a count or a fraction (default: automatic)",
    )
    demo.add_argument("--bf16", action="store_true", help="run stage 2 under bfloat16 autocast")
    demo.add_argument("--weights", default=None, help="generator checkpoint (default: shipped)")
    demo.add_argument(
        "--generator", default=None, help="a DepthSplat checkpoint (.pth) as stage 1 instead"
    )
    demo.add_argument("--improve", default=None, help="stage-2 checkpoint (default: shipped)")
    add_refine_arguments(demo)
    demo.add_argument("--overwrite", action="store_true", help="replace earlier results in --out")
    demo.set_defaults(func=cmd_demo)

    scenes = sub.add_parser("scenes", help="Blender-rendered synthetic scenes (needs bpy)")
    scenes_sub = scenes.add_subparsers(dest="scenes_command", required=True)
    rend = scenes_sub.add_parser(
        "render",
        help="render seeded scenes with Cycles into scene folders",
        description="Render scenes seed..seed+count-1 with Cycles on the CPU, each into "
        "OUT/NAME_SEED/ (transforms.json, images/, depth/). Finished scenes are "
        "skipped, so an interrupted run can simply be re-run. Seeds decide the "
        "split: train 0-899999, val 900000-949999, test 950000-999999.",
    )
    rend.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    rend.add_argument("--count", type=int, default=1, help="number of scenes (default 1)")
    rend.add_argument("--out", type=Path, required=True, help="dataset folder")
    rend.add_argument("--size", type=int, default=128, help="square image size in px (default 128)")
    rend.add_argument(
        "--inputs", type=int, default=4, help="input views per scene, 2-6 (default 4)"
    )
    rend.add_argument("--targets", type=int, default=8, help="target views per scene (default 8)")
    rend.add_argument(
        "--samples", type=int, default=32, help="Cycles samples per pixel (default 32)"
    )
    rend.add_argument("--denoise", action="store_true", help="run Cycles' denoiser (default off)")
    rend.add_argument(
        "--denoise-quality",
        choices=("high", "fast"),  # scenes.render.DENOISE_QUALITY's names (that module needs bpy)
        default="high",
        help="the denoiser's settings (with --denoise): high (Blender's default) or fast "
        "(no prefiltered albedo/normal passes, OIDN's balanced network: 0.7-0.8x the colour "
        "render's time, 0.1-0.9 dB from high; for training data)",
    )
    rend.add_argument(
        "--workers", type=int, default=2, help="parallel Blender processes (default 2)"
    )
    rend.add_argument(
        "--threads",
        type=int,
        default=None,
        help="Cycles threads per worker (default: the machine's cores / --workers); fewer "
        "leaves cores to a training run beside the rendering",
    )
    rend.add_argument(
        "--scene",
        default=None,
        help="family (room, tabletop, open) or hard scene (textureless, "
        "thin_structures, repeated_pattern, specular, near_far, "
        "inside_outside); default: the seed's family",
    )
    rend.set_defaults(func=cmd_scenes_render)
    lst = scenes_sub.add_parser(
        "list",
        help="list rendered scenes with their split, family and input overlap",
        description="Print a Markdown table of the scene folders under --out: split, family, "
        "hard-scene tags, view counts and the mean overlap between input views "
        "(to bin benchmarks by baseline).",
    )
    lst.add_argument("--out", type=Path, required=True, help="dataset folder")
    lst.set_defaults(func=cmd_scenes_list)
    pk = scenes_sub.add_parser(
        "pack",
        help="pack rendered scene folders into .npz files to move training data",
        description="Pack the scene folders under --data into OUT_000.npz, OUT_001.npz, ... "
        "of at most --max-mb each (JPEG images, q95 by default; float16 depth; float64 cameras): "
        "training reads packs like folders, with only numpy, Pillow and torch. "
        "Existing pack files are never replaced.",
    )
    pk.add_argument("--data", type=Path, required=True, help="dataset folder of scene folders")
    pk.add_argument("--out", type=Path, required=True, help="pack path prefix, e.g. packs/train")
    pk.add_argument("--max-mb", type=float, default=48.0, help="size bound per pack (default 48)")
    pk.add_argument("--first", type=int, default=0, help="skip the first N scenes (sorted)")
    pk.add_argument("--count", type=int, default=None, help="pack at most N scenes")
    pk.add_argument(
        "--no-depth",
        action="store_true",
        help="leave the depth maps out (about 40 %% smaller; enough for `prosplat train curate`, "
        "not for training the generator with depth terms)",
    )
    pk.add_argument(
        "--jpeg-quality",
        type=_int_between(1, 95),
        default=95,
        metavar="Q",
        help="JPEG quality of the images, 1-95 (default 95); lower fits more scenes into a "
        "bounded transfer",
    )
    pk.add_argument(
        "--depth-bits",
        type=_int_between(1, 10),
        default=10,
        metavar="BITS",
        help="mantissa bits kept of the float16 depth, 1-10 (default 10: all); fewer pack "
        "smaller (7: 0.4 %% relative error)",
    )
    pk.set_defaults(func=cmd_scenes_pack)

    train = sub.add_parser("train", help="train models on rendered scenes")
    train_sub = train.add_subparsers(dest="train_command", required=True)
    tg = train_sub.add_parser(
        "generator",
        help="train the stage-1 generator",
        description="Train the feed-forward generator on scene folders (prosplat scenes render). "
        "Re-running with the same --out resumes from its last checkpoint. One GPU or "
        "the CPU: run as is; several GPUs: torchrun --nproc_per_node K -m prosplat "
        "train generator ...",
    )
    from prosplat.generator.config import MAX_ALEXNET_LAYERS, PRESETS
    from prosplat.train.generator import DEPTH_LOSSES, TrainConfig, parse_inputs

    defaults = TrainConfig(data="", out="")
    tg.add_argument(
        "--data",
        required=True,
        help="training dataset folder(s) or scene packs (.npz, `prosplat scenes pack`), comma-separated",
    )
    tg.add_argument("--out", required=True, help="run folder (checkpoints, log.jsonl)")
    tg.add_argument("--val", default=None, help="validation dataset folder (optional)")
    tg.add_argument(
        "--config",
        default=defaults.config,
        choices=sorted(PRESETS),
        help="architecture preset of a new model (default %(default)s); prosplat --init "
        "weights bring their own",
    )
    for name in (
        "steps",
        "batch",
        "targets",
        "warmup",
        "log_every",
        "val_every",
        "val_scenes",
        "save_every",
        "seed",
        "cache_scenes",
    ):
        tg.add_argument(
            f"--{name.replace('_', '-')}",
            dest=name,
            type=int,
            default=getattr(defaults, name),
            help=f"(default {getattr(defaults, name)})",
        )
    for name in (
        "lr",
        "weight_decay",
        "lpips_weight",
        "ssim_weight",
        "depth_weight",
        "input_depth_weight",
        "input_depth_ce_weight",
        "input_render_weight",
        "crop_prob",
        "frame_prob",
        "grad_clip",
        "ema",
    ):
        tg.add_argument(
            f"--{name.replace('_', '-')}",
            dest=name,
            type=float,
            default=getattr(defaults, name),
            help=f"(default {getattr(defaults, name)})",
        )
    tg.add_argument(
        "--inputs",
        type=parse_inputs,
        default=defaults.inputs,
        help="input views per step: a count 2-6, or a set like 2,4,6 drawn from each step "
        f"(default {defaults.inputs})",
    )
    tg.add_argument(
        "--sizes",
        default=defaults.sizes,
        help="image sizes drawn per step, e.g. 64,128 (multiples of 32, at most the data's; "
        "default: the data's size)",
    )
    tg.add_argument(
        "--depth-loss",
        choices=DEPTH_LOSSES,
        default=defaults.depth_loss,
        help="how --depth-weight and --input-depth-weight compare depths: L1 of inverse depth "
        "(scene units) or of log depth (relative, the same at any scene scale; default "
        "%(default)s)",
    )
    tg.add_argument(
        "--stop-at",
        type=int,
        default=None,
        help="stop after this step with a checkpoint, the learning-rate schedule still "
        "following --steps: a long run taken in bounded parts (re-run with a later "
        "--stop-at, or none, to go on)",
    )
    tg.add_argument(
        "--target-scale",
        type=int,
        default=defaults.target_scale,
        help="render the targets at this multiple of the step's size (at most the data's), "
        "e.g. 2 with --sizes 64 on 128-px data: Gaussians made at 64 px that also cover a "
        "128-px camera, as the pipeline renders them (default 1)",
    )
    tg.add_argument(
        "--fill-holes",
        action="store_true",
        help="score every render with its holes filled (pull-push from its own colours), as "
        "stage 2 and the raw view see it, instead of black",
    )
    tg.add_argument(
        "--any-view",
        action="store_true",
        help="draw inputs and targets from all of a scene's views, not its input/target split",
    )
    tg.add_argument(
        "--init",
        default=None,
        help="start from these weights (fresh optimiser): a prosplat generator (.safetensors) "
        "trains all of it; a DepthSplat checkpoint (depthsplat-gs-*.pth, README 'DepthSplat "
        "weights') fine-tunes only its Gaussian regressor and head, the rest frozen, and writes "
        "OUT/<name>-prosplat-ft.pth for --generator / from_pretrained(generator=)",
    )
    tg.add_argument(
        "--grow-fine-matching",
        type=int,
        default=defaults.grow_fine_matching,
        metavar="CH",
        help="with --init prosplat weights: add a 1/2-resolution cost volume with CH feature "
        "channels (sharper matching peaks at wide baselines), entering through zero weights "
        "so training starts from the init's exact outputs (default 0: off)",
    )
    tg.add_argument(
        "--grow-image-matching",
        type=int,
        default=defaults.grow_image_matching,
        metavar="PX",
        help="with --init prosplat weights: add a plane sweep of the input images themselves "
        "(ZNCC over PX x PX windows, PX odd) to the depth head, which ranks depths a few planes "
        "apart where the learned features cannot; it enters through zero weights so training "
        "starts from the init's exact outputs (default 0: off)",
    )
    tg.add_argument(
        "--grow-band",
        type=int,
        default=defaults.grow_band,
        metavar="N",
        help="with --init prosplat weights: add a learned depth sweep after the depth refiner "
        "(N depths in a ±30%% band around each pixel's depth, scored by the images' ZNCC; "
        "prosplat/generator/band.py), entering through a zero convolution so training starts "
        "from the init's exact outputs (default 0: off)",
    )
    tg.add_argument(
        "--grow-alexnet",
        type=int,
        default=defaults.grow_alexnet,
        choices=range(MAX_ALEXNET_LAYERS + 1),
        metavar="N",
        help="with --init prosplat weights: add the frozen AlexNet relu1..reluN features of "
        "LPIPS (N 1-3; copied into the weights file) to the monocular branch, entering through "
        "zero weights so training starts from the init's exact outputs (default 0: off)",
    )
    tg.add_argument("--device", default=defaults.device, help="auto | cpu | cuda | cuda:N | mps")
    tg.set_defaults(func=cmd_train_generator)
    from prosplat.cli.improve import add_eval_parser, add_train_parsers

    add_train_parsers(train_sub)

    add_bench_parsers(sub)
    add_posed_parsers(sub)

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
    add_eval_parser(ev_sub)
    add_posed_parsers(sub, ev_sub)
    from prosplat.eval.ladder import cli as ladder_cli

    el = ev_sub.add_parser(
        "ladder",
        help="every ladder row (flat, paste, optimisation, generator, enhanced, true depth) "
        "with intervals, per family / overlap bin / target kind",
        description=ladder_cli.__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ladder_cli.add_arguments(el)
    el.set_defaults(func=ladder_cli.run)
    return parser


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    sys.exit(args.func(args))
