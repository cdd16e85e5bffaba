"""The files ``prosplat demo`` leaves in ``out/demo/``: pictures, metrics and a report.

- ``views/view_NNN_<kind>.png``: input reference | generator render (holes filled) | enhanced | Blender.
- ``overview.png``: the same panels for up to two interpolation and two extrapolation views.
- ``metrics.csv`` / ``metrics.json`` / ``metrics.md``: per view and per target kind.
- ``plot.png``: PSNR per view (generator vs enhanced) and speed against error.
- ``report.md``: what ran, how long each step took, the table and the pictures.

Panels are drawn with nearest-neighbour upsampling, so every model pixel stays visible: the
pictures' resolution grows with the model's so that a panel never shows fewer pixels than its
image has (256-px views come out at 1:1 or more).
"""

from __future__ import annotations

import csv
import json
import math
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path

from torch import Tensor


@dataclass
class ViewResult:
    """One target view: its scores against Blender and its timings (ms)."""

    index: int  # view index in the scene folder
    kind: str  # "interpolation" | "extrapolation"
    reference: int  # the scene view index of the input MORI chose
    psnr_raw: float
    psnr_enhanced: float
    ssim_raw: float
    ssim_enhanced: float
    lpips_raw: float
    lpips_enhanced: float
    render_ms: float
    mori_ms: float
    enhance_ms: float
    images: dict[str, Tensor] = field(default_factory=dict, repr=False)  # panels [3,H,W]
    guard: str | None = None  # why the raw render was kept (prosplat.pipeline.enhance's guard)


@dataclass
class DemoResult:
    out: Path
    scene_folder: Path
    views: list[ViewResult]
    # seconds: blender, reconstruct, prune, refine, views, ladder, pictures, total
    timings: dict[str, float]
    gaussians: dict[str, int]  # budget stats (input, kept, ...)
    blender_view_s: float  # Cycles seconds per rendered view (median)
    settings: dict
    ladder: list[dict] = field(default_factory=list)  # prosplat.eval.ladder.report.summarise


PANELS = (
    ("reference", "input (MORI reference)"),
    ("generator", "generator (stage 1, holes filled)"),
    ("enhanced", "enhanced (stage 2)"),
    ("blender", "Blender (ground truth)"),
)
METRICS = ("psnr", "ssim", "lpips")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _panel_titles(v: ViewResult) -> list[str]:
    return [
        f"input {v.reference} (MORI reference)",
        f"generator, filled {v.psnr_raw:.2f} dB",
        f"enhanced {v.psnr_enhanced:.2f} dB",
        "Blender (ground truth)",
    ]


def _draw_row(axes, v: ViewResult, titles: list[str]) -> None:
    for ax, (key, _), title in zip(axes, PANELS, titles):
        ax.imshow(v.images[key].permute(1, 2, 0).clamp(0, 1).numpy(), interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])


def _save(fig, axes, path: Path, image_width: int) -> None:
    """Lay ``fig`` out and save it at the resolution (at least 100 dpi) where its narrowest
    panel among ``axes`` is at least ``image_width`` pixels wide: the panels are
    upsampled, never downsampled (nearest-neighbour downsampling would drop pixels)."""
    fig.tight_layout()
    fw, fh = fig.get_size_inches()
    # a square image's panel: the axes' box shrunk to the aspect (inches)
    inches = min(min(a.get_position().width * fw, a.get_position().height * fh) for a in axes)
    fig.savefig(path, dpi=max(100, math.ceil(image_width / inches)))


def side_by_side(v: ViewResult, path: Path) -> None:
    """One view's four panels in a row, titled with their PSNR against Blender."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 4, figsize=(10, 2.9), dpi=100)
    _draw_row(axes, v, _panel_titles(v))
    fig.suptitle(f"view {v.index} ({v.kind})", fontsize=10)
    _save(fig, axes, path, _image_width(v))
    plt.close(fig)


def _image_width(v: ViewResult) -> int:
    return max(image.shape[-1] for image in v.images.values())


def overview_views(views: list[ViewResult], per_kind: int = 2) -> list[ViewResult]:
    """Up to ``per_kind`` views of each target kind, in view order."""
    picked = []
    for kind in ("interpolation", "extrapolation"):
        picked += [v for v in views if v.kind == kind][:per_kind]
    return sorted(picked or views[: 2 * per_kind], key=lambda v: v.index)


def overview(views: list[ViewResult], path: Path) -> None:
    plt = _pyplot()
    rows = overview_views(views)
    fig, axes = plt.subplots(len(rows), 4, figsize=(9, 2.35 * len(rows)), dpi=100, squeeze=False)
    for r, v in enumerate(rows):
        titles = [t for _, t in PANELS] if r == 0 else [""] * 4  # column headings, once
        _draw_row(axes[r], v, titles)
        axes[r][0].set_ylabel(
            f"view {v.index}\n{v.kind[:6]}.\n{v.psnr_raw:.1f} -> {v.psnr_enhanced:.1f} dB",
            fontsize=8,
        )
    _save(fig, axes.ravel(), path, max(_image_width(v) for v in rows))
    plt.close(fig)


def summary_rows(views: list[ViewResult]) -> list[dict]:
    """Mean scores and median ms per target kind, then over all views."""
    groups = {k: [v for v in views if v.kind == k] for k in sorted({v.kind for v in views})}
    groups["all"] = views
    rows = []
    for kind, sub in groups.items():
        row = {"kind": kind, "n": len(sub)}
        for m in METRICS:
            for which in ("raw", "enhanced"):
                row[f"{m}_{which}"] = statistics.fmean(getattr(v, f"{m}_{which}") for v in sub)
        row["raster_ms"] = statistics.median(v.render_ms for v in sub)
        row["enhanced_ms"] = statistics.median(v.render_ms + v.mori_ms + v.enhance_ms for v in sub)
        rows.append(row)
    return rows


def metrics_markdown(result: DemoResult) -> str:
    lines = [
        "| view | kind | reference | PSNR gen → enh | SSIM gen → enh | LPIPS gen → enh "
        "| raster ms | MORI+enhance ms |",
        "|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for v in result.views:
        lines.append(
            f"| {v.index} | {v.kind} | {v.reference} | {v.psnr_raw:.2f} → {v.psnr_enhanced:.2f} "
            f"| {v.ssim_raw:.3f} → {v.ssim_enhanced:.3f} | {v.lpips_raw:.3f} → "
            f"{v.lpips_enhanced:.3f} | {v.render_ms:.0f} | {v.mori_ms + v.enhance_ms:.0f} |"
        )
    guarded = [v for v in result.views if v.guard]
    if guarded:
        lines += ["", "Views where the guard kept the raw render:", ""]
        lines += [f"- view {v.index}: {v.guard}" for v in guarded]
    lines += [
        "",
        "| targets | n | PSNR gen → enh | SSIM gen → enh | LPIPS gen → enh | ms/view raster "
        "| ms/view enhanced |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for s in summary_rows(result.views):
        lines.append(
            f"| {s['kind']} | {s['n']} | {s['psnr_raw']:.2f} → {s['psnr_enhanced']:.2f} "
            f"| {s['ssim_raw']:.3f} → {s['ssim_enhanced']:.3f} | {s['lpips_raw']:.3f} → "
            f"{s['lpips_enhanced']:.3f} | {s['raster_ms']:.0f} | {s['enhanced_ms']:.0f} |"
        )
    return "\n".join(lines) + "\n"


def ladder_markdown(result: DemoResult) -> str:
    """The demo's views on the evaluation ladder: each row's mean over the targets with a
    bootstrapped 95 % interval, whole image and valid region (pixels some input sees)."""
    if not result.ladder:
        return ""

    def ci(e: dict, m: str, d: int) -> str:
        if e[f"{m}_n"] == 0:
            return "–"
        return f"{e[m]:.{d}f} [{e[f'{m}_lo']:.{d}f}, {e[f'{m}_hi']:.{d}f}]"

    lines = [
        "| row | PSNR ↑ | SSIM ↑ | LPIPS ↓ | PSNR valid ↑ | LPIPS valid ↓ | ms/view |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for e in result.ladder:
        lines.append(
            f"| {e['rung']} | {ci(e, 'psnr', 2)} | {ci(e, 'ssim', 3)} | {ci(e, 'lpips', 3)} | "
            f"{ci(e, 'psnr_valid', 2)} | {ci(e, 'lpips_valid', 3)} | {e['view_ms']:.0f} |"
        )
    return "\n".join(lines) + "\n"


def plot(result: DemoResult, path: Path) -> None:
    """Left: PSNR per view, generator vs enhanced. Right: ms per view against PSNR, with the
    time Cycles took for each exact image (the cost of the ground truth) for scale."""
    plt = _pyplot()
    views = result.views
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.6), dpi=100)
    x = list(range(len(views)))
    ax1.bar([i - 0.2 for i in x], [v.psnr_raw for v in views], 0.4, label="generator")
    ax1.bar([i + 0.2 for i in x], [v.psnr_enhanced for v in views], 0.4, label="enhanced")
    ax1.set_xticks(x, [f"{v.index}\n{v.kind[:5]}." for v in views], fontsize=7)
    lo = min(min(v.psnr_raw, v.psnr_enhanced) for v in views)
    ax1.set_ylim(max(0.0, lo - 3), None)
    ax1.set_ylabel("PSNR vs Blender (dB)")
    ax1.set_title("per target view")
    ax1.legend(fontsize=8)
    amortised = 1e3 * result.timings["reconstruct"] / max(len(views), 1)
    for s, marker in zip(summary_rows(views)[:-1], ("o", "s", "^")):
        ms = [s["raster_ms"] + amortised, s["enhanced_ms"] + amortised]
        ax2.plot(ms, [s["psnr_raw"], s["psnr_enhanced"]], marker=marker, label=s["kind"])
        for m, p, lab in zip(ms, [s["psnr_raw"], s["psnr_enhanced"]], ("gen", "enh")):
            ax2.annotate(lab, (m, p), fontsize=7, xytext=(3, 3), textcoords="offset points")
    rs, ms_size = result.settings.get("render_size"), result.settings.get("size")
    model_size = "" if rs == ms_size else f" (the model's views: {ms_size}²)"
    ax2.axvline(
        1e3 * result.blender_view_s,
        color="grey",
        ls="--",
        label=f"Cycles, one exact view at {rs}²{model_size}",
    )
    ax2.set_xscale("log")
    ax2.set_xlabel("ms per view (reconstruction amortised)")
    ax2.set_ylabel("mean PSNR (dB)")
    ax2.set_title("speed against error")
    ax2.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _write_tables(result: DemoResult) -> None:
    out = result.out
    fields = [k for k in result.views[0].__dataclass_fields__ if k != "images"]
    with open(out / "metrics.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(fields)
        for v in result.views:
            writer.writerow([getattr(v, k) for k in fields])
    payload = {
        "settings": result.settings,
        "timings_s": result.timings,
        "blender_view_s": result.blender_view_s,
        "gaussians": result.gaussians,
        "summary": summary_rows(result.views),
        "ladder": result.ladder,
        "views": [{k: getattr(v, k) for k in fields} for v in result.views],
    }
    (out / "metrics.json").write_text(json.dumps(payload, indent=2) + "\n")
    (out / "metrics.md").write_text(metrics_markdown(result))


def report_markdown(result: DemoResult) -> str:
    s, t, g = result.settings, result.timings, result.gaussians
    rows = summary_rows(result.views)
    total = rows[-1]
    n_rendered = len(result.views) + s["inputs"]
    pruned = (
        f"kept {g['kept']:,}; transparent {g['transparent']:,}, out of bounds "
        f"{g['out_of_bounds']:,}, duplicates {g['duplicate']:,}"
    )
    views = "\n".join(f"![view {v.index}](views/{side_by_side_name(v)})" for v in result.views)
    return f"""# ProSplat demo

Scene `{s["scene"]}` (seed {s["seed"]}, test split: no model saw it in training), built and
rendered by Blender (Cycles, CPU, {_render_text(s)}). {s["inputs"]} wide-baseline input
views; {len(result.views)} target cameras between the inputs (interpolation) and outside them
(extrapolation). The scene with a camera per view: `scene.blend`; the Gaussians:
`gaussians.ply` (open both in Blender; the ProSplat add-on imports the PLY as a point cloud).

![overview](overview.png)

## Numbers

Mean PSNR over all targets: generator (holes filled) {total["psnr_raw"]:.2f} dB → enhanced
{total["psnr_enhanced"]:.2f} dB ({total["psnr_enhanced"] - total["psnr_raw"]:+.2f} dB);
LPIPS {total["lpips_raw"]:.3f} → {total["lpips_enhanced"]:.3f}.

{metrics_markdown(result)}
![plot](plot.png)

## Against the ladder

A number means something only beside what is trivial and what is possible: a flat image of
the inputs' mean colour, the input MORI picks pasted as it is, and the upper bound, Gaussians
at Blender's true input depth with the holes no input saw filled as the generator's are
(*true depth filled*; raw on black and enhanced below it). *Filled* rows show the holes as a
continuation of the render's own colours instead of black. Means over the
{len(result.views)} targets with bootstrapped 95 % intervals; *valid*: only the pixels some
input sees (`prosplat eval ladder` runs the same rows on a test set).

{ladder_markdown(result)}
## Time

| step | seconds |
|---|---:|
| Blender: build + render {n_rendered} views ({result.blender_view_s:.2f} s per view) | {t["blender"]:.1f} |
| reconstruct ({g["input"]:,} Gaussians, one forward pass) | {t["reconstruct"]:.2f} |
| Gaussian budget ({pruned}) | {t["prune"]:.2f} |
| refinement against the inputs ({_refine_text(s)}) | {t.get("refine", 0.0):.2f} |
| render + enhance {len(result.views)} views, incl. scoring | {t["views"]:.1f} |
| evaluation ladder ({len(result.ladder)} rows of {len(result.views)} views, incl. scoring) \
| {t.get("ladder", 0.0):.1f} |
| pictures ({len(result.views)} side-by-sides, overview, plot) | {t.get("pictures", 0.0):.1f} |
| whole demo | {t["total"]:.1f} |

Timings are single runs on whatever machine ran this demo; `prosplat bench points` gives
medians over repeated runs.

## Every view

Input reference (the input MORI chose) | generator render, its holes filled | enhanced | Blender
ground truth.

{views}
"""


def _render_text(settings: dict) -> str:
    """How Blender made the ground truth: samples, denoiser, size (and the downsampling)."""
    s = settings
    denoise = s.get("denoise", "off")
    n = s["samples"]
    text = f"{n} sample{'' if n == 1 else 's'} at {s['render_size']}²"
    if denoise != "off":
        text += f", denoised ({denoise})"
    if s["render_size"] != s["size"]:
        return f"{text}, downsampled to the model's {s['size']}²"
    return f"{text}, the model's size"


def _refine_text(settings: dict) -> str:
    if settings.get("refine_seconds") is not None:
        return f"{settings['refine_seconds']:g} s budget"
    steps = settings.get("refine_steps") or 0
    return f"{steps} steps" if steps else "off"


def side_by_side_name(v: ViewResult) -> str:
    return f"view_{v.index:03d}_{v.kind}.png"


def write_report(result: DemoResult) -> None:
    """Write every file of the module docstring into ``result.out``; the seconds the
    pictures took go into ``result.timings["pictures"]`` and onto its ``"total"``."""
    from tqdm import tqdm

    t0 = time.perf_counter()
    (result.out / "views").mkdir(exist_ok=True)
    for v in tqdm(result.views, desc="writing pictures", unit="view"):
        side_by_side(v, result.out / "views" / side_by_side_name(v))
    overview(result.views, result.out / "overview.png")
    plot(result, result.out / "plot.png")
    result.timings["pictures"] = time.perf_counter() - t0
    if "total" in result.timings:  # the whole demo includes its pictures
        result.timings["total"] += result.timings["pictures"]
    _write_tables(result)
    (result.out / "report.md").write_text(report_markdown(result))
