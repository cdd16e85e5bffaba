"""``prosplat train recipes`` and the ``--recipe`` options of ``train generator|improve``: the
shipped weights' recipes (:mod:`prosplat.train.recipes`), listed or run stage by stage."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from prosplat.cli.config_args import changed_options
from prosplat.train.recipe import RunPaths, describe
from prosplat.train.recipes import RECIPES, recipe_named, run


def add_recipe_arguments(parser: argparse.ArgumentParser, kind: str) -> None:
    """``--recipe NAME`` and what goes with it, for ``train generator`` (``kind``
    "generator") or ``train improve`` ("improve")."""
    names = [r.name for r in RECIPES.values() if r.kind == kind]
    group = parser.add_argument_group(
        "recipes",
        "Run a shipped weight's recipe instead (prosplat.train.recipes): its stages in order "
        "into --out/<stage>/, each resumed where it stopped and skipped when done; the last "
        "stage's file is the one that ships. Only --out and --device go with it.",
    )
    group.add_argument("--recipe", choices=names, default=None, help="the recipe to run")
    group.add_argument(
        "--list", action="store_true", help="print the recipe's stages and commands, run nothing"
    )
    group.add_argument("--until", default=None, metavar="STAGE", help="stop after this stage")
    group.add_argument(
        "--data-root",
        type=Path,
        default=Path("data"),
        help="folder of the rendered scene sets the stages read (default data)",
    )
    if kind == "improve":
        group.add_argument(
            "--generator-run",
            type=Path,
            default=None,
            help="run folder of the generator recipe whose stages render the curated sets "
            "(default: beside --out, named after that recipe); missing stages run there first",
        )


def run_recipe_command(args: argparse.Namespace, config_cls: type, command: str) -> int:
    """``prosplat train generator|improve --recipe NAME ...``: list or run it."""
    recipe = recipe_named(args.recipe)
    out = Path(args.out) if args.out else Path("runs") / recipe.name
    generator_run = getattr(args, "generator_run", None)
    used = {c.generator_stage[0] for s in recipe.stages for c in (*s.sets, s.val_set) if c}
    runs = {} if generator_run is None else dict.fromkeys(used, generator_run)
    if args.list:
        print(describe(recipe, RunPaths(out, args.data_root, runs)))
        return 0
    unused = changed_options(config_cls, args, keep=("out", "device"))
    if unused:
        print(
            f"prosplat {command}: --recipe takes each stage's own settings; "
            f"{', '.join(unused)} would not be used (only --out and --device go with it)",
            file=sys.stderr,
        )
        return 2
    if not args.out:
        print(f"prosplat {command}: --recipe needs --out (the run folder)", file=sys.stderr)
        return 2
    device = None if args.device == "auto" else args.device
    try:
        final = run(
            recipe.name, out, args.data_root, runs, until=args.until, device=device,
        )  # fmt: skip
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"prosplat {command}: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        print(f"prosplat {command}: {e or 'interrupted'}", file=sys.stderr)
        return 130
    print(f"{recipe.name}: {final.resolve()}")
    return 0


def no_recipe_without_data(args: argparse.Namespace, command: str) -> int | None:
    """2 (with the usage error) when a run without ``--recipe`` lacks ``--data``/``--out``, or
    asks for a recipe's options; None when it may go on."""
    missing = [f"--{n}" for n in ("data", "out") if not getattr(args, n)]
    if args.list or args.until:
        print(f"prosplat {command}: --list and --until go with --recipe", file=sys.stderr)
        return 2
    if missing:
        print(
            f"prosplat {command}: the following arguments are required: {', '.join(missing)} "
            "(or --recipe NAME)",
            file=sys.stderr,
        )
        return 2
    return None


def cmd_recipes(args: argparse.Namespace) -> int:
    """Every recipe (or one) with its stages and the commands that make them."""
    try:
        chosen = [recipe_named(args.name)] if args.name else list(RECIPES.values())
    except ValueError as e:
        print(f"prosplat train recipes: {e}", file=sys.stderr)
        return 2
    for i, recipe in enumerate(chosen):
        out = args.out if args.out and args.name else Path("runs") / recipe.name
        print(("\n" if i else "") + describe(recipe, RunPaths(out, args.data_root)))
    return 0


def add_parser(train_sub) -> None:
    """``prosplat train recipes`` into the ``train`` subparsers."""
    rp = train_sub.add_parser(
        "recipes",
        help="the shipped weights' recipes: their stages and the commands that make them",
        description="Print each recipe of prosplat.train.recipes (or NAME's): every stage with "
        "its start, seed, steps and data, and the commands that render the scenes, curate "
        "the stage-2 sets and train it. `prosplat train generator|improve --recipe NAME "
        "--out DIR` runs them.",
    )
    rp.add_argument("name", nargs="?", default=None, help="one recipe, e.g. generator-tiny")
    rp.add_argument("--out", type=Path, default=None, help="run folder (default runs/NAME)")
    rp.add_argument("--data-root", type=Path, default=Path("data"), help="folder of the scene sets")
    rp.set_defaults(func=cmd_recipes)
