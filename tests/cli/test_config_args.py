"""Options made from config dataclasses: each field's comment reaches ``--help``, types and
defaults follow the annotations, and the parsed options rebuild the config."""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field, fields

import pytest

from prosplat.cli import build_parser
from prosplat.cli.config_args import (
    add_config_arguments,
    changed_options,
    config_from_args,
    field_docs,
)
from prosplat.train.generator_config import TrainConfig
from prosplat.train.improve import ImproveTrainConfig, JointTrainConfig


@dataclass(frozen=True)
class Example:
    """A config with every kind of field the helper handles."""

    name: str  # what it is called
    # how many, a comment above
    # on two lines
    count: int = 3
    scale: float | None = None
    sizes: tuple[int, ...] = (64, 128)
    flip: bool = False  # mirror it
    level: int = field(default=1, metadata={"help": "from metadata, 100 %"})


def _parser(**kw) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="x")
    add_config_arguments(p, Example, **kw)
    return p


def test_comments_and_metadata_become_help_with_the_default():
    docs = field_docs(Example)
    assert docs["name"] == "what it is called"
    assert docs["count"] == "how many, a comment above on two lines"
    text = _parser().format_help()
    assert "how many, a comment above on two lines (default: 3)" in text
    assert "from metadata, 100 % (default: 1)" in text and "--no-flip" in text


def test_types_follow_the_annotations_and_the_config_comes_back():
    args = _parser().parse_args(
        ["--name", "a", "--count", "5", "--scale", "0.5", "--sizes", "32", "96", "--flip"]
    )
    assert config_from_args(Example, args) == Example("a", 5, 0.5, (32, 96), True)
    args = _parser().parse_args(["--name", "b"])
    assert config_from_args(Example, args) == Example("b")
    assert changed_options(Example, _parser().parse_args(["--name", "b", "--no-flip"])) == [
        "--name"
    ]
    with pytest.raises(SystemExit):
        _parser().parse_args([])  # --name has no default: required
    assert _parser(optional=("name",)).parse_args([]).name is None


def test_every_training_option_has_its_fields_documentation():
    for cls in (TrainConfig, ImproveTrainConfig, JointTrainConfig):
        docs = field_docs(cls)
        assert not [f.name for f in fields(cls) if not docs.get(f.name)], cls.__name__
    parser = build_parser()
    sub = parser._subparsers._group_actions[0].choices["train"]  # noqa: SLF001
    text = sub._subparsers._group_actions[0].choices["generator"].format_help()  # noqa: SLF001
    assert "score every render with its holes filled by pull-push" in text


def test_train_generator_keeps_its_option_names_and_values():
    argv = ["train", "generator", "--data", "d", "--out", "o", "--inputs", "2,4", "--fill-holes",
            "--any-view", "--grow-alexnet", "0", "--depth-loss", "log", "--stop-at", "7"]  # fmt: skip
    cfg = config_from_args(TrainConfig, build_parser().parse_args(argv))
    assert cfg == TrainConfig(data="d", out="o", inputs=(2, 4), fill_holes=True, any_view=True,
                              depth_loss="log", stop_at=7)  # fmt: skip
    with pytest.raises(SystemExit):
        build_parser().parse_args([*argv[:6], "--grow-alexnet", "9"])  # choices kept
