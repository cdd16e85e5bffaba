"""``prosplat bench points``: time per view against PSNR / SSIM / LPIPS over operating points.

An operating point is (input resolution, input views, Gaussian budget, enhancement, stage-2
dtype, refinement steps) for the generator, or a per-scene optimisation baseline at some step
count. The full factorial is too slow to be useful, so one axis is varied at a time around a
base point (64 px, 4 views, automatic budget, enhancement on, fp32, no refinement), plus
enhancement off at every view count. Every point runs in the same process on the same
scenes, and repeats are interleaved across points, so ratios between points are fair even on
a busy machine.

Per scene and point the reconstruction (+ pruning) is timed ``--repeats`` times and every
target view's render (+ MORI + enhancement) ``--repeats`` times; medians are kept. Points that
share a reconstruction (same method, size, views, budget) share its timing. Optimisation and
refinement (generator + budget + ``prosplat.pipeline.refine`` for N steps, at the base point) are
timed once (seconds to minutes per scene). Outputs are deterministic, so quality is scored on
one run. Writes ``points.json`` (every per-view row), ``points.md`` and ``pareto.png``.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from collections import defaultdict
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import torch

from prosplat.data.scene import SceneData, resize_views
from prosplat.eval.bench import pareto
from prosplat.eval.generator import (
    REFERENCE_ROWS,
    Method,
    generator_method,
    optimize_method,
    pick_inputs,
    plane_sweep_method,
    reference_scores,
    refine_method,
    score_view,
)
from prosplat.geometry.budget import prune_pixel_aligned
from prosplat.metrics import psnr

TIMED_ONCE = ("opt-", "refine-")  # methods too slow to repeat: timed on one run
DTYPES = {"fp32": torch.float32, "bf16": torch.bfloat16}
REFERENCE_LABELS = {"flat": "flat colour", "paste": "MORI paste", "true-depth": "true depth"}
RENDER_HINT = (
    "render scenes with `prosplat scenes render --out DIR --seed 950000 --count 6 --size 64`"
)


@dataclass(frozen=True)
class Point:
    """One operating point; ``family`` names the axis it varies (for the plot's legend)."""

    family: str
    label: str
    method: str  # "generator", "plane sweep", "opt-STEPS" or "refine-STEPS"
    size: int
    views: int
    budget: int | float | None
    enhance: bool
    dtype: str

    @property
    def recon_key(self) -> tuple:
        return (self.method, self.size, self.views, self.budget)


@dataclass
class Axes:
    sizes: list[int]
    views: list[int]
    budgets: list[int | float | None]
    enhance: list[bool]
    dtypes: list[str]
    opt_steps: list[int]
    opt_views: int
    refine_steps: list[int] = field(default_factory=list)


def budget_name(budget: int | float | None) -> str:
    return "auto" if budget is None else str(budget)


def _ints(text: str, what: str) -> list[int]:
    try:
        return [int(v) for v in str(text).split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"--{what} must be comma-separated integers, got {text!r}") from None


def _budget(text: str) -> int | float | None:
    """A --budgets entry: auto -> None (automatic pruning only), 0.5 -> a fraction, 20000 -> a count."""
    text = text.strip().lower()
    if text == "auto":
        return None
    try:
        value: int | float = float(text) if any(c in text for c in ".e") else int(text)
    except ValueError:
        value = -1
    if (isinstance(value, float) and not 0 < value <= 1) or (isinstance(value, int) and value < 1):
        raise ValueError(f"--budgets: {text!r} is not auto, a count >= 1 or a fraction in (0, 1]")
    return value


def parse_axes(args: argparse.Namespace) -> Axes:
    """Check every axis value before any work; raises ValueError naming the bad value."""
    axes = Axes(
        sizes=_ints(args.sizes, "sizes"),
        views=_ints(args.views, "views"),
        budgets=[_budget(b) for b in str(args.budgets).split(",") if b.strip()],
        enhance=[],
        dtypes=[d.strip() for d in str(args.dtypes).split(",") if d.strip()],
        opt_steps=_ints(args.opt_steps, "opt-steps"),
        opt_views=int(args.opt_views),
        refine_steps=_ints(getattr(args, "refine_steps", ""), "refine-steps"),
    )
    for e in (e.strip() for e in str(args.enhance).split(",") if e.strip()):
        if e not in ("on", "off"):
            raise ValueError(f"--enhance: {e!r} is not on or off")
        axes.enhance.append(e == "on")
    if not (axes.sizes and axes.views and axes.budgets and axes.enhance and axes.dtypes):
        raise ValueError("--sizes, --views, --budgets, --enhance and --dtypes need a value each")
    if bad := [s for s in axes.sizes if s < 32 or s % 32]:
        raise ValueError(f"--sizes: {bad} are not multiples of 32 (the generator's stride)")
    if bad := [v for v in axes.views + [axes.opt_views] * bool(axes.opt_steps) if not 2 <= v <= 6]:
        raise ValueError(f"--views/--opt-views: {bad} outside 2-6 input views")
    if bad := [d for d in axes.dtypes if d not in DTYPES]:
        raise ValueError(f"--dtypes: {bad} not among {sorted(DTYPES)}")
    if bad := [s for s in axes.opt_steps if s < 1]:
        raise ValueError(f"--opt-steps: {bad} must be >= 1")
    if bad := [s for s in axes.refine_steps if s < 0]:
        raise ValueError(f"--refine-steps: {bad} must be >= 0 (0 is the base point)")
    return axes


def build_points(axes: Axes, plane_sweep: bool = False) -> list[Point]:
    """The base point, one axis varied at a time, enhancement off/on at every view count,
    then the baselines. Duplicates (a varied value equal to the base's) appear once."""

    def pick(values: list, preferred):
        return preferred if preferred in values else values[0]

    base = Point("base", "base", "generator", max(axes.sizes), pick(axes.views, 4), None, True, "")
    base = replace(base, budget=pick(axes.budgets, None), enhance=pick(axes.enhance, True))
    base = replace(base, dtype=pick(axes.dtypes, "fp32"))
    variants = [("resolution", dict(size=s), f"{s} px") for s in axes.sizes]
    variants += [("views", dict(views=v), f"{v} views") for v in axes.views]
    for v in axes.views:
        for e in axes.enhance:
            tag = f"enh {'on' if e else 'off'}"
            label = tag if v == base.views else f"{v} views, {tag}"
            variants.append(("enhance", dict(views=v, enhance=e), label))
    variants += [("budget", dict(budget=b), f"budget {budget_name(b)}") for b in axes.budgets]
    if base.enhance:  # bf16 only changes stage 2
        variants += [("dtype", dict(dtype=d), d) for d in axes.dtypes]
    points, seen = [base], {replace(base, family="", label="")}
    for family, change, label in variants:
        p = replace(base, family=family, label=label, **change)
        if (key := replace(p, family="", label="")) not in seen:
            seen.add(key)
            points.append(p)
    for n in axes.refine_steps:  # 0 is the base point itself
        if n > 0:
            ref = dict(family="refine", label=f"refine {n}", method=f"refine-{n}")
            points.append(replace(base, **ref))
    if plane_sweep:
        sweep = dict(family="plane sweep", label="plane sweep", method="plane sweep")
        points.append(replace(base, enhance=False, dtype="fp32", **sweep))
    for n in axes.opt_steps:  # optimisation fits every pixel: no budget, no enhancement
        opt = dict(family="optimise", label=f"opt-{n}", method=f"opt-{n}", budget=None)
        points.append(replace(base, views=axes.opt_views, enhance=False, dtype="fp32", **opt))
    return points


def reference_points(base: Point, names: list[str]) -> list[Point]:
    """The ladder's reference rows (flat colour, MORI paste, true depth) at the base point's
    size and view count: what the generator must beat, and what exact depth would give."""
    if bad := [n for n in names if n not in REFERENCE_ROWS]:
        raise ValueError(f"--references: {bad} not among {', '.join(REFERENCE_ROWS)}")
    return [
        replace(
            base,
            family="reference",
            label=REFERENCE_LABELS[n],
            method=n,
            enhance=False,
            budget=None,
            dtype="fp32",
        )  # fmt: skip
        for n in names
    ]


def reference_rows(scene: SceneData, refs: list[Point], split: str) -> list[dict]:
    """One row per (reference point, target), in :func:`measure_scene`'s form, scored and
    timed (once: they are cheap and model-free) by the ladder's own rows."""
    rows, name = [], scene.folder.name if scene.folder else "scene"
    targets = scene.target_indices
    for size, views in dict.fromkeys((p.size, p.views) for p in refs):
        here = [p for p in refs if (p.size, p.views) == (size, views)]
        idx = pick_inputs(scene, views)
        imgs, cams = resize_views(scene.images, scene.cameras, size)
        scores = reference_scores(scene, idx, [p.method for p in here], imgs, cams)
        for p in here:
            mine = [s for s in scores if s.method == p.label]  # one per target, in order
            for t, s in zip(targets, mine, strict=True):
                rows.append(
                    dict(split=split, scene=name, point=p.label, family=p.family)
                    | dict(method=p.method, size=size, views=views, enhance=False)
                    | dict(n_targets=len(targets), budget="-", dtype="-", recon_repeats=1)
                    | dict(recon_timed_once=True, kind=s.kind, target=t, recon_s=s.recon_s)
                    | dict(view_ms=s.render_ms)
                    | dict(amortised_ms=amortised_ms(s.recon_s, len(targets), s.render_ms))
                    | dict(psnr=s.psnr, psnr_raw=s.psnr, ssim=s.ssim, lpips=s.lpips)
                    | dict(gaussians=s.gaussians)
                )
    return rows


def reconstruct(method: Method, inputs: tuple, budget) -> tuple:
    """(Gaussians, seconds): reconstruction and, for pixel-aligned methods, pruning."""
    images, cams, near, far = inputs  # images [V,3,H,W]
    t0 = time.perf_counter()
    g, depths = method(images, cams, near, far)  # depths [V,H,W] or None (optimised)
    g = g.detach()
    if depths is not None:
        g = prune_pixel_aligned(g, depths, cams, budget=budget)[0]
    return g, time.perf_counter() - t0


def method_of(model, p: Point) -> Method:
    if p.method == "generator":
        return generator_method(model)
    if p.method == "plane sweep":
        return plane_sweep_method()
    if p.method.startswith("refine-"):
        steps = int(p.method.removeprefix("refine-"))
        return refine_method(model, steps=steps, budget=p.budget)
    return optimize_method(int(p.method.removeprefix("opt-")))


def amortised_ms(recon_s: float, n_targets: int, view_ms: float) -> float:
    """Time per view when one reconstruction serves all of a scene's target views."""
    return recon_s * 1e3 / n_targets + view_ms


def measure_scene(
    model, scene: SceneData, points: list[Point], repeats: int, split: str, bar=None
) -> list[dict]:
    """Time and score every point on one scene; one row (dict) per (point, target view)."""
    inputs, targets = {}, {}
    for p in points:
        if (p.size, p.views) not in inputs:
            idx = pick_inputs(scene, p.views)
            near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
            imgs, cams = resize_views(scene.images[idx], [scene.cameras[i] for i in idx], p.size)
            inputs[p.size, p.views] = (imgs, cams, near, far)
        if p.size not in targets:
            t_idx = scene.target_indices
            targets[p.size] = resize_views(
                scene.images[t_idx], [scene.cameras[i] for i in t_idx], p.size
            )
    recon_s, gaussians = defaultdict(list), {}
    view_ms, views = defaultdict(list), {}
    for r in range(repeats):  # interleaved: every point once per repeat
        for pi, p in enumerate(points):
            key = p.recon_key
            if len(recon_s[key]) <= r and not (r and p.method.startswith(TIMED_ONCE)):
                inp = inputs[p.size, p.views]
                gaussians[key], s = reconstruct(method_of(model, p), inp, p.budget)
                recon_s[key].append(s)
            imgs, cams = inputs[p.size, p.views][:2]
            for t, cam in enumerate(targets[p.size][1]):
                t0 = time.perf_counter()
                views[pi, t] = model.render(
                    gaussians[key], cam, imgs, cams, enhance=p.enhance, dtype=DTYPES[p.dtype]
                )
                view_ms[pi, t].append((time.perf_counter() - t0) * 1e3)
            if bar is not None:
                bar.update(1)
    rows, name = [], scene.folder.name if scene.folder else "scene"
    n_targets = len(scene.target_indices)
    for pi, p in enumerate(points):
        rec, n_g = statistics.median(recon_s[p.recon_key]), len(gaussians[p.recon_key])
        common = dict(split=split, scene=name, point=p.label, family=p.family, method=p.method)
        common |= dict(size=p.size, views=p.views, enhance=p.enhance, n_targets=n_targets)
        common |= dict(
            budget="-" if p.method.startswith("opt-") else budget_name(p.budget),
            dtype=p.dtype if p.enhance else "-",
            recon_repeats=len(recon_s[p.recon_key]),
            recon_timed_once=p.method.startswith(TIMED_ONCE),
        )
        for t, ti in enumerate(scene.target_indices):
            gt, v, ms = targets[p.size][0][t], views[pi, t], statistics.median(view_ms[pi, t])
            s = score_view(
                p.label, p.views, scene.target_kinds[ti], name, v.image, gt, rec, ms, n_g
            )
            raw = s.psnr if v.image is v.raw else float(psnr(v.raw.clamp(0, 1), gt))
            rows.append(
                common
                | dict(kind=s.kind, target=ti, recon_s=rec, view_ms=ms)
                | dict(amortised_ms=amortised_ms(rec, n_targets, ms), psnr=s.psnr, psnr_raw=raw)
                | dict(ssim=s.ssim, lpips=s.lpips, gaussians=n_g)
            )
    return rows


#: the comma-separated axes: flag -> (default, help)
AXIS_FLAGS = {
    "--sizes": ("32,64", "input resolutions in px, multiples of 32; the largest is the base"),
    "--views": ("2,4,6", "input-view counts, 2-6; base 4"),
    "--budgets": ("auto,0.5,0.2", "Gaussian budgets: auto, a count, or a fraction in (0,1]"),
    "--enhance": ("off,on", "stage-2 enhancement, also varied at every view count; base on"),
    "--dtypes": ("fp32,bf16", "stage-2 dtypes (bf16 = autocast); base fp32"),
    "--opt-steps": ("300,1000,3000", "per-scene optimisation step counts ('' for none)"),
    "--refine-steps": (
        "50,100,300,1000",
        "generator + refinement step counts at the base point ('' for none)",
    ),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``prosplat bench points`` (the CLI wires ``run`` to them)."""
    parser.add_argument(
        "--data",
        type=Path,
        nargs="+",
        required=True,
        help="dataset folders, each one split (e.g. data/test64 data/hard64)",
    )
    parser.add_argument("--scenes", type=int, default=None, help="at most N scenes per folder")
    for flag, (default, text) in AXIS_FLAGS.items():
        parser.add_argument(flag, default=default, help=f"{text} (default {default})")
    parser.add_argument("--opt-views", type=int, default=4, help="input views for optimisation")
    parser.add_argument("--plane-sweep", action="store_true", help="add the plane-sweep baseline")
    parser.add_argument(
        "--references",
        default=",".join(REFERENCE_ROWS),
        help="the ladder's reference rows at the base point: flat, paste, true-depth "
        f"('' for none; default {','.join(REFERENCE_ROWS)})",
    )
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per measurement")
    parser.add_argument("--weights", default=None, help="generator checkpoint (default: shipped)")
    parser.add_argument("--out", type=Path, default=Path("out/bench/points"), help="output folder")
    parser.add_argument("--overwrite", action="store_true", help="replace earlier results in --out")


def _load(args: argparse.Namespace, axes: Axes) -> list[tuple[str, SceneData]]:
    """Every scene (split = its data folder's name), checked against the axes."""
    from prosplat.data import find_scenes, load_scene

    scenes = []
    for root in args.data:
        folders = find_scenes(root)[: args.scenes] if Path(root).exists() else []
        if not folders:
            raise FileNotFoundError(f"no scenes in {root}; {RENDER_HINT}")
        scenes += [(Path(root).name, load_scene(f)) for f in folders]
    for _, sc in scenes:
        n_in, h = len(sc.input_indices), sc.images.shape[-2]
        if (most := max(axes.views + [axes.opt_views] * bool(axes.opt_steps))) > n_in:
            raise ValueError(
                f"{sc.folder} has {n_in} input views, cannot measure {most}; lower --views"
            )
        if (big := max(axes.sizes)) > h:
            raise ValueError(
                f"{sc.folder} is {h} px high, cannot measure at {big} px; lower --sizes"
            )
        if not sc.target_indices:
            raise ValueError(f"{sc.folder} has no target views to score")
    return scenes


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from prosplat.core.paths import fresh_folder, staged_folder
    from prosplat.pipeline.model import ProSplat

    try:
        axes = parse_axes(args)
        if args.repeats < 1:
            raise ValueError("--repeats must be >= 1")
        scenes = _load(args, axes)
        model = ProSplat.from_pretrained(args.weights)
        if True in axes.enhance and model.improver is None:
            raise ValueError("no improvement model is loaded; train one or pass --enhance off")
    except (ValueError, FileNotFoundError) as e:
        print(f"prosplat bench points: {e}", file=sys.stderr)
        return 2
    points = build_points(axes, args.plane_sweep)
    names = [n.strip() for n in str(args.references).split(",") if n.strip()]
    try:
        refs = reference_points(points[0], names)
    except ValueError as e:
        print(f"prosplat bench points: {e}", file=sys.stderr)
        return 2
    started = time.perf_counter()
    first = scenes[0][1]  # warm-up on one target: first-call costs stay out of the timings
    first = first.select(first.input_indices + first.target_indices[:1])
    measure_scene(model, first, [p for p in points if not p.method.startswith(TIMED_ONCE)], 1, "")
    rows = []
    with tqdm(total=len(scenes) * len(points) * args.repeats, desc="scene x point x repeat") as bar:
        for split, sc in scenes:
            rows += measure_scene(model, sc, points, args.repeats, split, bar)
            rows += reference_rows(sc, refs, split)
    summary = pareto.summarise(rows)
    table = pareto.markdown_table(summary, args.repeats)
    meta = dict(
        argv=sys.argv,
        args={k: str(v) for k, v in vars(args).items() if k != "func"},
        machine=f"{platform.node()} {platform.machine()} {platform.processor() or ''}".strip(),
        torch=torch.__version__,
        threads=torch.get_num_threads(),
        device="cpu",
        repeats=args.repeats,
        seconds=round(time.perf_counter() - started, 1),
        points=[asdict(p) for p in points + refs],
    )
    out = fresh_folder(args.out, args.overwrite)
    header = (
        f"Speed against error ({meta['machine']}, torch {meta['torch']}, {meta['threads']} threads)"
    )
    with staged_folder(out) as partial:  # moved to --out only when complete
        (partial / "points.json").write_text(
            json.dumps(dict(meta=meta, rows=rows, summary=summary), indent=1)
        )
        (partial / "points.md").write_text(f"{header}\n\n{table}\n")
        pareto.plot(summary, partial / "pareto.png", header)
    print(table)
    print(f"wrote {out / 'points.md'}, points.json and pareto.png ({meta['seconds']} s)")
    return 0
