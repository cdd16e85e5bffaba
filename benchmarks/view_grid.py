"""The figure grid that ``generator_views.py`` and ``stage2_views.py`` share: which scenes get
a row, how a panel is drawn, and where the figure goes."""

from __future__ import annotations

from pathlib import Path

from torch import Tensor

from prosplat.data import find_scenes


def spread_scenes(root: Path, count: int) -> list[Path]:
    """At most ``count`` scene folders under ``root``, spread evenly over its sorted list (so
    a folder of families in order gives one row per family)."""
    folders = find_scenes(root)
    return folders[:: max(1, len(folders) // count)][:count]


def draw_panel(ax, image: Tensor, title: str, row_label: str | None = None, **imshow) -> None:
    """``image`` [3,H,W] (clamped to [0,1]) or [H,W] (``imshow`` options, e.g. a colour map)
    on ``ax``, without ticks; ``row_label`` on the first column."""
    if image.dim() == 3:
        ax.imshow(image.permute(1, 2, 0).clamp(0, 1).numpy())
    else:
        ax.imshow(image.numpy(), **imshow)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title, fontsize=8)
    if row_label is not None:
        ax.set_ylabel(row_label, fontsize=7)


def save_figure(fig, out: Path) -> None:
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    print(f"wrote {out}")
