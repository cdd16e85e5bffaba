"""Means with bootstrapped confidence intervals, and the input-overlap bins.

A test set of a few dozen scenes gives means that move by tenths of a dB from one set of
scenes to the next, which is the size of many differences we report. Every mean in the ladder
therefore carries a percentile-bootstrap interval: resample the scored targets with
replacement (``n_resamples`` times, from a fixed seed so a table is reproducible), take the
mean of each resample, and report the 2.5th and 97.5th percentiles. With ``clusters`` the
resampling draws whole clusters (e.g. scenes), which is the honest choice when the targets
of one scene are correlated; the ladder's default resamples targets, as the issue asks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

#: resamples per interval; 1000 keeps the percentile's Monte-Carlo error near 0.1 of a width
N_RESAMPLES = 1000
#: the default input-overlap bin edges (mean pairwise overlap of the chosen inputs, 0-1)
OVERLAP_EDGES = (0.2, 0.4, 0.6)


@dataclass(frozen=True)
class Interval:
    """A mean over ``n`` finite values with its bootstrap interval [lo, hi] (NaN if n = 0)."""

    mean: float
    lo: float
    hi: float
    n: int

    def fmt(self, digits: int = 2) -> str:
        """``"14.23 [13.90, 14.55]"``; ``"–"`` when there were no values."""
        if self.n == 0:
            return "–"
        return f"{self.mean:.{digits}f} [{self.lo:.{digits}f}, {self.hi:.{digits}f}]"


def bootstrap_ci(
    values: Sequence[float],
    level: float = 0.95,
    n_resamples: int = N_RESAMPLES,
    seed: int = 0,
    clusters: Sequence[object] | None = None,
) -> Interval:
    """The mean of ``values`` and its percentile-bootstrap ``level`` interval.

    NaN values (e.g. LPIPS below 32 px, AbsRel of a row without depth) are dropped first.
    The same ``seed`` always gives the same interval. With ``clusters`` (one label per value)
    whole clusters are resampled and the mean is over the pooled values of the drawn clusters.
    A single value (or a single cluster) gives a zero-width interval. The percentiles can
    miss the mean itself with very few, skewed values; the interval is then widened to reach
    it, so a table never shows a mean outside its own interval.

    Raises:
        ValueError: ``level`` outside (0, 1), ``n_resamples`` < 1, or ``clusters`` of another
            length than ``values``.
    """
    if not 0 < level < 1:
        raise ValueError(f"bootstrap_ci: level must lie in (0, 1), got {level}")
    if n_resamples < 1:
        raise ValueError(f"bootstrap_ci: n_resamples must be >= 1, got {n_resamples}")
    if clusters is not None and len(clusters) != len(values):
        raise ValueError(f"bootstrap_ci: {len(clusters)} cluster labels for {len(values)} values")
    keep = [i for i, v in enumerate(values) if not math.isnan(float(v))]
    if not keep:
        return Interval(math.nan, math.nan, math.nan, 0)
    x = torch.tensor([float(values[i]) for i in keep], dtype=torch.float64)  # [n]
    gen = torch.Generator().manual_seed(seed)
    if clusters is None:
        idx = torch.randint(0, len(x), (n_resamples, len(x)), generator=gen)  # [R, n]
        means = x[idx].mean(dim=1)  # [R]
    else:
        labels = [clusters[i] for i in keep]
        order = list(dict.fromkeys(labels))
        code = torch.tensor([order.index(c) for c in labels])  # [n] cluster of each value
        sums = torch.zeros(len(order), dtype=torch.float64).index_add_(0, code, x)  # [C]
        counts = torch.bincount(code, minlength=len(order)).double()  # [C]
        draw = torch.randint(0, len(order), (n_resamples, len(order)), generator=gen)  # [R, C]
        means = sums[draw].sum(dim=1) / counts[draw].sum(dim=1)  # [R]
    q = torch.tensor([(1 - level) / 2, (1 + level) / 2], dtype=torch.float64)
    lo, hi = torch.quantile(means, q).tolist()
    mean = float(x.mean())
    return Interval(mean, min(lo, mean), max(hi, mean), len(x))


def overlap_bin(overlap: float, edges: Sequence[float] = OVERLAP_EDGES) -> str:
    """The bin label of a mean input overlap: ``"<0.2"``, ``"0.2-0.4"``, ..., ``">=0.6"``."""
    if math.isnan(overlap):
        return "unknown"
    for k, edge in enumerate(edges):
        if overlap < edge:
            return f"<{edge:g}" if k == 0 else f"{edges[k - 1]:g}-{edge:g}"
    return f">={edges[-1]:g}"


def bin_order(edges: Sequence[float] = OVERLAP_EDGES) -> list[str]:
    """The bins of :func:`overlap_bin` from the widest baseline (least overlap) up."""
    labels = [f"<{edges[0]:g}"] + [f"{a:g}-{b:g}" for a, b in zip(edges, edges[1:])]
    return labels + [f">={edges[-1]:g}", "unknown"]
