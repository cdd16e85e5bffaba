"""``prosplat reconstruct``: your own posed images -> Gaussians (PLY) and enhanced renders.

INPUT is a ``transforms.json`` (nerfstudio, instant-ngp, NeRF synthetic; OpenCV or fisheye
distortion allowed) or a COLMAP model (text or binary) with its images; or a folder of photos
with no poses, or a video: then the photos are posed first into ``--out``'s ``poses/``
(``prosplat poses``; ``--feature-size``, ``--matching``), a re-run with the same photos and
options reuses them, and the inputs are picked among the registered photos
(:mod:`prosplat.cli.photo_input`). The command

1. picks 2-6 input views (``--num-inputs`` by farthest-point sampling of the camera centres,
   or ``--inputs`` names / indices);
2. reads them: RGBA composited over ``--background`` (white by default for NeRF-synthetic
   data), undistorted onto pinhole cameras, resized to ``--size`` (default: the resolution
   the shipped weights were trained at) with the intrinsics scaled to match;
3. takes near/far from ``--near/--far``, else from the transforms file's ``near``/``far``
   (per frame or top level), else from the COLMAP points the inputs see, else from points
   triangulated from the inputs with their poses (pycolmap; ``--no-triangulate`` skips it),
   else from the cameras (:func:`prosplat.geometry.rig.near_far_from_cameras`);
4. reconstructs, prunes to the Gaussian budget (``--budget``), optionally refines what the
   budget kept against the inputs (``--refine-steps/--refine-seconds``, with a progress
   bar) and writes ``gaussians.ply``;
5. renders ``--render`` cameras (``held-out``, ``all``, ``none``, names, or a camera path:
   a ``transforms.json`` of pinhole cameras) raw and enhanced, and with ``--distill-steps``
   once more from the Gaussians fitted to the inputs and those enhanced views
   (:mod:`prosplat.pipeline.distill`: views that agree with each other);
6. writes ``report.md`` (for photos: how many were registered, each one that was not, each
   file skipped) and ``transforms.json`` (the undistorted, resized inputs, in ``inputs/``),
   so the result opens in Blender with its cameras.

--out must be new or empty; ``--overwrite`` lets it replace this command's own files there.
Everything is written into a hidden folder beside --out and moved there only when complete,
so a failure or Ctrl-C leaves no half-written folder (with ``--overwrite``, each file or
folder the run made replaces the one of the same name; nothing else there is touched).

Frames that list an image an earlier frame lists are left out (with a warning), and frames
whose cameras coincide count as one view when the inputs are picked; fewer than 2 distinct
camera poses is refused with one line.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

from prosplat.cli import photo_input
from prosplat.cli.options import float_between
from prosplat.core.paths import staged_folder
from prosplat.geometry.depth_edges import EDGE_CHOICES
from prosplat.pipeline.distill import DEFAULT_DISTILL_STEPS
from prosplat.pipeline.enhance import OTHER_VIEWS_OPACITY
from prosplat.pipeline.trust import TrustEstimate, leave_one_out

__all__ = [
    "DEFAULT_INPUTS",
    "ReconstructResult",
    "add_arguments",
    "add_common_arguments",
    "trust_line",
    "near_far",
    "out_folder",
    "path_cameras",
    "prepare",
    "refine_kwargs",
    "render_selection",
    "run",
    "run_reconstruct",
]


#: input views picked when --num-inputs is not given (if the set has that many frames)
DEFAULT_INPUTS = 4


def add_common_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by ``prosplat reconstruct`` and ``prosplat eval posed``."""
    from prosplat.pipeline.model import TRAINED_SIZE

    p.add_argument(
        "input",
        type=Path,
        help="transforms.json (or its folder) or a COLMAP model; for reconstruct also a folder "
        "of photos without poses, or a video (posed first, into OUT/poses)",
    )
    p.add_argument("--out", type=Path, required=True, help="output folder (new or empty)")
    p.add_argument("--images", type=Path, default=None, help="image folder, if not the usual")
    p.add_argument(
        "--skip-missing",
        action="store_true",
        help="leave out frames whose image file is missing (named in the output) instead of "
        "stopping; published sets list frames they do not ship",
    )
    p.add_argument(
        "--inputs",
        nargs="+",
        default=None,
        metavar="NAME",
        help="input views by name (file stem) or index; default: --num-inputs picked by "
        "farthest-point sampling of the camera centres",
    )
    p.add_argument(
        "--num-inputs",
        type=int,
        default=None,
        help=f"input views to pick, 2-6 (default {DEFAULT_INPUTS}, fewer on smaller sets)",
    )
    p.add_argument(
        "--size",
        type=int,
        default=TRAINED_SIZE,
        help=f"image height in px the inputs are loaded, refined and rendered at, a multiple of "
        f"32 (default {TRAINED_SIZE}: what the shipped weights were trained at; the generator "
        "never runs above its trained size); the width keeps the aspect",
    )
    p.add_argument(
        "--background",
        default=None,
        help="RGBA images go over this: white, black or R,G,B (default: white for "
        "NeRF-synthetic data, black otherwise)",
    )
    p.add_argument("--near", type=float, default=None, help="near depth (default: estimated)")
    p.add_argument("--far", type=float, default=None, help="far depth (default: estimated)")
    p.add_argument(
        "--anchors",
        action="store_true",
        help="scale each input's depth to agree with the points (COLMAP's or triangulated) it "
        "observes, before the depth sweep (off by default: on four real sets it moved the "
        "enhanced view by -1.1 to +0.4 dB; BENCHMARKS 'Depth range from the inputs' own points')",
    )
    p.add_argument(
        "--no-triangulate",
        action="store_true",
        help="estimate near/far from the cameras where the pose file brings no near/far or "
        "points, instead of from points triangulated from the inputs (SIFT and COLMAP's "
        "triangulator with the known poses, about 0.4 s for four 256-px inputs; needs pycolmap)",
    )
    p.add_argument("--weights", default=None, help="generator checkpoint (default: shipped)")
    p.add_argument(
        "--generator",
        default=None,
        help="a DepthSplat checkpoint (.pth, downloaded by you) as stage 1 instead of --weights",
    )
    p.add_argument("--improve", default=None, help="stage-2 checkpoint (default: shipped)")
    p.add_argument(
        "--no-depth-sweep",
        action="store_true",
        help="skip the local plane sweep that moves the generator's depth to where the inputs "
        "match (prosplat.pipeline.depth_sweep; on by default for prosplat generators: +0.3 dB enhanced, "
        "about 1 s at 128 px)",
    )
    p.add_argument(
        "--depth-edges",
        choices=EDGE_CHOICES,
        default=None,
        help="the Gaussians of pixels inside a depth ramp between two surfaces (the curtains "
        "a generator's smooth depth hangs between a wall and what lies behind it) are dropped, "
        "snapped onto the nearer surface, or left as they are (prosplat.geometry.depth_edges; "
        "default: the model's own)",
    )
    p.add_argument(
        "--budget",
        type=float,
        default=None,
        help="Gaussians to keep: a count or a fraction (default: automatic)",
    )
    p.add_argument(
        "--merge-flat",
        action="store_true",
        help="merge flat 2x2 blocks of the Gaussians placed above the generator's matching size "
        "into one each (prosplat.geometry.merge): at 512 px about a third fewer Gaussians at "
        "level PSNR and LPIPS, for a smaller PLY and a lighter Blender viewport; views are not "
        "faster (BENCHMARKS 'Merging flat blocks'). Off by default",
    )
    p.add_argument(
        "--cross-view-fade",
        type=float_between(0.0, 1.0),
        default=None,
        metavar="F",
        help="check each Gaussian against the other input views' depth and multiply its "
        "opacity by F once per view that saw through it (0 drops it; "
        "prosplat.geometry.consistency). On the twelve 512-px test scenes F=0.3 took the "
        "floaters from 12.7 %% to 8.9 %% of the pixels at +0.09 dB, but cost 0.5 dB on eight "
        "real photo sets (BENCHMARKS 'Cross-view check'). Off by default",
    )
    p.add_argument(
        "--other-views-opacity",
        type=float,
        default=OTHER_VIEWS_OPACITY,
        help="rendered views take their colour mostly from the input nearest them (MORI's pick), "
        "the other inputs' Gaussians at up to this fraction of their opacity where they overlap, "
        "less the farther they are; the coverage is all of them "
        f"(default {OTHER_VIEWS_OPACITY:g}; 1: every input alike)",
    )
    p.add_argument(
        "--refine-steps",
        type=int,
        default=None,
        help="fit the Gaussians to the inputs for this many steps after the budget (default "
        "none; 0: none). On real photos 1000 steps beat the pasted nearest input in PSNR and "
        "LPIPS (the fox, README 'Refinement'); on synthetic scenes 100 buy most of the gain",
    )
    p.add_argument(
        "--refine-seconds",
        type=float,
        default=None,
        help="... or for this many seconds (> 0), instead of --refine-steps",
    )
    p.add_argument("--overwrite", action="store_true", help="allow a non-empty --out")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_common_arguments(p)
    photo_input.add_pose_arguments(p)
    p.add_argument(
        "--render",
        nargs="+",
        default=["held-out"],
        metavar="WHICH",
        help="cameras to render raw + enhanced: held-out (default), all, none, names / "
        "indices of frames, or a camera path (a transforms.json of pinhole cameras)",
    )
    p.add_argument(
        "--fill-holes",
        action="store_true",
        help="where no input saw the scene, continue the render's own colours instead of "
        "black (prosplat.render.hole_fill): writes NAME_filled.png beside NAME_raw.png, and "
        "the enhanced renders blend with that fill where the Gaussians do not cover them; "
        "not for sets composited over a background",
    )
    p.add_argument(
        "--no-trust-check",
        action="store_true",
        help="skip the leave-one-out check before rendering (each input left out, the rest "
        "reconstructed at 128 px and its camera re-rendered, against its nearest photo "
        "pasted there; prosplat.pipeline.trust): it warns in one line when the views would "
        "score below simply showing the nearest photo, and costs one small reconstruction "
        "per input (up to 4)",
    )
    p.add_argument(
        "--max-renders",
        type=int,
        default=8,
        help="render at most this many held-out cameras, evenly spread (default 8; 0 = all)",
    )
    p.add_argument(
        "--distill-steps",
        type=int,
        nargs="?",
        const=DEFAULT_DISTILL_STEPS,
        default=0,
        help="fit the Gaussians to the inputs and the enhanced renders together for N steps "
        f"(prosplat.pipeline.distill; bare: {DEFAULT_DISTILL_STEPS}, measured best) and render every "
        "camera again from them: "
        "NAME_distilled.png and gaussians_distilled.ply, views that agree with each other "
        "(a camera path does not flicker); default 0: off",
    )


def out_folder(out: Path, overwrite: bool, keep=None) -> Path:
    """``out`` when it is new, empty, or ``overwrite``; otherwise a ValueError: nothing the
    user owns is written over. Entries ``keep(name)`` is true for do not count (the poses of
    an earlier run on the same photos: :func:`prosplat.cli.photo_input.is_pose_entry`). (Not
    ``prosplat.cli._fresh_folder``, which picks ``out-N`` instead and would make this module
    import the CLI that imports it.)"""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file; give a folder")
    mine = out.exists() and any(not (keep and keep(e.name)) for e in out.iterdir())
    if mine and not overwrite:
        raise ValueError(
            f"--out {out} is not empty; pick a new folder or pass --overwrite to replace this "
            "command's files there"
        )
    return out


def refine_kwargs(steps: int | None, seconds: float | None) -> dict:
    """``refine_steps`` / ``refine_seconds`` for ``ProSplat.reconstruct``, only those given.

    Raises:
        ValueError: a negative step count, a time budget <= 0, or both a step count > 0 and
            a time budget (checked before any work).
    """
    from prosplat.pipeline.refine import check_refine_args

    check_refine_args(0 if steps is None else steps, seconds, one_run=True)
    kwargs = {}
    if steps is not None:
        kwargs["refine_steps"] = steps
    if seconds is not None:
        kwargs["refine_seconds"] = seconds
    return kwargs


def path_cameras(which: list[str], size: tuple[int, int]) -> list[tuple[str, object]]:
    """(name, camera) of a camera path given as ``--render PATH.json`` (a transforms file with
    pinhole cameras, e.g. written by the add-on or nerfstudio), at the model resolution:
    ``size`` (W, H) when the aspect matches, else the same height."""
    from prosplat.convert.nerfstudio import read_transforms
    from prosplat.pipeline.posed_views import model_size

    if not (len(which) == 1 and which[0].lower().endswith(".json")):
        return []
    tf = read_transforms(which[0], image_size=size)
    out = []
    for k, f in enumerate(tf.frames):
        c = f.camera
        wh = (
            size
            if c.width * size[1] == c.height * size[0]
            else model_size(c.width, c.height, size[1])
        )
        out.append((f"path_{k:03d}_{Path(f.file_path).stem}", c.resized(*wh)))
    return out


def render_selection(
    names: list[str], inputs: list[int], which: list[str], max_held_out: int
) -> list[int]:
    """Frame indices ``--render`` asks for (``held-out`` evenly thinned to ``max_held_out``)."""
    if which == ["none"]:
        return []
    if len(which) == 1 and which[0].lower().endswith(".json"):
        return []  # a camera path: see path_cameras
    if which == ["all"]:
        return list(range(len(names)))
    if which == ["held-out"]:
        rest = [i for i in range(len(names)) if i not in inputs]
        if max_held_out and len(rest) > max_held_out:
            step = len(rest) / max_held_out
            rest = [rest[int(k * step)] for k in range(max_held_out)]
        return rest
    out = []
    for s in which:
        if s in names:
            out.append(names.index(s))
        elif s.isdigit() and int(s) < len(names):
            out.append(int(s))
        else:
            raise ValueError(
                f"--render: {s!r} is not held-out, all, none, a frame name or an index "
                f"0-{len(names) - 1}"
            )
    return out


@dataclass
class ReconstructResult:
    out: Path
    inputs: list[str]
    rendered: list[str]
    near: float
    far: float
    near_far_source: str
    background: str
    gaussians: int
    size: tuple[int, int]
    timings: dict[str, float] = field(default_factory=dict)
    #: the pose step, when the input was photos or a video (None for a posed set)
    photos: photo_input.PhotoPoses | None = None
    #: the leave-one-out estimate (:mod:`prosplat.pipeline.trust`), None when not run
    trust: TrustEstimate | None = None


def near_far(posed, inputs: list[int], cameras, near, far, images=None, triangulate: bool = True):
    """The :class:`~prosplat.pipeline.depth_range.DepthRange` (near/far, where they came
    from, the points) of :func:`prosplat.pipeline.depth_range.depth_range`:
    the flags, else the file's own near/far, else the COLMAP points the inputs observe, else
    points triangulated from ``images [V,3,H,W]`` (when given, ``triangulate`` and pycolmap),
    else :func:`~prosplat.geometry.rig.near_far_from_cameras`."""
    from prosplat.pipeline.depth_range import depth_range

    points = observed = None
    if len(posed.points):
        points = posed.points
        observed = [posed.observed.get(posed.views[i].name, torch.zeros(0, dtype=torch.long))
                    for i in inputs]  # fmt: skip
    return depth_range(
        images, cameras, near=near, far=far, file_range=posed.file_near_far(inputs),
        file_name=posed.source.name, points=points, observed=observed,
        triangulate=triangulate and images is not None, given_name="--near/--far",
    )  # fmt: skip


def prepare(args: argparse.Namespace, keep_targets: int = 0):
    """Shared first half of reconstruct and eval posed: posed set, inputs, background, size.
    Without --num-inputs, :data:`DEFAULT_INPUTS` views are picked, or fewer on a set that
    has fewer frames (leaving ``keep_targets`` frames as targets, but at least 2 inputs)."""
    from prosplat.pipeline.posed_views import (
        load_posed_set,
        model_size,
        pick_views,
        resolve_background,
    )

    if not 0 <= args.other_views_opacity <= 1:
        raise ValueError(
            f"--other-views-opacity must lie in [0, 1], got {args.other_views_opacity}"
        )
    posed = load_posed_set(args.input, args.images, skip_missing=args.skip_missing)
    if posed.missing:
        print(missing_note(posed))
    if posed.repeats:
        print(repeats_note(posed))
    count = args.num_inputs
    if count is None:  # coincident cameras are one view (pick_views)
        distinct = sum(i == first for i, first in enumerate(posed.first_of_pose()))
        count = max(2, min(DEFAULT_INPUTS, distinct - keep_targets))
    inputs = pick_views(posed, args.inputs, count)
    background, bg_text = resolve_background(posed, args.background)
    first = posed.views[inputs[0]].camera
    size = model_size(first.width, first.height, args.size)
    return posed, inputs, background, bg_text, size


def missing_note(posed) -> str:
    """One line naming the frames ``--skip-missing`` left out (the first few)."""
    shown = ", ".join(posed.missing[:5]) + (", ..." if len(posed.missing) > 5 else "")
    return (
        f"left out {len(posed.missing)} frames of {posed.source} whose images are missing "
        f"({shown}); {len(posed.views)} frames remain"
    )


def repeats_note(posed) -> str:
    """One warning line naming the frames left out because an earlier frame lists the same
    image (the first few)."""
    more = ", ..." if len(set(posed.repeats)) > 5 else ""
    shown = ", ".join(list(dict.fromkeys(posed.repeats))[:5]) + more
    return (
        f"warning: left out {len(posed.repeats)} frames of {posed.source} that list an image "
        f"an earlier frame lists ({shown}); {len(posed.views)} remain"
    )


def load_model(args: argparse.Namespace):
    from prosplat.pipeline.model import ProSplat

    improve = args.improve if args.improve else True
    generator = getattr(args, "generator", None)
    if generator and args.weights:
        raise ValueError("pass either --weights (a prosplat generator) or --generator (DepthSplat)")
    sweep = False if getattr(args, "no_depth_sweep", False) else None
    model = ProSplat.from_pretrained(
        args.weights, generator=generator, improve=improve, depth_sweep=sweep
    )
    if getattr(args, "merge_flat", False):
        from prosplat.geometry.merge import MergeOptions

        model.merge_flat = MergeOptions()
    fade = getattr(args, "cross_view_fade", None)
    if fade is not None:
        from prosplat.geometry.consistency import CrossViewOptions

        model.cross_view = CrossViewOptions(fade=fade)
    edges = getattr(args, "depth_edges", None)
    if edges is not None:
        from prosplat.geometry.depth_edges import edge_options

        model.depth_edges = edge_options(edges)
    return model


def reconstruct_gaussians(model, images, cameras, near, far, args, anchors=None) -> tuple:
    """(Gaussians, seconds, note): generator + budget pruning, then refinement when asked;
    ``anchors`` (:class:`~prosplat.geometry.anchors.DepthAnchors`) scale each view's depth.

    ``--budget`` prunes in both cases (refinement fits only the Gaussians the budget keeps,
    :meth:`~prosplat.ProSplat.reconstruct`), and refinement shows a progress bar
    (steps, or seconds under ``--refine-seconds``) and its statistics in the note, since it
    is the one step here that can run for tens of seconds."""
    from tqdm import tqdm

    from prosplat.geometry.budget import budget_arg

    budget = budget_arg(args.budget)
    t0 = time.perf_counter()
    # the flags were checked by run_reconstruct before any work (refine_kwargs); 0 is "off"
    steps, seconds = args.refine_steps or None, args.refine_seconds or None
    if steps is None and seconds is None:
        rec = model.reconstruct(images, cameras, near, far, budget=budget, anchors=anchors)
        note = _kept_note(rec.prune_stats) + anchor_note(rec.anchor_fits)
        return rec.gaussians, time.perf_counter() - t0, note
    # under a time budget the bar counts seconds, so it ends where the budget does
    total = steps if steps is not None else round(seconds, 1)
    unit = "step" if steps is not None else "s"
    fmt = None if steps is not None else "{l_bar}{bar}| {n:.1f}/{total:.1f} s [{elapsed}{postfix}]"
    with tqdm(total=total, desc="refining against the inputs", unit=unit, bar_format=fmt) as bar:
        t_fit = time.perf_counter()

        def progress(step: int, _total, loss: float) -> None:
            done = step if steps is not None else min(time.perf_counter() - t_fit, total)
            bar.set_postfix(loss=f"{loss:.4f}", refresh=False)
            bar.update(done - bar.n)  # tqdm redraws at most every 0.1 s

        rec = model.reconstruct(
            images, cameras, near, far, budget=budget, refine_steps=steps,
            refine_seconds=seconds, progress=progress, anchors=anchors,
        )  # fmt: skip
    st = rec.refine_stats
    note = (
        f"{_kept_note({**rec.prune_stats, 'kept': st.n_gaussians})}; refined {st.steps} steps "
        f"in {st.seconds:.1f} s, input-view loss {st.initial_loss:.4f} -> {st.final_loss:.4f}"
    ) + anchor_note(rec.anchor_fits)
    return rec.gaussians.detach(), time.perf_counter() - t0, note


def anchors_of(depth, args: argparse.Namespace):
    """The depth anchors ``--anchors`` asks for: the points that gave the depth range; None
    without the flag, or (said in one line) when the range came from elsewhere."""
    if not args.anchors:
        return None
    if depth.anchors is None:
        print(f"--anchors: no points anchor these inputs (near/far from {depth.source})")
    return depth.anchors


def anchor_note(fits) -> str:
    """'; depth scaled to the points in K of V views (x0.94, ...)', or '' without anchors."""
    if not fits:
        return ""
    used = [f for f in fits if f.used]
    factors = ", ".join(f"x{f.scale:.3f}" for f in used)
    return f"; depth scaled to the points in {len(used)} of {len(fits)} views" + (
        f" ({factors})" if used else ""
    )


def _kept_note(stats: dict) -> str:
    """What the budget (and ``--merge-flat``, when it merged) left, for the report."""
    note = f"budget kept {stats['kept']:,} of {stats['input']:,}"
    if stats.get("merged"):
        note += f" ({stats['merged']:,} merged away in flat 2x2 blocks)"
    if stats.get("faded"):
        note += f"; {stats['faded']:,} faded where another input saw through them"
    return note


def run_reconstruct(args: argparse.Namespace) -> ReconstructResult:
    """Everything ``prosplat reconstruct`` does (see the module docstring), written aside and
    moved to ``--out`` only when complete (:func:`~prosplat.core.paths.staged_folder`): a
    failure or Ctrl-C leaves no half-written folder, and ``--out`` as it was."""
    kind = photo_input.photo_input(args.input)
    keep = photo_input.is_pose_entry if kind else None
    out = out_folder(args.out, args.overwrite, keep)  # refused before any work
    photos = None
    if kind:  # posed into out/poses before the rest is staged: a failure below keeps them
        photo_input.check_before_posing(args)
        _check_flags(args)
        photos = photo_input.pose_step(args, out, kind)
    with staged_folder(out) as partial:
        result = _reconstruct_into(partial, args, photos)
    result.out = out
    return result


def _check_flags(args: argparse.Namespace) -> None:
    """The flag checks that need no posed set, before a pose step that takes minutes."""
    from prosplat.pipeline.posed_views import model_size

    if not 0 <= args.other_views_opacity <= 1:
        raise ValueError(
            f"--other-views-opacity must lie in [0, 1], got {args.other_views_opacity}"
        )
    model_size(args.size, args.size, args.size)  # a multiple of 32
    refine_kwargs(args.refine_steps, args.refine_seconds)
    if args.distill_steps < 0:
        raise ValueError(f"--distill-steps must be >= 0 (0: off), got {args.distill_steps}")


def _reconstruct_into(out: Path, args: argparse.Namespace, photos=None) -> ReconstructResult:
    """:func:`run_reconstruct`'s work, every file written into the new folder ``out``."""
    from tqdm import tqdm

    from prosplat.convert.nerfstudio import Frame, write_transforms
    from prosplat.core.image_io import write_image
    from prosplat.core.ply import write_ply
    from prosplat.pipeline.posed_views import load_views, view_camera
    from prosplat.render.hole_fill import fill_holes as hole_fill

    t_start = time.perf_counter()
    posed, inputs, background, bg_text, size = prepare(args)
    which = render_selection(posed.names, inputs, args.render, args.max_renders)
    path = path_cameras(args.render, size)
    model = load_model(args)
    refine_kwargs(args.refine_steps, args.refine_seconds)  # fail before any work
    if args.distill_steps < 0:
        raise ValueError(f"--distill-steps must be >= 0 (0: off), got {args.distill_steps}")
    if args.distill_steps and (model.improver is None or not which and not path):
        raise ValueError(
            "--distill-steps fits the enhanced renders: it needs an improvement model and "
            "cameras to render (--render)"
        )
    fill = getattr(args, "fill_holes", False)
    if fill and bool(torch.as_tensor(background).any()):
        raise ValueError(
            f"--fill-holes continues renders on black, but this set is composited over "
            f"{bg_text}; leave --fill-holes out (the background already fills the holes)"
        )
    images, cameras = load_views(posed, inputs, size, background, progress=True)
    depth = near_far(posed, inputs, cameras, args.near, args.far, images, not args.no_triangulate)
    near, far, nf_source = depth.near, depth.far, depth.source
    anchors = anchors_of(depth, args)
    names = [posed.views[i].name for i in inputs]
    print(
        f"reconstructing from {len(inputs)} views ({', '.join(names)}) at {size[0]}x{size[1]}, "
        f"near {near:.3g}, far {far:.3g} ({nf_source})"
    )
    g, t_recon, note = reconstruct_gaussians(model, images, cameras, near, far, args, anchors)
    trust = None
    if (which or path) and not getattr(args, "no_trust_check", False):
        trust = leave_one_out(model, images, cameras, near, far, anchors=anchors)
        if (message := trust.message()) is not None:
            print(message)
    out.mkdir(parents=True, exist_ok=True)
    write_ply(g, out / "gaussians.ply", overwrite=args.overwrite)
    (out / "inputs").mkdir(exist_ok=True)
    frames = []
    for name, img, cam in zip(names, images, cameras, strict=True):
        write_image(out / "inputs" / f"{name}.png", img, overwrite=args.overwrite)
        frames.append(Frame(cam, f"inputs/{name}.png"))
    write_transforms(out / "transforms.json", frames, {"near": near, "far": far}, args.overwrite)

    rendered, rows, enhanced = [], [], []
    t0 = time.perf_counter()
    todo = [(posed.views[i].name, view_camera(posed.views[i], size),
             "input" if i in inputs else "held-out") for i in which]  # fmt: skip
    todo += [(name, cam, "camera path") for name, cam in path]
    if todo:
        (out / "renders").mkdir(exist_ok=True)
    for name, cam, kind in tqdm(todo, desc="rendering + enhancing", unit="view", disable=not todo):
        enhance = model.improver is not None
        r = model.render(  # a black background is the render's own: the fill goes over it
            g, cam, images, cameras, enhance=enhance, fill_holes=fill,
            background=None if fill else background,
            other_views_opacity=args.other_views_opacity,
        )  # fmt: skip
        write_image(out / "renders" / f"{name}_raw.png", r.raw, overwrite=args.overwrite)
        if fill:
            filled = hole_fill(r.raw, r.alpha)
            write_image(out / "renders" / f"{name}_filled.png", filled, overwrite=args.overwrite)
        if enhance:
            write_image(out / "renders" / f"{name}_enhanced.png", r.image, overwrite=args.overwrite)
            enhanced.append((cam, r.image))
        rendered.append(name)
        rows.append((name, kind, names[r.reference] if r.reference is not None else "-"))
    t_views = time.perf_counter() - t0
    if args.distill_steps:
        t0 = time.perf_counter()
        note += _distill_renders(g, images, cameras, todo, enhanced, background, args, out)
        t_views += time.perf_counter() - t0
    result = ReconstructResult(
        out=out,
        inputs=names,
        rendered=rendered,
        near=near,
        far=far,
        near_far_source=nf_source,
        background=bg_text,
        gaussians=len(g),
        size=size,
        timings={"reconstruct": t_recon, "views": t_views},
        photos=photos,
        trust=trust,
    )
    result.timings["total"] = time.perf_counter() - t_start
    _write_report(result, posed, note, rows, args)
    return result


def _distill_renders(g, images, cameras, todo, enhanced, background, args, out: Path) -> str:
    """``--distill-steps``: fit ``g`` to the inputs and the enhanced renders of the cameras
    with the inputs' aspect ratio (refinement fits views of one size), write
    ``gaussians_distilled.ply`` and every camera's render from it; returns a note for the
    report."""
    from prosplat.core.image_io import write_image
    from prosplat.core.ply import write_ply
    from prosplat.pipeline.distill import distill, fits_inputs
    from prosplat.pipeline.refine import RefineOptions
    from prosplat.render import render

    h, w = images.shape[-2:]
    same = [(c, im) for c, im in enhanced if fits_inputs(c, h, w)]
    if not same:
        raise ValueError("--distill-steps: no rendered camera has the inputs' aspect ratio")
    views = torch.stack([im for _, im in same])
    steps = args.distill_steps
    print(f"distilling {len(same)} enhanced views into the Gaussians ({steps} steps)")
    # fitted over the background the renders were composited on (white for NeRF-synthetic)
    options = RefineOptions(background=tuple(float(x) for x in background))
    result = distill(g, images, cameras, views, [c for c, _ in same], steps=steps, options=options)
    write_ply(result.gaussians, out / "gaussians_distilled.ply", overwrite=args.overwrite)
    for name, cam, _ in todo:
        with torch.no_grad():
            rgb = render(result.gaussians, cam, background=background).rgb.clamp(0, 1)
        write_image(out / "renders" / f"{name}_distilled.png", rgb, overwrite=args.overwrite)
    skipped = len(enhanced) - len(same)
    return (
        f"; distilled {result.stats.steps} steps from {len(same)} enhanced views"
        + (f" ({skipped} of another aspect ratio rendered, not fitted)" if skipped else "")
        + " into `gaussians_distilled.ply`"
    )


def trust_line(t: TrustEstimate) -> str:
    """The leave-one-out estimate in one line: the scores, and the warning when the paste
    wins."""
    if not t.views:
        return "leave-one-out: fewer than 3 inputs, no estimate"
    head = (
        f"leave-one-out over {len(t.views)} inputs: re-rendered {t.model_db:.2f} dB, "
        f"nearest photo pasted {t.paste_db:.2f} dB"
    )
    return f"{head}; {t.message()}" if t.loses_to_paste else f"{head}: no warning"


def _write_report(result: ReconstructResult, posed, note: str, rows, args) -> None:
    lens = sorted({v.distortion.model for v in posed.views if v.distortion is not None})
    lines = [
        "# prosplat reconstruct",
        "",
        f"- input: `{posed.source}` ({posed.kind}, {len(posed.views)} frames; lens: "
        f"{', '.join(lens) + ' distortion, undistorted' if lens else 'pinhole'})",
        *(photo_input.report_lines(result.photos) if result.photos else []),
        *([f"- {missing_note(posed)} (`--skip-missing`)"] if posed.missing else []),
        f"- input views: {', '.join(result.inputs)}",
        f"- model resolution: {result.size[0]}x{result.size[1]}",
        f"- background for RGBA: {result.background}",
        f"- near/far: {result.near:.4g} / {result.far:.4g} from {result.near_far_source}",
        f"- Gaussians: {result.gaussians:,} ({note}); `gaussians.ply`",
        *([f"- {trust_line(result.trust)}"] if result.trust is not None else []),
        f"- time: reconstruct {result.timings['reconstruct']:.2f} s, render + enhance "
        f"{result.timings['views']:.2f} s for {len(result.rendered)} views, total "
        f"{result.timings['total']:.1f} s",
        "- `transforms.json` + `inputs/`: the undistorted, resized inputs with their cameras",
        "",
    ]
    if rows:
        distilled = bool(getattr(args, "distill_steps", 0))
        lines += [
            "| view | kind | MORI reference | raw | enhanced |"
            + (" distilled |" if distilled else ""),
            "|---|---|---|---|---|" + ("---|" if distilled else ""),
        ]
        for name, kind, ref in rows:
            enh = f"![](renders/{name}_enhanced.png)" if ref != "-" else "-"
            line = f"| {name} | {kind} | {ref} | ![](renders/{name}_raw.png) | {enh} |"
            lines.append(line + (f" ![](renders/{name}_distilled.png) |" if distilled else ""))
        lines.append("")
    opts = {k: v for k, v in vars(args).items() if k != "func" and not k.endswith("_command")}
    lines.append("options: " + ", ".join(f"`{k}={v}`" for k, v in opts.items() if k != "command"))

    (result.out / "report.md").write_text("\n".join(lines) + "\n")


def run(args: argparse.Namespace) -> int:
    """The command: one-line message and exit status 2 on bad input."""
    try:
        result = run_reconstruct(args)
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"prosplat reconstruct: {' '.join(str(e).split())}", file=sys.stderr)
        return 2
    print(
        f"wrote {result.gaussians:,} Gaussians and {len(result.rendered)} renders (raw + "
        f"enhanced) to {result.out}; report: {result.out / 'report.md'}"
    )
    if result.photos:
        print(photo_input.summary_line(result.photos))
    return 0
