"""``prosplat eval posed``: its options and handler. The scoring (rows, tables, contact sheet)
is :mod:`prosplat.eval.posed`, whose docstring is the command's description; the options
and the posed-set preparation are shared with ``prosplat reconstruct``
(:mod:`prosplat.cli.reconstruct`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from torch import Tensor

from prosplat.cli.reconstruct import (
    add_common_arguments,
    anchors_of,
    load_model,
    missing_note,
    near_far,
    out_folder,
    prepare,
    refine_kwargs,
    render_selection,
    repeats_note,
    trust_line,
)
from prosplat.core.image_io import write_image
from prosplat.core.paths import staged_folder
from prosplat.eval import posed as engine
from prosplat.geometry.budget import budget_arg
from prosplat.pipeline.posed_views import load_posed_set, load_views
from prosplat.pipeline.trust import leave_one_out


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_common_arguments(p)
    p.add_argument(
        "--targets",
        type=int,
        default=8,
        help="held-out frames to score, evenly spread (default 8; 0 = all)",
    )
    p.add_argument(
        "--target-set",
        type=Path,
        default=None,
        help="take the targets from this other posed file in the same world frame (e.g. "
        "NeRF synthetic's transforms_test.json) instead of INPUT's held-out frames",
    )
    p.add_argument(
        "--input-sets",
        type=int,
        default=1,
        help="score this many choices of input views (farthest-point sampling started from "
        "frames spread over the set; the first is the default choice) and report their mean: "
        "one choice of inputs can swing the result by most of a dB (default 1)",
    )


def run(args: argparse.Namespace) -> int:
    try:
        out = out_folder(args.out, args.overwrite)
        keep = 0 if args.target_set else 1
        posed, inputs, background, bg_text, size = prepare(args, keep_targets=keep)
        target_set = posed
        if args.target_set:
            target_set = load_posed_set(args.target_set, None, skip_missing=args.skip_missing)
            if target_set.missing:
                print(missing_note(target_set))
            if target_set.repeats:
                print(repeats_note(target_set))
        sets = engine.input_sets(posed, inputs, args.input_sets, fixed=bool(args.inputs))
        model = load_model(args)
        kwargs = refine_kwargs(args.refine_steps, args.refine_seconds)
        name = posed.source.parent.name if posed.kind == "transforms" else posed.source.name
        cases, lines = [], []
        for k, chosen in enumerate(sets):
            held_out = [] if args.target_set else chosen
            targets = render_selection(target_set.names, held_out, ["held-out"], args.targets)
            if not targets:
                raise ValueError(
                    f"{posed.source} has no frames besides the {len(chosen)} inputs; nothing "
                    "to score (or give --target-set)"
                )
            images, cameras = load_views(posed, chosen, size, background, progress=True)
            t_images, t_cams = load_views(target_set, targets, size, background, progress=True)
            depth = near_far(
                posed, chosen, cameras, args.near, args.far, images, not args.no_triangulate
            )
            near, far, nf_source = depth.near, depth.far, depth.source
            anchors = anchors_of(depth, args)
            case_name = (name or "posed") + (f" set {k}" if len(sets) > 1 else "")
            cases.append(engine.PosedCase(images, cameras, t_images, t_cams, near, far, case_name,
                                          anchors))  # fmt: skip
            lines.append(f"{case_name}: inputs {', '.join(posed.views[i].name for i in chosen)}, "
                         f"{len(targets)} targets, near/far {near:.3g}/{far:.3g}")  # fmt: skip
        budget = budget_arg(args.budget)
        sheet: list[list[Tensor]] = []
        rows = engine.score_cases(model, cases, budget=budget, background=background,
                           reconstruct_kwargs=kwargs, sheet=sheet,
                           other_views_opacity=args.other_views_opacity)  # fmt: skip
        trust = [leave_one_out(model, c.images, c.cameras, c.near, c.far, anchors=c.anchors)
                 for c in cases]  # fmt: skip
        trust_lines = [
            (f"{c.name}: " if len(cases) > 1 else "") + trust_line(t) for c, t in zip(cases, trust)
        ]
        with staged_folder(out) as partial:  # moved to --out only when complete
            table = engine.write_results(rows, partial, args.overwrite)
            with open(partial / "summary.md", "a") as fh:
                fh.write("\n" + "\n".join(trust_lines) + "\n")
            table += "\n\n" + "\n".join(trust_lines)
            (partial / "trust.json").write_text(
                json.dumps({c.name: t.as_dict() for c, t in zip(cases, trust)}, indent=1)
            )
            if len(sets) > 1:
                per_set = engine.per_set_table(rows)
                with open(partial / "summary.md", "a") as fh:
                    fh.write("\n" + "\n".join(lines) + "\n\n" + per_set + "\n")
                table += "\n\n" + per_set
            write_image(
                partial / "views.png", engine.contact_sheet(sheet), overwrite=args.overwrite
            )
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"prosplat eval posed: {' '.join(str(e).split())}", file=sys.stderr)
        return 2
    if len(sets) > 1:
        print(
            f"{len(sets)} choices of inputs of {posed.source}, targets from {target_set.source} "
            f"({target_set.kind}), at {size[0]}x{size[1]}; near/far from {nf_source}; "
            f"background {bg_text}"
        )
        print("\n".join(lines))
    else:
        names = ", ".join(posed.views[i].name for i in inputs)
        print(
            f"{len(targets)} held-out frames of {target_set.source} ({target_set.kind}) from "
            f"inputs {names} of {posed.source} at "
            f"{size[0]}x{size[1]}; near/far {near:.3g}/{far:.3g} ({nf_source}); background "
            f"{bg_text}"
        )
    print(table)
    shown = [m for m in engine.ROWS if f"| {m} |" in table]
    print(
        f"wrote {out / 'summary.md'}, scores.csv, scores.json, trust.json and views.png (the first "
        f"{len(sheet)} targets: ground truth, {', '.join(shown)})"
    )
    return 0
