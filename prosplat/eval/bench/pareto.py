"""Speed against error: group per-view rows, find the Pareto front, write the table and plot.

A user picks an operating point by asking "what is the best quality I can have within this
much time per view?". The answer is the Pareto front over (amortised ms per view, PSNR):
the points that no other point beats on both at once. Everything here works on plain dicts
(the rows of ``points.json``) so the table and the plot can be rebuilt from a saved run.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from pathlib import Path

from prosplat.eval.ladder.stats import bootstrap_ci

#: the order target kinds are shown in; others follow alphabetically
KIND_ORDER = ("interpolation", "extrapolation")

#: (colour, marker) per axis family, fixed so that plots of different runs read the same
FAMILY_STYLE: dict[str, tuple[str, str]] = {
    "base": ("black", "*"),
    "resolution": ("tab:blue", "s"),
    "views": ("tab:orange", "o"),
    "enhance": ("tab:green", "v"),
    "budget": ("tab:purple", "D"),
    "dtype": ("tab:brown", "P"),
    "optimise": ("tab:red", "X"),
    "refine": ("tab:cyan", "h"),
    "plane sweep": ("tab:gray", "^"),
    "reference": ("tab:cyan", "d"),
}


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the points (time, quality) that no other point dominates, sorted by time.

    Lower time and higher quality are better. A point is dominated when another is at least
    as good on both and strictly better on one; equal points do not dominate each other, so
    ties are all kept. Points with a NaN coordinate are never on the front.
    """
    ok = [i for i, (x, y) in enumerate(points) if not (math.isnan(x) or math.isnan(y))]
    front = []
    for i in ok:
        xi, yi = points[i]
        dominated = any(
            points[j][0] <= xi and points[j][1] >= yi and (points[j][0] < xi or points[j][1] > yi)
            for j in ok
        )
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: (points[i][0], -points[i][1], i))


def _mean(values: Sequence[float]) -> float:
    """Mean over the non-NaN values (LPIPS is NaN below 32 px); NaN if none."""
    vals = [v for v in values if not math.isnan(v)]
    return sum(vals) / len(vals) if vals else float("nan")


def kinds_of(rows: Sequence[dict]) -> list[str]:
    present = {r["kind"] for r in rows}
    return [k for k in KIND_ORDER if k in present] + sorted(present - set(KIND_ORDER))


def summarise(rows: Sequence[dict]) -> list[dict]:
    """One entry per (split, point, target kind), in the order the rows first name them.

    Times are medians (per view over views; reconstruction over scenes, each scene's value
    itself a median of repeats), quality means: times have outliers from a shared machine,
    quality does not. ``x_base`` is the amortised time relative to the base point of the same
    split and kind (same run, so the ratio is fair); ``front`` marks the Pareto front.
    """
    groups: dict[tuple[str, str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["split"], r["point"], r["kind"]), []).append(r)
    out = []
    for (split, point, kind), sub in groups.items():
        first = sub[0]
        recon = {r["scene"]: r["recon_s"] for r in sub}
        entry = {k: first[k] for k in ("family", "method", "size", "views", "budget", "enhance")}
        entry.update(
            split=split,
            point=point,
            kind=kind,
            dtype=first["dtype"],
            timed_once=first["recon_timed_once"],
            n=len(sub),
            scenes=len(recon),
            view_ms=statistics.median(r["view_ms"] for r in sub),
            recon_s=statistics.median(recon.values()),
            amortised_ms=statistics.median(r["amortised_ms"] for r in sub),
            psnr=_mean([r["psnr"] for r in sub]),
            psnr_lo=(ci := bootstrap_ci([r["psnr"] for r in sub])).lo,
            psnr_hi=ci.hi,
            psnr_raw=_mean([r["psnr_raw"] for r in sub]),
            ssim=_mean([r["ssim"] for r in sub]),
            lpips=_mean([r["lpips"] for r in sub]),
            gaussians=_mean([float(r["gaussians"]) for r in sub]),
        )
        out.append(entry)
    for split in {e["split"] for e in out}:
        for kind in {e["kind"] for e in out}:
            sub = [e for e in out if (e["split"], e["kind"]) == (split, kind)]
            base = next((e["amortised_ms"] for e in sub if e["family"] == "base"), float("nan"))
            front = set(pareto_front([(e["amortised_ms"], e["psnr"]) for e in sub]))
            for i, e in enumerate(sub):
                e["x_base"] = e["amortised_ms"] / base if base > 0 else float("nan")
                e["front"] = i in front
    return out


def _psnr_ci(s: dict) -> str:
    if "psnr_lo" not in s or math.isnan(s["psnr_lo"]):
        return f"{s['psnr']:.2f}"
    return f"{s['psnr']:.2f} [{s['psnr_lo']:.2f}, {s['psnr_hi']:.2f}]"


def markdown_table(summary: Sequence[dict], repeats: int) -> str:
    """The grouped table, one section per target kind (interpolation, extrapolation)."""
    head = (
        "| split | point | px | views | budget | enhance | dtype | n | view ms | recon s "
        "| amortised ms/view | × base | PSNR ↑ [95 % CI] | raw PSNR | SSIM ↑ | LPIPS ↓ | Gaussians | front |\n"
        "|---|---|---:|---:|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|:-:|"
    )
    parts = []
    for kind in kinds_of(summary):
        lines = [f"### {kind} targets", "", head]
        for s in (e for e in summary if e["kind"] == kind):
            once = "¹" if s["timed_once"] else ""
            lines.append(
                f"| {s['split']} | {s['point']} | {s['size']} | {s['views']} | {s['budget']} | "
                f"{'on' if s['enhance'] else 'off'} | {s['dtype']} | {s['n']} | "
                f"{s['view_ms']:.1f} | {s['recon_s']:.2f}{once} | {s['amortised_ms']:.1f} | "
                f"{s['x_base']:.2f} | {_psnr_ci(s)} | {s['psnr_raw']:.2f} | {s['ssim']:.3f} | "
                f"{s['lpips']:.3f} | {s['gaussians']:.0f} | {'★' if s['front'] else ''} |"
            )
        parts.append("\n".join(lines))
    notes = (
        f"view ms: render (+ MORI + enhancement) per target view, median of {repeats} runs; "
        f"recon s: reconstruction (+ pruning) per scene, median of {repeats} runs, median over "
        "scenes; amortised = recon / targets per scene + view ms. ¹ per-scene optimisation is "
        "timed once (it takes seconds to minutes), as are the ladder's reference rows (flat colour, "
        "MORI paste, true depth: model-free). Quality: means over views, PSNR with a "
        "bootstrapped 95 % interval over views. × base: amortised "
        "time over the base point's, same run. ★: on the Pareto front (faster and better PSNR). "
        "Quality is against ground truth at the row's own size (downsized with antialiasing), "
        "so a smaller size is scored on an easier, blurrier target."
    )
    return "\n\n".join(parts + [notes])


def plot(summary: Sequence[dict], path: Path, title: str = "") -> Path:
    """Amortised ms per view (log) against PSNR: a panel per (split, target kind), a colour
    and marker per axis family, the Pareto front as a step line (best PSNR within a time)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    splits = list(dict.fromkeys(e["split"] for e in summary))
    kinds = kinds_of(summary) or ["target"]
    fig, axes = plt.subplots(
        len(splits), len(kinds), figsize=(5.5 * len(kinds), 4.2 * len(splits)), squeeze=False
    )
    seen: set[str] = set()
    for r, split in enumerate(splits):
        for c, kind in enumerate(kinds):
            ax = axes[r][c]
            sub = [e for e in summary if (e["split"], e["kind"]) == (split, kind)]
            for e in sub:
                colour, marker = FAMILY_STYLE.get(e["family"], ("tab:olive", "o"))
                label = None if e["family"] in seen else e["family"]
                seen.add(e["family"])
                ax.scatter(e["amortised_ms"], e["psnr"], c=colour, marker=marker, label=label)
                ax.annotate(
                    e["point"],
                    (e["amortised_ms"], e["psnr"]),
                    fontsize=6,
                    xytext=(3, 3),
                    textcoords="offset points",
                )
            front = [sub[i] for i in pareto_front([(e["amortised_ms"], e["psnr"]) for e in sub])]
            if front:
                xs, ys = [e["amortised_ms"] for e in front], [e["psnr"] for e in front]
                ax.step(xs, ys, where="post", color="0.4", lw=1, ls="--", zorder=0)
            ax.set_xscale("log")
            ax.set_xlabel("amortised ms per view (log)")
            ax.set_ylabel("PSNR (dB)")
            ax.set_title(f"{split}: {kind}", fontsize=10)
            ax.grid(alpha=0.3, which="both")
    handles, labels = axes[0][0].get_legend_handles_labels()
    for ax in axes.flat[1:]:
        h, lab = ax.get_legend_handles_labels()
        handles, labels = handles + h, labels + lab
    fig.legend(handles, labels, loc="lower center", ncol=min(8, len(labels)), fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path
