"""Train / validation / test splits, fixed by seed ranges so no test scene is ever trained on.

A scene's seed decides its split once and for all; ``prosplat scenes render --seed S``
renders the split that S falls in. Hard scenes use the test range.
"""

from __future__ import annotations

SPLITS: dict[str, range] = {
    "train": range(0, 900_000),
    "val": range(900_000, 950_000),
    "test": range(950_000, 1_000_000),
}


def split_of(seed: int) -> str:
    """The split a seed belongs to."""
    for name, seeds in SPLITS.items():
        if seed in seeds:
            return name
    raise ValueError(f"seed {seed} is outside every split (0 <= seed < 1,000,000)")


def first_seed(split: str) -> int:
    """The first seed of ``split`` ("train", "val" or "test")."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; use one of {list(SPLITS)}")
    return SPLITS[split].start


# Scene families the builders make; a seed's family is fixed so folder names are known
# before anything is rendered (``prosplat scenes render`` skips finished scenes by name).
FAMILIES: tuple[str, ...] = ("room", "tabletop", "open")


def family_for_seed(seed: int) -> str:
    """The family a seed builds when no scene name is given."""
    return FAMILIES[seed % len(FAMILIES)]
