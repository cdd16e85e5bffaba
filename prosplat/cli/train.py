"""``prosplat train generator|recipes|curate|improve|joint|blend``: training on rendered scenes.

``train generator``'s options are :class:`~prosplat.train.generator_config.TrainConfig`'s
fields (:mod:`prosplat.cli.config_args`), so each field's comment is its ``--help``; the
stage-2 subcommands live in :mod:`prosplat.cli.improve`, the recipes in
:mod:`prosplat.cli.recipes`.
"""

from __future__ import annotations

import argparse
import os

from prosplat.cli import improve, recipes
from prosplat.cli.config_args import add_config_arguments, config_from_args
from prosplat.generator.config import MAX_ALEXNET_LAYERS, PRESETS
from prosplat.train.generator_config import DEPTH_LOSSES, TrainConfig, parse_inputs

#: argparse's own settings for TrainConfig fields (the help comes from the fields' comments).
GENERATOR_OPTIONS = {
    "config": {"choices": sorted(PRESETS)},
    "inputs": {"type": parse_inputs},
    "depth_loss": {"choices": DEPTH_LOSSES},
    "grow_fine_matching": {"metavar": "CH"},
    "grow_image_matching": {"metavar": "PX"},
    "grow_band": {"metavar": "N"},
    "grow_alexnet": {"choices": range(MAX_ALEXNET_LAYERS + 1), "metavar": "N"},
}


def cmd_train_generator(args: argparse.Namespace) -> int:
    if args.recipe:
        return recipes.run_recipe_command(args, TrainConfig, "train generator")
    refused = recipes.no_recipe_without_data(args, "train generator")
    if refused is not None:
        return refused
    from prosplat.train.generator import train  # torch and the model: only when training

    cfg = config_from_args(TrainConfig, args)
    path = train(cfg)
    if int(os.environ.get("RANK", "0")) == 0:  # once, not once per torchrun process
        print(f"checkpoint: {path.resolve()}")
        if path.suffix == ".pth":  # a DepthSplat fine-tune
            print(f"use it with: prosplat reconstruct --generator {path.resolve()} ...")
    return 0


def add_parser(sub) -> None:
    """``prosplat train ...`` into the top-level subparsers ``sub``."""
    train = sub.add_parser("train", help="train models on rendered scenes")
    train_sub = train.add_subparsers(dest="train_command", required=True)
    tg = train_sub.add_parser(
        "generator",
        help="train the stage-1 generator",
        description="Train the feed-forward generator on scene folders (prosplat scenes render). "
        "Re-running with the same --out resumes from its last checkpoint. One GPU or "
        "the CPU: run as is; several GPUs: torchrun --nproc_per_node K -m prosplat "
        "train generator ... With --recipe NAME, the stages of a shipped weight's recipe "
        "instead (prosplat train recipes lists them).",
    )
    add_config_arguments(tg, TrainConfig, optional=("data", "out"), extra=GENERATOR_OPTIONS)
    recipes.add_recipe_arguments(tg, "generator")
    tg.set_defaults(func=cmd_train_generator)
    recipes.add_parser(train_sub)
    improve.add_train_parsers(train_sub)
