"""Turning ladder scores into tables: means with intervals per group, Markdown, CSV, JSON, plot.

Groups (``GROUPINGS``): every target together, then per target kind, per scene family, per
scene type (the family or the hard scene's name), and per input-overlap bin (the recorded
overlap of the inputs actually used: widest baselines first). Quality is a mean over targets
with a bootstrapped 95 % interval; time is a median (a shared machine has outliers): the
reconstruction per scene, the view per target, and the amortised time per view
(reconstruction / targets + view), the number a user who renders every target pays.
"""

from __future__ import annotations

import csv
import json
import statistics
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

from prosplat.eval.ladder.run import METRICS, VALID_METRICS, TargetScore
from prosplat.eval.ladder.stats import bin_order, bootstrap_ci

#: (column of TargetScore, title) of the groupings reported
GROUPINGS = (
    ("all", "all targets"),
    ("kind", "target kind"),
    ("family", "scene family"),
    ("scene_type", "scene type"),
    ("overlap_bin", "input overlap"),
)
ALL_METRICS = METRICS + VALID_METRICS


def summarise(
    scores: Sequence[TargetScore], seed: int = 0, n_resamples: int = 1000, by_scene: bool = False
) -> list[dict]:
    """One entry per (size, views, grouping, group, rung) in ladder order: ``n``, per metric
    ``{metric}``, ``{metric}_lo``, ``{metric}_hi`` (mean and 95 % interval), and the median
    ``recon_s``, ``view_ms``, ``amortised_ms``. ``by_scene`` resamples whole scenes instead of
    targets (wider, honest intervals when a scene's targets move together)."""
    rung_order = list(dict.fromkeys(s.rung for s in scores))
    out = []
    for size, views in dict.fromkeys((s.size, s.views) for s in scores):
        here = [s for s in scores if (s.size, s.views) == (size, views)]
        for by, _ in GROUPINGS:
            for group in _groups(here, by):
                sub = [s for s in here if by == "all" or getattr(s, by) == group]
                for rung in rung_order:
                    rows = [s for s in sub if s.rung == rung]
                    if rows:
                        out.append(
                            _entry(rows, size, views, by, group, rung, seed, n_resamples, by_scene)
                        )
    return out


def _groups(scores: Sequence[TargetScore], by: str) -> list[str]:
    if by == "all":
        return ["all"]
    present = {getattr(s, by) for s in scores}
    if by == "overlap_bin":
        order = bin_order()
        return [b for b in order if b in present] + sorted(present - set(order))
    if by == "kind":
        first = [k for k in ("interpolation", "extrapolation") if k in present]
        return first + sorted(present - set(first))
    return sorted(present)


def _entry(rows, size, views, by, group, rung, seed, n_resamples, by_scene) -> dict:
    e = dict(size=size, views=views, grouping=by, group=group, rung=rung, n=len(rows))
    e["scenes"] = len({r.scene for r in rows})
    clusters = [r.scene for r in rows] if by_scene else None
    for m in ALL_METRICS:
        values = [getattr(r, m) for r in rows]
        ci = bootstrap_ci(values, seed=seed, n_resamples=n_resamples, clusters=clusters)
        e.update({m: ci.mean, f"{m}_lo": ci.lo, f"{m}_hi": ci.hi, f"{m}_n": ci.n})
    recon = {r.scene: r.recon_s for r in rows}
    e["recon_s"] = statistics.median(recon.values())
    e["view_ms"] = statistics.median(r.view_ms for r in rows)
    e["amortised_ms"] = statistics.median(r.recon_s * 1e3 / r.n_targets + r.view_ms for r in rows)
    e["valid_fraction"] = statistics.fmean(r.valid_fraction for r in rows)
    return e


#: the rows every other row is compared with, pairwise on the same targets
ANCHORS = ("MORI paste", "true depth")


def paired_deltas(
    scores: Sequence[TargetScore], seed: int = 0, n_resamples: int = 1000, by_scene: bool = False
) -> list[dict]:
    """Per (size, views, rung, anchor): the mean PSNR and LPIPS difference ``rung − anchor``
    over the targets both scored, with a bootstrapped 95 % interval of the paired
    differences. Pairing removes the between-target spread that dominates the plain
    intervals, so "does the enhanced view beat the paste?" gets a sharp answer."""
    out = []
    key = lambda s: (s.scene, s.target)  # noqa: E731
    for size, views in dict.fromkeys((s.size, s.views) for s in scores):
        here = [s for s in scores if (s.size, s.views) == (size, views)]
        rungs = list(dict.fromkeys(s.rung for s in here))
        for anchor in (a for a in ANCHORS if a in rungs):
            base = {key(s): s for s in here if s.rung == anchor}
            for rung in (r for r in rungs if r != anchor):
                pairs = [(s, base[key(s)]) for s in here if s.rung == rung and key(s) in base]
                e = dict(size=size, views=views, rung=rung, anchor=anchor, n=len(pairs))
                clusters = [a.scene for a, _ in pairs] if by_scene else None
                for m in ("psnr", "lpips", "psnr_valid"):
                    diffs = [getattr(a, m) - getattr(b, m) for a, b in pairs]
                    ci = bootstrap_ci(diffs, seed=seed, n_resamples=n_resamples, clusters=clusters)
                    e.update({f"d_{m}": ci.mean, f"d_{m}_lo": ci.lo, f"d_{m}_hi": ci.hi})
                    e[f"d_{m}_n"] = ci.n
                out.append(e)
    return out


def deltas_markdown(deltas: Sequence[dict], size: int, views: int) -> str:
    """Each row against the paste and against the upper bound, paired on the same targets."""
    here = [d for d in deltas if (d["size"], d["views"]) == (size, views)]
    if not here:
        return ""
    anchors = list(dict.fromkeys(d["anchor"] for d in here))
    rungs = list(dict.fromkeys(d["rung"] for d in here))
    head = "| row | " + " | ".join(f"Δ PSNR vs {a} | Δ LPIPS vs {a}" for a in anchors) + " |"
    lines = ["#### paired differences", "", head, "|---|" + "---:|---:|" * len(anchors)]
    for r in rungs:
        cells = []
        for a in anchors:
            d = next((x for x in here if (x["rung"], x["anchor"]) == (r, a)), None)
            if d is None:
                cells += ["–", "–"]
                continue
            cells += [_ci(d, "d_psnr", 2, signed=True), _ci(d, "d_lpips", 3, signed=True)]
        lines.append(f"| {r} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _pct(e: dict, m: str) -> str:
    """A share as a percentage with its interval, one decimal."""
    if e[f"{m}_n"] == 0:
        return "–"
    return f"{100 * e[m]:.1f} [{100 * e[f'{m}_lo']:.1f}, {100 * e[f'{m}_hi']:.1f}]"


def _ci(e: dict, m: str, digits: int, signed: bool = False) -> str:
    if e[f"{m}_n"] == 0:
        return "–"
    f = f"+.{digits}f" if signed else f".{digits}f"
    return f"{e[m]:{f}} [{e[f'{m}_lo']:{f}}, {e[f'{m}_hi']:{f}}]"


def markdown(summary: Sequence[dict], deltas: Sequence[dict] = (), by_scene: bool = False) -> str:
    """The full ladder per (size, views), its paired differences (:func:`paired_deltas`)
    and the grouped tables under it."""
    parts = []
    for size, views in dict.fromkeys((e["size"], e["views"]) for e in summary):
        here = [e for e in summary if (e["size"], e["views"]) == (size, views)]
        overall = [e for e in here if e["grouping"] == "all"]
        n, scenes = overall[0]["n"], overall[0]["scenes"]
        lines = [
            f"### {size} px, {views} input views ({scenes} scenes, {n} targets)",
            "",
            "| row | PSNR ↑ | SSIM ↑ | LPIPS ↓ | depth AbsRel ↓ | floaters % ↓ | PSNR valid ↑ | SSIM valid ↑ "
            "| LPIPS valid ↓ | AbsRel valid ↓ | recon s | ms/view | amortised ms/view |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for e in overall:
            lines.append(
                f"| {e['rung']} | {_ci(e, 'psnr', 2)} | {_ci(e, 'ssim', 3)} | "
                f"{_ci(e, 'lpips', 3)} | {_ci(e, 'abs_rel', 3)} | {_pct(e, 'floaters')} | "
                f"{_ci(e, 'psnr_valid', 2)} | "
                f"{_ci(e, 'ssim_valid', 3)} | {_ci(e, 'lpips_valid', 3)} | "
                f"{_ci(e, 'abs_rel_valid', 3)} | {e['recon_s']:.2f} | "
                f"{e['view_ms']:.1f} | {e['amortised_ms']:.1f} |"
            )
        valid = statistics.fmean(e["valid_fraction"] for e in overall)
        lines += ["", f"Valid region: {100 * valid:.0f} % of the target pixels on average."]
        parts.append("\n".join(lines))
        if table := deltas_markdown(deltas, size, views):
            parts.append(table)
        for by, title in GROUPINGS[1:]:
            parts.append(_grouped(here, by, title))
    notes = (
        "Means over target views with bootstrapped 95 % intervals [lo, hi] (1000 seeded "
        f"resamples of the {'scenes (all targets of a drawn scene)' if by_scene else 'targets'}); "
        "paired differences: the same over per-target differences. "
        "*valid*: scored only on the pixels whose surface at least one input sees (Blender "
        "depth, reprojected, occlusion-tested). *floaters*: the share of the target pixels "
        "with a true surface where the drawn depth lies more than 10 % in front of it. Times are medians: recon "
        "per scene, ms/view per target, amortised = recon / targets + ms/view."
    )
    return "\n\n".join(parts + [notes]) + "\n"


def _grouped(here: Sequence[dict], by: str, title: str) -> str:
    """One compact table: a row per group, a column pair per rung (PSNR [CI], LPIPS)."""
    entries = [e for e in here if e["grouping"] == by]
    rungs = list(dict.fromkeys(e["rung"] for e in entries))
    groups = list(dict.fromkeys(e["group"] for e in entries))
    head = f"| {title} | n | " + " | ".join(f"{r} PSNR / LPIPS" for r in rungs) + " |"
    lines = [f"#### by {title}", "", head, "|---|---:|" + "---:|" * len(rungs)]
    for g in groups:
        cells = []
        n = 0
        for r in rungs:
            e = next((x for x in entries if (x["group"], x["rung"]) == (g, r)), None)
            if e is None:
                cells.append("–")
                continue
            n = e["n"]
            lp = "–" if e["lpips_n"] == 0 else f"{e['lpips']:.3f}"
            cells.append(f"{_ci(e, 'psnr', 2)} / {lp}")
        lines.append(f"| {g} | {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_csv(summary: Sequence[dict], path: Path) -> None:
    """The summary, one row per (size, views, grouping, group, rung)."""
    if not summary:
        path.write_text("")
        return
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(summary[0]))
        writer.writeheader()
        writer.writerows(summary)


def write_json(
    scores: Sequence[TargetScore],
    summary: Sequence[dict],
    meta: dict,
    path: Path,
    deltas: Sequence[dict] = (),
) -> None:
    """Everything: the run's settings, every per-target score, the summary and the paired
    differences."""
    payload = {"meta": meta, "summary": list(summary), "deltas": list(deltas)}
    payload["scores"] = [asdict(s) for s in scores]
    path.write_text(json.dumps(payload, indent=1, default=str) + "\n")


def plot(summary: Sequence[dict], path: Path, title: str = "") -> Path:
    """Amortised ms per view (log) against PSNR with its interval, a panel per (size, views)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = list(dict.fromkeys((e["size"], e["views"]) for e in summary))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4.2), squeeze=False)
    for ax, (size, views) in zip(axes[0], panels):
        sub = [e for e in summary if (e["size"], e["views"], e["grouping"]) == (size, views, "all")]
        for e in sub:
            x = max(e["amortised_ms"], 1e-3)
            yerr = [[e["psnr"] - e["psnr_lo"]], [e["psnr_hi"] - e["psnr"]]]
            ax.errorbar(x, e["psnr"], yerr=yerr, fmt="o", capsize=3, label=e["rung"])
            ax.annotate(e["rung"], (x, e["psnr"]), fontsize=7, xytext=(4, 3),
                        textcoords="offset points")  # fmt: skip
        ax.set_xscale("log")
        ax.set_xlabel("amortised ms per view (log)")
        ax.set_ylabel("PSNR (dB), 95 % interval")
        ax.set_title(f"{size} px, {views} views", fontsize=10)
        ax.grid(alpha=0.3, which="both")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path
