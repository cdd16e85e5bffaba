"""``prosplat bench hard``: the whole pipeline on hard cases; zero NaN/Inf is the bar.

Every case is applied to every given scene and runs the whole pipeline a user runs:
reconstruct (generator) -> :func:`~prosplat.geometry.budget.prune_gaussians` (automatic budget) ->
render the raw view -> enhance it (stage 2, once per dtype) for 2 target views, and checks
that every tensor it produces is finite: the generator's Gaussians (means, quats, scales,
opacities, SH), depths and confidences, the pruned Gaussians after a PLY round trip, and per
target the raw render, alpha, depth and the enhanced image. Cases that are invalid input
(near = far, near <= 0, NaN far, coincident cameras without a depth range) must instead
raise a *clear* error: a ``ValueError``/``FileNotFoundError`` whose message names the
offending argument; any other exception (a RuntimeError from torch internals, a
ZeroDivisionError) is a bug.

Cases (:data:`CASES`), with a and b the scene's two farthest-apart input views and near/far
the scene's depth range unless said otherwise:

==============================  =================================================================
``baseline``                    inputs [a, b]: the reference row
``duplicated_inputs``           inputs [a, a, b, b] (each image and camera twice)
``single_view``                 inputs [a, a] with the scene's near/far: finite
``single_view_no_depth_range``  inputs [a, a], near/far left to default: clear error
``near_equals_far``             near = far = the scene's median depth: clear error
``near_nonpositive``            near = 0 and near = -far: clear error (each)
``depth_range_nonfinite``       near = NaN, far = NaN and far = Inf: clear error (each)
``depth_range_1e4_near``        near = far / 1e4 (a 1:10⁴ range reaching in to the lens)
``depth_range_1e4_far``         far = near · 1e4 (a 1:10⁴ range reaching out)
``textureless_inputs``          both input images one flat colour (their mean)
``textureless``                 the Blender ``textureless`` hard scene as it is (else n/a)
``specular``                    the Blender ``specular`` hard scene as it is (else n/a)
``focal_x0.1``, ``focal_x10``   input and target focal lengths x0.1 (~160° wide) and x10
                                (telephoto), images unchanged: PSNR not meaningful
``target_focal_x0.1``,          only the target focal lengths scaled
``target_focal_x10``
``target_is_input``             targets = the input cameras: PSNR against the inputs, and MORI
                                must pick that input (the pair's F is 0 for DWEA)
``target_behind_inputs``        a target behind every input looking away: nothing is visible
                                (alpha < 1e-3), the image is the background
==============================  =================================================================

A result is ``ok`` when it is finite, any error it raised is clear (and expected), and its
case-specific checks (``problems``) passed; the command exits 1 when any result is not ok.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import Tensor

from prosplat.data.scene import SceneData
from prosplat.eval.bench.hard_cases import (
    ARGUMENT_WORDS,
    CASES,
    EMPTY_ALPHA,
    CaseScene,
    Raises,
    Run,
    case_plan,
    prepare,
)

__all__ = [
    "CASES",
    "HardCaseResult",
    "run_hard_cases",
    "hard_case_table",
    "add_arguments",
    "run",
]

_DTYPE_NAMES = {torch.float32: "fp32", torch.bfloat16: "bf16", torch.float16: "fp16"}


@dataclass
class HardCaseResult:
    """One case on one scene.

    ``finite``: nothing the case produced holds NaN/Inf (a case that is expected to raise and
    raises produced nothing, so it is finite; a case that should run but raised is not).
    ``error``: the exception (type: message) or None. ``clear_error``: None when nothing was
    raised; True for a ValueError/FileNotFoundError naming the argument (near, far, camera,
    ...); False for any other exception, or for an invalid input that raised nothing.
    ``psnr_raw``/``psnr_enhanced``: mean PSNR (dB) over the targets where ground truth exists
    (the enhanced one at the first dtype), else None. ``problems``: failed case checks.
    """

    case: str
    scene: str
    finite: bool
    error: str | None
    clear_error: bool | None
    psnr_raw: float | None
    psnr_enhanced: float | None
    seconds: float
    note: str
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.finite and self.clear_error is not False and not self.problems


def _describe(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def _is_clear(exc: BaseException, words: Sequence[str] = ARGUMENT_WORDS) -> bool:
    """A ValueError/FileNotFoundError whose message names the offending argument."""
    if not isinstance(exc, (ValueError, FileNotFoundError)):
        return False
    message = str(exc).lower()
    return any(w in message for w in words)


def _nonfinite(named: dict[str, Tensor]) -> list[str]:
    return [name for name, t in named.items() if not bool(torch.isfinite(t.float()).all())]


def _ply_round_trip(gaussians) -> dict[str, Tensor]:
    """The Gaussians as the pipeline's output file reads back."""
    from prosplat.core.ply import read_ply, write_ply

    with tempfile.TemporaryDirectory(prefix="prosplat-hard-") as tmp:
        path = Path(tmp) / "gaussians.ply"
        write_ply(gaussians, path)
        back = read_ply(path, allow_empty=True)  # a hard case may keep no Gaussians
    return {f"ply.{k}": v for k, v in back.tensors().items()}


def _mean(values: list[float]) -> float | None:
    return sum(values) / len(values) if values else None


def _run_pipeline(model, plan: Run, dtypes: Sequence[torch.dtype]) -> dict:
    """Reconstruct, prune, render and enhance; returns what the result needs."""
    from prosplat.geometry.budget import prune_pixel_aligned
    from prosplat.metrics import psnr

    # the network and its depth sweep, unchecked: a NaN is reported here, where Gaussians raise
    out = model.run_generator(plan.images, plan.cameras, plan.near, plan.far, sweep=True)
    named = {
        f"generator.{k}": getattr(out, k)
        for k in ("means", "quats", "scales", "opacities", "sh", "depths", "confidence")
    }
    bad = _nonfinite(named)
    if bad:  # .gaussians() would raise on them; report the NaN instead
        return dict(bad=bad, psnr_raw=None, psnr_enh=None, notes=[], problems=[])
    g = out.gaussians(0).detach()
    g, _, stats = prune_pixel_aligned(g, out.depths[0], plan.cameras)
    named = _ply_round_trip(g) if len(g) else {}
    bad += _nonfinite(named)
    notes = [f"{stats['kept']}/{stats['input']} kept"]
    problems: list[str] = []
    enhance = model.improver is not None
    raw_scores: list[float] = []
    enh_scores: dict[torch.dtype, list[float]] = {dt: [] for dt in dtypes}
    refs, alphas = [], []
    for k, target in enumerate(plan.targets):
        view = model.render(g, target.camera, plan.images, plan.cameras, enhance=False)
        named = {f"t{k}.raw": view.raw, f"t{k}.alpha": view.alpha, f"t{k}.depth": view.depth}
        bad += _nonfinite(named)
        if target.gt is not None:
            raw_scores.append(float(psnr(view.raw.clamp(0, 1), target.gt.to(view.raw))))
        if target.empty:
            alpha = float(view.alpha.max())
            alphas.append(alpha)
            if not alpha < EMPTY_ALPHA:
                problems.append(f"t{k}: alpha max {alpha:.3g} behind the inputs (want < 1e-3)")
        if not enhance:
            continue
        for dt in dtypes:
            name = _DTYPE_NAMES.get(dt, str(dt))
            ev = model.render(g, target.camera, plan.images, plan.cameras, dtype=dt)
            bad += _nonfinite({f"t{k}.enhanced[{name}]": ev.image})
            if target.gt is not None:
                enh_scores[dt].append(float(psnr(ev.image.clamp(0, 1), target.gt.to(ev.image))))
            if dt == dtypes[0]:
                refs.append(ev.reference)
            if target.reference is not None and ev.reference != target.reference:
                problems.append(
                    f"t{k}: MORI picked input {ev.reference}, not the identical input "
                    f"{target.reference}"
                )
    if refs:
        notes.append("ref " + ",".join(str(r) for r in refs))
    if alphas:
        notes.append(f"alpha max {max(alphas):.1e}")
    if not enhance:
        notes.append("no improvement model: raw only")
    for dt in dtypes[1:]:
        score = _mean(enh_scores[dt])
        if score is not None:
            notes.append(f"{_DTYPE_NAMES.get(dt, str(dt))} enh {score:.2f} dB")
    return dict(
        bad=bad,
        psnr_raw=_mean(raw_scores),
        psnr_enh=_mean(enh_scores[dtypes[0]]) if dtypes else None,
        notes=notes,
        problems=problems,
    )


def _run_case(model, case: str, s: CaseScene, dtypes: Sequence[torch.dtype]) -> HardCaseResult:
    t0 = time.perf_counter()

    def result(finite, error, clear, p_raw, p_enh, note, problems=()) -> HardCaseResult:
        seconds = time.perf_counter() - t0
        return HardCaseResult(
            case, s.name, finite, error, clear, p_raw, p_enh, seconds, note, list(problems)
        )

    try:
        plan = case_plan(case, s)
    except Exception as exc:  # building the case itself failed: report, never abort the suite
        return result(False, _describe(exc), _is_clear(exc), None, None, "case setup failed")
    if isinstance(plan, str):
        return result(True, None, None, None, None, plan)
    if isinstance(plan, Raises):
        errors, clear, bad, notes = [], True, [], [plan.note] if plan.note else []
        for label, near, far in plan.attempts:
            try:
                out = model.run_generator(plan.images, plan.cameras, near, far, sweep=True)
            except Exception as exc:
                errors.append(f"[{label}] {_describe(exc)}")
                clear &= _is_clear(exc, plan.words)
                notes.append(f"{label}: {type(exc).__name__}")
                continue
            clear = False
            errors.append(f"[{label}] no error raised (expected a ValueError naming near/far)")
            notes.append(f"{label}: no error")
            bad += [f"{label}: {n}" for n in _nonfinite({"depths": out.depths, "means": out.means})]
        note = "; ".join(notes + ([f"NaN/Inf in {', '.join(bad)}"] if bad else []))
        return result(not bad, " | ".join(errors), clear, None, None, note)
    try:
        r = _run_pipeline(model, plan, dtypes)
    except Exception as exc:  # an input that should work raised: a failure either way
        note = f"{plan.note}; expected a finite result" if plan.note else "expected a finite result"
        return result(False, _describe(exc), _is_clear(exc), None, None, note)
    notes = ([plan.note] if plan.note else []) + r["notes"]
    if r["bad"]:
        notes.append("NaN/Inf in " + ", ".join(r["bad"]))
    return result(
        not r["bad"], None, None, r["psnr_raw"], r["psnr_enh"], "; ".join(notes), r["problems"]
    )


def run_hard_cases(
    model,
    scenes: list[SceneData],
    cases: Sequence[str] | None = None,
    dtypes: Sequence[torch.dtype] = (torch.float32, torch.bfloat16),
    *,
    n_targets: int = 2,
    progress: bool = False,
) -> list[HardCaseResult]:
    """Run every case in ``cases`` (default :data:`CASES`) on every scene.

    Args:
        model: a :class:`~prosplat.ProSplat` (with an improvement model to test stage 2).
        scenes: scenes with at least two input views and one target view.
        cases: names from :data:`CASES`.
        dtypes: stage-2 dtypes each target is enhanced at (the first gives ``psnr_enhanced``).
        n_targets: scene target views per case (the first ones).
        progress: show a tqdm bar.
    Returns:
        One :class:`HardCaseResult` per (scene, case), scene-major.
    Raises:
        ValueError: an unknown case name, no scenes, or a scene without target views.
    """
    cases = tuple(CASES if cases is None else cases)
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        raise ValueError(f"unknown hard cases {unknown}; choose from {', '.join(CASES)}")
    if not scenes:
        raise ValueError("run_hard_cases needs at least one scene")
    if n_targets < 1:
        raise ValueError(f"n_targets must be >= 1, got {n_targets}")
    dtypes = tuple(dtypes)
    prepared = [prepare(scene, n_targets) for scene in scenes]
    jobs = [(s, c) for s in prepared for c in cases]
    if progress:
        from tqdm import tqdm

        jobs = tqdm(jobs, desc="hard cases", unit="case")
    results = []
    for s, case in jobs:
        if progress:
            jobs.set_postfix_str(f"{s.name}: {case}")
        with torch.no_grad():
            results.append(_run_case(model, case, s, dtypes))
    return results


# ---- reporting ----------------------------------------------------------------------------
def _cell(text: str | None, limit: int = 90) -> str:
    if not text:
        return ""
    text = " ".join(text.split()).replace("|", "\\|")
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _db(value: float | None) -> str:
    return "—" if value is None else f"{value:.2f}"


def hard_case_table(results: Sequence[HardCaseResult]) -> str:
    """A markdown table, one row per result, failures marked **FAIL**."""
    lines = [
        "| scene | case | ok | finite | error | clear | PSNR raw | PSNR enh | s | note |",
        "|---|---|---|---|---|---|---:|---:|---:|---|",
    ]
    for r in results:
        clear = {None: "—", True: "yes", False: "**no**"}[r.clear_error]
        note = "; ".join([r.note] + r.problems) if r.problems else r.note
        lines.append(
            f"| {r.scene} | {r.case} | {'yes' if r.ok else '**FAIL**'} | "
            f"{'yes' if r.finite else '**NO**'} | {_cell(r.error)} | {clear} | "
            f"{_db(r.psnr_raw)} | {_db(r.psnr_enhanced)} | {r.seconds:.2f} | {_cell(note, 140)} |"
        )
    n_bad = sum(not r.ok for r in results)
    n_nonfinite = sum(not r.finite for r in results)
    lines.append("")
    lines.append(
        f"{len(results)} results: {n_bad} failed, {n_nonfinite} not finite, "
        f"{sum(r.error is not None and bool(r.clear_error) for r in results)} clear errors."
    )
    return "\n".join(lines)


def hard_case_summary(results: Sequence[HardCaseResult]) -> str:
    """A markdown table, one row per case over all scenes: how many were ok, finite or a clear
    error, and the mean PSNR where it is meaningful (the short form for BENCHMARKS.md)."""
    lines = [
        "| case | scenes | ok | finite | clear errors | mean PSNR raw | mean PSNR enh | max s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for case in dict.fromkeys(r.case for r in results):
        rows = [r for r in results if r.case == case]
        applies = [r for r in rows if not r.note.startswith("n/a")]
        raw = _mean([r.psnr_raw for r in applies if r.psnr_raw is not None])
        enh = _mean([r.psnr_enhanced for r in applies if r.psnr_enhanced is not None])
        lines.append(
            f"| {case} | {len(applies)} | {sum(r.ok for r in applies)} | "
            f"{sum(r.finite for r in applies)} | "
            f"{sum(r.error is not None and bool(r.clear_error) for r in applies)} | "
            f"{_db(raw)} | {_db(enh)} | {max((r.seconds for r in applies), default=0):.2f} |"
        )
    return "\n".join(lines)


def _default_data() -> list[Path]:
    return [p for p in (Path("data/hard64"), Path("data/test64")) if p.exists()]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``prosplat bench hard``."""
    parser.add_argument(
        "--data",
        type=Path,
        nargs="+",
        default=None,
        metavar="DIR",
        help="scene folders or dataset folders (default: data/hard64 and data/test64 when present)",
    )
    parser.add_argument(
        "--scenes", type=int, default=None, metavar="N", help="at most N scenes per folder"
    )
    parser.add_argument(
        "--cases", default=None, help=f"comma-separated cases (default all: {','.join(CASES)})"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("out/bench/hard"),
        help="folder for hard_cases.md and hard_cases.json (default out/bench/hard; a new "
        "-N folder if it holds results, unless --overwrite)",
    )
    parser.add_argument("--overwrite", action="store_true", help="write into --out even if used")


def run(args: argparse.Namespace) -> int:
    """``prosplat bench hard``: 0 when every case is ok, 1 when any is not, 2 on bad options."""
    import sys

    from prosplat.core.paths import fresh_folder, staged_folder
    from prosplat.data import find_scenes, load_scene
    from prosplat.pipeline.model import ProSplat

    def fail(message: str) -> int:
        print(f"prosplat bench hard: {message}", file=sys.stderr)
        return 2

    cases = None
    if args.cases:
        cases = [c.strip() for c in args.cases.split(",") if c.strip()]
        unknown = [c for c in cases if c not in CASES]
        if unknown:
            return fail(f"unknown cases {unknown}; choose from {', '.join(CASES)}")
    if args.scenes is not None and args.scenes < 1:
        return fail(f"--scenes must be >= 1, got {args.scenes}")
    roots = list(args.data) if args.data else _default_data()
    if not roots:
        return fail("no data: pass --data DIR (data/hard64 and data/test64 are missing)")
    folders = []
    for root in roots:
        try:
            found = find_scenes(root)
        except FileNotFoundError as exc:
            return fail(str(exc))
        if not found:
            return fail(f"{root} holds no scene folders (no */transforms.json)")
        folders += found[: args.scenes]

    t0 = time.perf_counter()
    scenes = [load_scene(f) for f in folders]
    model = ProSplat.from_pretrained()
    results = run_hard_cases(model, scenes, cases, progress=True)
    seconds = time.perf_counter() - t0

    table = hard_case_table(results)
    print(table)
    device = torch.cuda.get_device_name() if model.device.type == "cuda" else "CPU"
    header = (
        f"# Hard cases\n\n`prosplat bench hard` on {len(scenes)} scenes "
        f"({', '.join(str(r) for r in roots)}), {seconds:.0f} s on {device} "
        f"({platform.machine()}, {platform.system()}, torch {torch.__version__}, "
        f"{torch.get_num_threads()} threads).\n\n"
    )
    out = fresh_folder(args.out, args.overwrite)
    summary = hard_case_summary(results)
    print(summary)
    rows = [dict(asdict(r), ok=r.ok) for r in results]
    with staged_folder(out) as partial:  # moved to --out only when complete
        (partial / "hard_cases.md").write_text(header + summary + "\n\n" + table + "\n")
        (partial / "hard_cases.json").write_text(json.dumps(rows, indent=1) + "\n")
    print(f"wrote {out / 'hard_cases.md'} and hard_cases.json ({seconds:.0f} s)")
    return 0 if all(r.ok for r in results) else 1
