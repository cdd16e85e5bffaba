"""Command-line options made from a config dataclass, so the options never drift from the
settings a run records and each field's documentation is its ``--help``.

Each field becomes ``--field-name`` (``dest`` the field's name). Its help is, first found:
``field(metadata={"help": ...})``, then the comment lines right above the field or on its line
in the class's source; the default is appended. Types come from the annotations: ``bool`` ->
``--flag/--no-flag``, ``X | None`` -> ``X`` (default None), ``tuple[X, ...]`` -> ``nargs="+"``
of ``X``; anything else needs ``extra={"field": {"type": parser}}``. ``extra`` also carries
argparse's own choices, metavar or help for a field, which the config need not know about.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import textwrap
import types
import typing
from collections.abc import Collection, Mapping
from functools import cache
from pathlib import PurePath
from typing import Any


@cache
def field_docs(cls: type) -> dict[str, str]:
    """Field name -> the comment that documents it in ``cls``'s source (the ``#`` lines right
    above it, then a comment on its own line), joined into one paragraph; empty without source."""
    try:
        lines, _ = inspect.getsourcelines(cls)
    except (OSError, TypeError):  # no source (a frozen app): options without help
        return {}
    source = textwrap.dedent("".join(lines))
    rows = source.splitlines()
    docs = {}
    for node in ast.parse(source).body[0].body:
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        above = []
        row = node.lineno - 2  # the line above the field, 0-based
        while row >= 0 and rows[row].strip().startswith("#"):
            above.insert(0, rows[row].strip().lstrip("#").strip())
            row -= 1
        line = rows[node.end_lineno - 1]
        trailing = line.split("  # ", 1)[1].strip() if "  # " in line else ""
        docs[node.target.id] = " ".join(part for part in (*above, trailing) if part)
    return docs


def _option_type(hint: Any) -> tuple[Any, dict[str, Any]]:
    """(argparse type, extra keywords) for a resolved annotation."""
    args = typing.get_args(hint)
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        kinds = [a for a in args if a is not type(None)]
        if len(kinds) == 1:
            return _option_type(kinds[0])
        raise TypeError(f"give a type for the union {hint} in extra=")
    if typing.get_origin(hint) is tuple and len(args) == 2 and args[1] is Ellipsis:
        return args[0], {"nargs": "+"}
    if hint in (int, float, str):
        return hint, {}
    raise TypeError(f"give a type for {hint} in extra=")


def add_config_arguments(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    cls: type,
    *,
    skip: Collection[str] = (),
    optional: Collection[str] = (),
    extra: Mapping[str, Mapping[str, Any]] | None = None,
) -> None:
    """One option per field of the dataclass ``cls`` (see the module docstring). Fields without
    a default are required options unless named in ``optional`` (then their default is None,
    for a command that checks them itself); ``skip`` leaves fields out."""
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        spec = dict((extra or {}).get(f.name, {}))
        has_default = f.default is not dataclasses.MISSING
        default = f.default if has_default else None
        doc = spec.pop("help", None) or f.metadata.get("help") or docs.get(f.name, "")
        doc = doc.replace("%", "%%")  # argparse formats help with %
        if has_default:
            shown = str(default) if isinstance(default, PurePath) else repr(default)
            doc = f"{doc} (default: {shown})" if doc else f"(default: {shown})"
        flag = f"--{f.name.replace('_', '-')}"
        if hints[f.name] is bool:
            spec.setdefault("action", argparse.BooleanOptionalAction)
        elif "type" not in spec:
            kind, more = _option_type(hints[f.name])
            spec = {"type": kind, **more, **spec}
        required = not has_default and f.name not in optional
        parser.add_argument(flag, dest=f.name, default=default, required=required, help=doc, **spec)


def config_from_args(cls: type, args: argparse.Namespace, **given: Any):
    """``cls`` built from the parsed options of :func:`add_config_arguments` (``given``
    replaces or supplies fields); tuples come back as tuples, not argparse's lists."""
    values = {}
    for f in dataclasses.fields(cls):
        if f.name in given:
            values[f.name] = given[f.name]
        elif hasattr(args, f.name):
            value = getattr(args, f.name)
            values[f.name] = tuple(value) if isinstance(value, list) else value
    return cls(**values)


def changed_options(cls: type, args: argparse.Namespace, keep: Collection[str] = ()) -> list[str]:
    """The ``--options`` of ``cls``'s fields given a value other than their default (those in
    ``keep`` aside): for a command that refuses settings it would not use."""
    changed = []
    for f in dataclasses.fields(cls):
        if f.name in keep or not hasattr(args, f.name):
            continue
        default = f.default if f.default is not dataclasses.MISSING else None
        if getattr(args, f.name) != default:
            changed.append(f"--{f.name.replace('_', '-')}")
    return changed
