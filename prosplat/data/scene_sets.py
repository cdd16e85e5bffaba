"""The rendered scene sets the shipped weights and the ladder use, by name, each with the
``prosplat scenes render`` commands that make it; and subsets of a set by seed.

A set is a folder of scene folders named ``NAME_SEED`` (``prosplat scenes render``), so a seed
names one scene for good. Training sets grow in render rounds (``train128``: 60 family scenes
and 2 of each hard scene a round), and a training run keeps to the seeds it saw: its data is a
:func:`link_subset` of the set, a folder of links, rebuilt from the seeds whatever else has
been rendered since.

Seed ranges are written ``"FIRST-LAST FIRST-LAST ..."`` (single seeds too); ``hard:A-B`` adds
the hard scenes of render rounds A..B of the training block (two seeds per kind and round).
A set of one scene kind (``photo128``: ``object_ring`` only) names it, and every one of its
commands renders that kind whatever the seed.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

#: The hard scenes in the order their seed blocks are laid out.
HARD_KINDS: tuple[str, ...] = (
    "textureless",
    "specular",
    "near_far",
    "thin_structures",
    "repeated_pattern",
    "inside_outside",
)
#: Training block: family seeds from 10000 (60 a round), hard kind k at 20000 + 100 k + 2 round.
FIRST_FAMILY_SEED = 10_000
ROUND_FAMILY_SCENES = 60
FIRST_HARD_SEED = 20_000
HARD_KIND_STRIDE = 100
#: Test block: one scene of each hard kind from this seed, in HARD_KINDS' order.
FIRST_HARD_TEST_SEED = 950_100


def hard_round_seeds(first: int, last: int) -> list[int]:
    """The seeds of the hard training scenes of render rounds ``first..last``."""
    return [
        FIRST_HARD_SEED + HARD_KIND_STRIDE * k + 2 * r + j
        for k in range(len(HARD_KINDS))
        for r in range(first, last + 1)
        for j in (0, 1)
    ]


def parse_seeds(spec: str) -> tuple[int, ...]:
    """``"10000-10359 hard:0-4"`` -> the sorted seeds (see the module docstring).

    Raises:
        ValueError: a part that is not ``N``, ``A-B`` or ``hard:A-B`` with A <= B.
    """
    seeds: set[int] = set()
    for part in spec.split():
        hard = part.startswith("hard:")
        text = part.removeprefix("hard:")
        first, _, last = text.partition("-")
        try:
            a, b = int(first), int(last or first)
        except ValueError:
            raise ValueError(f"seed range {part!r} is not N, A-B or hard:A-B") from None
        if a > b:
            raise ValueError(f"seed range {part!r} runs backwards")
        seeds.update(hard_round_seeds(a, b) if hard else range(a, b + 1))
    return tuple(sorted(seeds))


def scene_name(seed: int) -> str | None:
    """The hard scene a seed of the training or test block renders, None for a family seed
    (``prosplat scenes render`` then picks the seed's family)."""
    if FIRST_HARD_SEED <= seed < FIRST_HARD_SEED + HARD_KIND_STRIDE * len(HARD_KINDS):
        return HARD_KINDS[(seed - FIRST_HARD_SEED) // HARD_KIND_STRIDE]
    if FIRST_HARD_TEST_SEED <= seed < FIRST_HARD_TEST_SEED + len(HARD_KINDS):
        return HARD_KINDS[seed - FIRST_HARD_TEST_SEED]
    return None


@dataclass(frozen=True)
class SceneSet:
    """A named set: its folder under the data root, the ``prosplat scenes render`` options its
    scenes are rendered with, and the seeds it holds (all of them, for a set that grows)."""

    name: str
    options: str  # size, views, samples, denoiser
    seeds: str  # seed ranges (parse_seeds)
    about: str = ""
    scene: str | None = None  # every seed renders this scene kind (default: scene_name's)

    def render_commands(
        self, seeds: str | Iterable[int] | None = None, root: str | Path = "data"
    ) -> list[str]:
        """The commands that render ``seeds`` (ranges or seeds; default: the whole set) into
        ``root/name``: one per run of consecutive seeds of one scene kind (the set's ``scene``,
        else :func:`scene_name`'s). They skip finished scenes, so a command re-run completes a
        partial set."""
        if seeds is None or isinstance(seeds, str):
            chosen = parse_seeds(seeds if seeds is not None else self.seeds)
        else:
            chosen = tuple(sorted(set(seeds)))
        runs: list[list[int]] = []
        for seed in chosen:
            if runs and seed == runs[-1][-1] + 1 and self.kind(seed) == self.kind(runs[-1][0]):
                runs[-1].append(seed)
            else:
                runs.append([seed])
        out = Path(root) / self.name
        commands = []
        for run in runs:
            kind = self.kind(run[0])
            commands.append(
                f"prosplat scenes render --seed {run[0]} --count {len(run)}"
                + (f" --scene {kind}" if kind else "")
                + f" {self.options} --out {out}"
            )
        return commands

    def kind(self, seed: int) -> str | None:
        """The scene kind ``seed`` renders in this set; None: the seed's family."""
        return self.scene or scene_name(seed)


_TRAIN128 = "--size 128 --inputs 6 --targets 10 --samples 8 --denoise --denoise-quality fast"
#: The evaluation sets as they were rendered (16 samples, the denoiser's high settings), so a
#: set rendered again gives the same pixels and the same tables.
_TEST = "--inputs 6 --targets 8 --samples 16 --denoise"
#: Photo-like captures: object_ring scenes (objects on a plain background, a ring of cameras)
#: with rolled cameras (up to 20 degrees) and a lens per scene in 24-85 mm, the train128
#: settings otherwise, for the object-centric photo sets (DTU, Middlebury) the families miss.
_PHOTO128 = f"{_TRAIN128} --roll 20 --lens-range 24-85"

#: The sets by name. ``train128`` lists its first 40 rounds; runs use subsets of it. Its
#: first rounds were rendered with 16 samples and the denoiser's high settings (each scene's
#: transforms.json records its own); today's commands render 8 and fast, as it grew since.
SCENE_SETS: dict[str, SceneSet] = {
    s.name: s
    for s in (
        SceneSet("train64", "--size 64 --inputs 4 --targets 8 --samples 16", "0-59",
                 "generator v0's 60 scenes"),
        SceneSet("train64b", "--size 64 --inputs 4 --targets 8 --samples 16", "1000-1149",
                 "150 more 64-px scenes (generator v1)"),
        SceneSet("val64", "--size 64 --inputs 4 --targets 8 --samples 16", "900000-900003",
                 "validation for generator v0 and v1"),
        SceneSet("train128", _TRAIN128, "10000-12399 hard:0-39",
                 "the training scenes since generator v2, in rounds of 60 family scenes + 2 "
                 "of each hard scene"),
        SceneSet("val128", "--size 128 --inputs 6 --targets 10 --samples 16 --denoise",
                 "900000-900007", "validation since generator v2"),
        SceneSet("train256", "--size 256 --inputs 4 --targets 8 --samples 8 --denoise",
                 "10000-10032", "33 training scenes at 256 px (stage 2 v13)"),
        SceneSet("test128", f"--size 128 {_TEST}", "950100-950105 987000-987017",
                 "the test ladder at 64 and 128 px: 6 hard + 18 family scenes"),
        SceneSet("test256", f"--size 256 {_TEST}", "987000-987005",
                 "the test ladder at 256 px (all 24: seeds 950100-950105 987000-987017)"),
        SceneSet("photo128", _PHOTO128, "30000-30999",
                 "object_ring scenes like object-centric photo sets: a ring of rolled cameras "
                 "with 24-85 mm lenses round objects on a plain background (train split)",
                 scene="object_ring"),
    )
}  # fmt: skip


def scene_folders(root: str | Path, seeds: Iterable[int]) -> list[Path]:
    """The scene folders of ``root`` with these seeds, in seed order.

    Raises:
        FileNotFoundError: seeds with no folder (named, with how many are missing).
    """
    root = Path(root)
    by_seed = {}
    if root.is_dir():
        for path in root.iterdir():
            tail = path.name.rpartition("_")[2]
            if tail.isdigit() and (path / "transforms.json").is_file():
                by_seed[int(tail)] = path
    seeds = list(seeds)
    missing = [s for s in seeds if s not in by_seed]
    if missing:
        shown = ", ".join(map(str, missing[:8])) + (" ..." if len(missing) > 8 else "")
        raise FileNotFoundError(
            f"{len(missing)} of {len(seeds)} scenes are not rendered in {root} (seeds {shown}); "
            "render them first (`prosplat scenes sets` prints the commands)"
        )
    return [by_seed[s] for s in seeds]


def link_subset(root: str | Path, seeds: Sequence[int], dest: str | Path) -> Path:
    """``dest``: a folder of relative links to the scenes of ``root`` with these seeds, made
    aside and moved into place, so a run can be repeated on exactly the scenes it saw while
    ``root`` grows. A ``dest`` that already holds exactly these links is left alone (runs
    started side by side on one subset keep their scenes); any other is replaced."""
    dest = Path(dest)
    folders = scene_folders(root, seeds)
    dest.parent.mkdir(parents=True, exist_ok=True)
    here = dest.parent.resolve() / dest.name
    want = {f.name: os.path.relpath(f.resolve(), here) for f in folders}
    if dest.exists() or dest.is_symlink():
        entries = list(dest.iterdir()) if dest.is_dir() and not dest.is_symlink() else [dest]
        if any(not p.is_symlink() for p in entries):
            raise FileExistsError(f"{dest} holds more than links to scenes; choose another folder")
        if {p.name: os.readlink(p) for p in entries} == want:
            return dest
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.parent))
    for name, target in want.items():
        (tmp / name).symlink_to(target)
    if dest.is_dir() and not dest.is_symlink():
        shutil.rmtree(dest)  # links only (checked above)
    elif dest.is_symlink():
        dest.unlink()
    tmp.rename(dest)
    return dest
