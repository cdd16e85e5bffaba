"""The named recipes of the shipped weights, one registry (as nerfstudio's ``method_configs``).

``generator-tiny`` makes ``prosplat/weights/generator_tiny.safetensors`` (generator v16) and
``improve-tiny`` makes ``improve_tiny.safetensors`` (stage 2 v22), each from scratch, stage by
stage, as the versioned training scripts that trained them did (they are in git history: see
``git show 9250853:scripts/train_generator_v16.sh`` and the scripts it ``exec``s). Stage
names are the versions in ``docs/MODEL_ZOO.md``; a stage that was not shipped on its own is a
part (``v2a``, ``v4a``, ``v13a``). Stage 2's sets are curated with the generator stage that
was shipped when they were made (stage 2 follows the generator whose renders it learned).

Run one::

    prosplat train generator --recipe generator-tiny --out runs/generator-tiny
    prosplat train improve --recipe improve-tiny --out runs/improve-tiny
    prosplat train recipes [NAME]        # the stages and the commands that make them

Where the history cannot be replayed exactly, a stage says so in ``about``: the early runs
trained on the part of ``data/train128`` rendered at the time (the recipe names the render
rounds they were meant to have), and code has changed since (curation had no depth sweep,
splat cap or view favouring before the stage that first used them; the recipe turns them off
for older sets). Bit-exact weights also need the commit each stage ran at.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from prosplat.train.generator_config import TrainConfig
from prosplat.train.improve import ImproveTrainConfig
from prosplat.train.recipe import Blend, Curated, Recipe, RunPaths, Scenes, Stage, run_recipe

# ---- generator-tiny ---------------------------------------------------------------------------

#: data/train128's first two render rounds (seeds 10000-10119 and 24 hard scenes): generator
#: v2-v3 and stage 2 v4-v7 trained on the 107-109 of them rendered at the time.
ROUNDS_0_1 = Scenes("train128", "10000-10119 hard:0-1")
#: The 420 scenes generator v6-v16 trained on (scripts/train_generator_v6.sh's data/gen_v6).
GEN_V6_SCENES = Scenes("train128", "10000-10359 hard:0-4")


def _gen(base: Mapping[str, Any] | None = None, **settings: Any) -> TrainConfig:
    """A generator stage's config: ``base`` (a recipe's settings) updated by ``settings``, the
    paths left to the run."""
    return TrainConfig(data="", out="", **{**(base or {}), **settings})


def _init(stage: str) -> str:
    """A generator stage's weights, relative to the recipe's folder (filled in when it runs)."""
    return f"{stage}/checkpoint.safetensors"


#: v2's recipe (both parts), scripts/train_generator_v2.sh's C.
_V2 = dict(
    config="tiny", sizes="64", any_view=True, inputs=(2, 3, 4, 5, 6), targets=2, lr=1.5e-4,
    input_depth_weight=0.3, depth_weight=0.1, input_render_weight=0.5, log_every=50,
    val_every=1000, val_scenes=8,
)  # fmt: skip
#: v4's COMMON: log depth, 3x the input-depth weight, targets at twice the size.
_V4 = dict(
    sizes="64", any_view=True, inputs=(2, 3, 4, 5, 6), targets=2, lr=1.5e-4,
    input_depth_weight=1.0, depth_weight=0.1, depth_loss="log", input_render_weight=0.5,
    target_scale=2, warmup=100, save_every=250, log_every=50, val_every=1000, val_scenes=8,
    cache_scenes=256,
)  # fmt: skip
#: v6's recipe (scripts/train_generator_v6.sh), which v7-v16 run with more options.
_V6 = dict(
    _V4, sizes="64,128", cache_scenes=512, val_every=1000, val_scenes=8,
)  # fmt: skip
#: v8's additions (scripts/train_generator_v8.sh): framed windows and a weight average.
_V8 = dict(_V6, frame_prob=0.5, ema=0.998)

GENERATOR_TINY = Recipe(
    name="generator-tiny",
    kind="generator",
    ships="generator_tiny.safetensors",
    about="the shipped generator (v16), from scratch in 16 stages",
    stages=(
        Stage(
            "v0",
            _gen(
                config="tiny",
                steps=18000,
                inputs=2,
                targets=2,
                lr=5e-4,
                warmup=500,
                log_every=100,
                val_every=1000,
                val_scenes=4,
                save_every=1000,
            ),
            scenes=(Scenes("train64"),),
            val=Scenes("val64"),
            about="60 scenes at 64 px, commit dde73b3",
        ),
        Stage(
            "v1",
            _gen(
                init=_init("v0"),
                steps=7000,
                inputs=(2, 4),
                targets=2,
                lr=3e-4,
                warmup=200,
                input_depth_weight=0.3,
                log_every=50,
                val_every=1000,
                val_scenes=4,
                save_every=500,
            ),
            init="v0",
            scenes=(Scenes("train64"), Scenes("train64b")),
            val=Scenes("val64"),
            about="input-depth supervision on 210 scenes, commit 58351a3",
        ),
        Stage(
            "v2a",
            _gen(_V2, init=_init("v1"), warmup=200, steps=12000, stop_at=5000, save_every=500),
            init="v1",
            scenes=(ROUNDS_0_1,),
            val=Scenes("val128"),
            about="the geometry terms; 5,000 steps of a 12,000-step schedule",
        ),
        Stage(
            "v2",
            _gen(_V2, init=_init("v2a"), target_scale=2, warmup=100, steps=6000, save_every=250),
            init="v2a",
            scenes=(ROUNDS_0_1,),
            val=Scenes("val128"),
            about="targets at twice the inputs' size",
        ),
        Stage(
            "v3",
            _gen(
                _V2,
                init=_init("v2"),
                target_scale=2,
                grow_fine_matching=16,
                warmup=100,
                steps=10000,
                save_every=250,
                cache_scenes=128,
            ),
            init="v2",
            scenes=(ROUNDS_0_1,),
            val=Scenes("val128"),
            about="grown by a 1/2-resolution cost volume (the shipped run cached 32 scenes, "
            "which changes only the speed)",
        ),
        Stage(
            "v4a",
            _gen(_V4, init=_init("v3"), steps=3000),
            init="v3",
            scenes=(Scenes("train128", "10000-10119 hard:0"),),
            val=Scenes("val128"),
            about="depth terms in log depth at 3x the weight, 132 scenes",
        ),
        Stage(
            "v4",
            _gen(_V4, init=_init("v4a"), steps=5000),
            init="v4a",
            scenes=(Scenes("train128", "10000-10209 hard:0-2"),),
            val=Scenes("val128"),
            about="5,000 more steps on 246 scenes",
        ),
        Stage(
            "v5",
            _gen(_V6, init=_init("v4"), steps=5000),
            init="v4",
            scenes=(Scenes("train128", "10000-10419 hard:0-5"),),
            val=Scenes("val128"),
            about="64 and 128 px drawn per step, 492 scenes",
        ),
        Stage(
            "v6",
            _gen(_V6, init=_init("v5"), steps=3000, seed=0),
            init="v5",
            scenes=(GEN_V6_SCENES,),
            about="3,000 more steps on 420 scenes",
        ),
        Stage(
            "v7",
            _gen(_V6, init=_init("v6"), frame_prob=0.5, steps=5000, seed=1),
            init="v6",
            scenes=(GEN_V6_SCENES,),
            about="half of the 128-px steps on windows of other shapes",
        ),
        Stage(
            "v8",
            _gen(_V8, init=_init("v7"), steps=5000, seed=2),
            init="v7",
            scenes=(GEN_V6_SCENES,),
            about="a moving average of the weights (decay 0.998)",
        ),
        Stage(
            "v9",
            _gen(_V8, init=_init("v8"), steps=5000, stop_at=3500, seed=3),
            init="v8",
            scenes=(GEN_V6_SCENES,),
            about="shipped at step 3,500 of its 5,000-step schedule",
        ),
        Stage(
            "v11",
            _gen(_V8, init=_init("v9"), input_render_weight=2.0, steps=5000, seed=5),
            init="v9",
            scenes=(GEN_V6_SCENES,),
            about="from v9 (v10 is a sibling): the input cameras' render term at 2",
        ),
        Stage(
            "v12",
            _gen(_V8, init=_init("v11"), input_render_weight=2.0, steps=3500, seed=7),
            init="v11",
            scenes=(GEN_V6_SCENES,),
            about="v11's recipe, 3,500 more steps",
        ),
        Stage(
            "v14",
            _gen(
                _V8,
                init=_init("v12"),
                input_render_weight=2.0,
                grow_image_matching=5,
                steps=3500,
                seed=9,
            ),
            init="v12",
            scenes=(GEN_V6_SCENES,),
            about="grown by the images' own ZNCC plane sweep",
        ),
        Stage(
            "v16",
            _gen(
                _V8,
                init=_init("v14"),
                input_render_weight=2.0,
                fill_holes=True,
                steps=3500,
                seed=12,
            ),
            init="v14",
            scenes=(GEN_V6_SCENES,),
            about="every render scored with its holes filled (trained as v16a)",
        ),
    ),  # fmt: skip
)

# ---- improve-tiny -----------------------------------------------------------------------------


def _s2(base: Mapping[str, Any] | None = None, **settings: Any) -> ImproveTrainConfig:
    """A stage-2 stage's config, as :func:`_gen`."""
    return ImproveTrainConfig(data="", out="", **{**(base or {}), **settings})


def _s2_init(stage: str) -> str:
    return f"{stage}/improve.safetensors"


def _sets(
    prefix: str,
    generator: str,
    scenes: Scenes,
    specs: str,
    generator_size: int | None = None,
    **options: Any,
) -> tuple[Curated, ...]:
    """Curated sets from ``"NAME:VIEWS:SIZE:REFINE ..."`` (scripts/gpu_train_stage2.sh's SETS),
    stored as ``PREFIX-NAME``."""
    out = []
    for spec in specs.split():
        name, views, size, refine = spec.split(":")
        out.append(Curated(
            f"{prefix}-{name}", (scenes,), f"generator-tiny/{generator}", views, int(size),
            generator_size, int(refine), **options,
        ))  # fmt: skip
    return tuple(out)


VAL128 = Scenes("val128")
#: scripts/curate_stage2_sets.sh's sets, with generator v1 at 64 px (stage 2 v4; v5 keeps the
#: refined ones): raw from rounds 0-1, refined from the first 54 family scenes.
_V4_RAW64, _V4_REF64, _V4_RAW128, _V4_REF128 = (
    _sets("v4", "v1", ROUNDS_0_1, "raw64:2,3,4,6:64:0", 64)
    + _sets("v4", "v1", Scenes("train128", "10000-10053"), "ref64:2,4:64:300", 64)
    + _sets("v4", "v1", ROUNDS_0_1, "raw128:2,4:128:0", 64)
    + _sets("v4", "v1", Scenes("train128", "10000-10053"), "ref128:2,4:128:300", 64)
)
(_V4_VAL,) = _sets("v4", "v1", VAL128, "val_ref128:4:128:300", 64)
#: The recipe stage 2 v4-v7 share (replicate padding, alpha, 48-px crops, flips, LPIPS 0.1).
_S2_BASE = dict(padding="replicate", alpha=True, crop=48, flip=True, batch=8, lpips_weight=0.1)
#: v6-v10: the warped reference, lr 2e-4.
_S2_WARP = dict(_S2_BASE, warp=True, lr=2e-4, warmup=100, val_every=500, save_every=100,
                log_every=50)  # fmt: skip
#: v12's recipe (scripts/train_stage2_v12.sh), v13a-v16: the sub-pixel shift term at 256 px.
_S2_SHIFT = dict(_S2_BASE, warp=True, lr=1e-4, warmup=100, shift_weight=10.0,
                 subpixel_shift=True, working_size=256, save_every=100, log_every=50)  # fmt: skip
#: v18/v19 on a lent GPU (scripts/gpu_train_stage2.sh): batch 16, fill, eight shards a set.
_S2_GPU = dict(_S2_SHIFT, batch=16, lpips_weight=0.1, fill=True, save_every=500)
_GPU_SETS = dict(generator_size=128, shards=8, depth_sweep=True)

IMPROVE_TINY = Recipe(
    name="improve-tiny",
    kind="improve",
    ships="improve_tiny.safetensors",
    about="the shipped stage 2 (v22), from scratch (v4) in 12 stages, on generator-tiny's renders",
    stages=(
        Stage(
            "v4a",
            _s2(
                _S2_BASE,
                lr=5e-4,
                warmup=100,
                steps=4000,
                val_every=1000,
                save_every=100,
                log_every=50,
            ),
            sets=(_V4_RAW64, _V4_REF64, _V4_RAW128, _V4_REF128),
            val_set=_V4_VAL,
            about="from scratch, the first 4,000 steps (scripts/train_stage2_v4.sh 4000)",
        ),
        Stage(
            "v4",
            _s2(
                _S2_BASE,
                lr=5e-4,
                warmup=100,
                steps=8000,
                val_every=1000,
                save_every=100,
                log_every=50,
            ),
            init="v4a",
            resumes=True,
            sets=(_V4_RAW64, _V4_REF64, _V4_RAW128, _V4_REF128),
            val_set=_V4_VAL,
            about="the same run resumed to an 8,000-step schedule (... 8000)",
        ),
        Stage(
            "v5",
            _s2(
                _S2_BASE,
                init=_s2_init("v4"),
                lr=2e-4,
                warmup=100,
                steps=3000,
                val_every=500,
                save_every=100,
                log_every=50,
            ),
            init="v4",
            sets=(
                *_sets("v5", "v2", ROUNDS_0_1, "raw64:2,3,4,6:64:0", 64),
                _V4_REF64,
                *_sets("v5", "v2", ROUNDS_0_1, "raw128:2,4:128:0", 64),
                _V4_REF128,
            ),
            val_set=_sets("v5", "v2", VAL128, "val_ref128:4:128:300", 64)[0],
            about="generator v2's raw renders beside v4's refined sets",
        ),
        Stage(
            "v6",
            _s2(_S2_WARP, init=_s2_init("v5"), steps=3000),
            init="v5",
            sets=_sets("v6", "v2", ROUNDS_0_1, "raw64:2,3,4,6:64:0 raw128:2,4:128:0", 64),
            val_set=_sets("v6", "v2", VAL128, "val_raw64:2,4:64:0", 64)[0],
            about="the warped reference (a zero-initialised input)",
        ),
        Stage(
            "v7",
            _s2(_S2_WARP, init=_s2_init("v6"), steps=3000),
            init="v6",
            sets=_sets("v7", "v3", ROUNDS_0_1, "raw64:2,3,4,6:64:0 raw128:2,4:128:0", 64),
            val_set=_sets("v7", "v3", VAL128, "val_raw64:2,4:64:0", 64)[0],
            about="generator v3's renders",
        ),
        Stage(
            "v10",
            _s2(_S2_WARP, init=_s2_init("v7"), steps=3000, shift_weight=10.0, working_size=256),
            init="v7",
            sets=_sets(
                "v10",
                "v5",
                Scenes("train128", "10000-10209 hard:0-2"),
                "raw64:2,3,4,6:64:0 raw128:2,4:128:0",
                generator_size=128,
            ),
            val_set=_sets("v10", "v5", VAL128, "val_raw64:2,4:64:0", generator_size=128)[0],
            about="generator v5's renders and the shift term; shipped with its working size "
            "set to 256 afterwards (the same weights), which --working-size 256 saves directly",
        ),
        Stage(
            "v13a",
            _s2(_S2_SHIFT, init=_s2_init("v10"), steps=2000, lpips_weight=1.0),
            init="v10",
            sets=(
                *_sets(
                    "v13",
                    "v5",
                    Scenes("train128", "10000-10239 hard:0-3"),
                    "raw64:2,3,4,6:64:0 raw128:2,4:128:0",
                    generator_size=128,
                ),
                *_sets("v13", "v5", Scenes("train256"), "raw256:2,4:256:0", generator_size=128),
            ),
            about="v10 fine-tuned at LPIPS weight 1 (runs/s2v13/lp1)",
        ),
        Stage("v13", Blend("v10", "v13a", 0.3), about="0.7 x v10 + 0.3 x v13a"),
        Stage(
            "v16",
            _s2(_S2_SHIFT, init=_s2_init("v13"), steps=2000, lpips_weight=0.1, fill=True),
            init="v13",
            sets=_sets(
                "v16",
                "v7",
                Scenes("train128", "10000-10154 hard:0-1"),
                "raw64:2,3,4,6:64:0 raw128:2,4:128:0",
                generator_size=128,
            ),
            about="generator v7's renders, filled before the model sees them",
        ),
        Stage(
            "v18",
            _s2(_S2_GPU, init=_s2_init("v16"), steps=4200),
            init="v16",
            sets=_sets(
                "v18",
                "v7",
                Scenes("train128", "10000-10135 hard:0-1"),
                "raw64:2,3,4,6:64:0 raw128:2,4:128:0",
                **_GPU_SETS,
            ),
            about="on a lent H200 (--device cuda) for the steps its time budget allowed "
            "(scripts/gpu_train_stage2.sh), curated in 8 shards a set",
        ),
        Stage(
            "v19",
            _s2(_S2_GPU, init=_s2_init("v18"), steps=3200),
            init="v18",
            sets=_sets(
                "v19",
                "v7",
                Scenes("train128", "10136-10279 hard:2-3"),
                "raw64:2,4:64:0 raw128:4:128:0 ref64:2,4:64:100",
                **_GPU_SETS,
            ),
            about="on a lent H200 (--device cuda), 168 new scenes with refined renders beside "
            "the raw ones; curated before the scene-wide depth factor existed",
        ),
        Stage(
            "v22",
            _s2(
                _S2_SHIFT,
                init=_s2_init("v19"),
                fill=True,
                steps=2000,
                lr=5e-5,
                lpips_weight=0.1,
                seed=22,
            ),
            init="v19",
            sets=_sets(
                "v22",
                "v16",
                Scenes("train128", "10360-10442 hard:5-6"),
                "raw64:2,4:64:0 raw128:4:128:0 ref64:2,4:64:100",
                generator_size=128,
                depth_sweep=True,
                max_splat_radius=0.1,
            ),
            about="generator v16's capped renders, on the CPU",
        ),
    ),  # fmt: skip
)

#: Every recipe by name.
RECIPES: dict[str, Recipe] = {r.name: r for r in (GENERATOR_TINY, IMPROVE_TINY)}


def recipe_named(name: str, kind: str | None = None) -> Recipe:
    """The recipe ``name`` (of ``kind``, "generator" or "improve", when given).

    Raises:
        ValueError: no such recipe, naming those there are.
    """
    found = RECIPES.get(name)
    if found is None or (kind is not None and found.kind != kind):
        names = [r.name for r in RECIPES.values() if kind is None or r.kind == kind]
        raise ValueError(f"no {kind or ''} recipe {name!r}; one of {', '.join(names)}")
    return found


def run(
    name: str,
    out: str | Path,
    data_root: str | Path = "data",
    generator_runs: Mapping[str, str | Path] | None = None,
    **options: Any,
) -> Path:
    """:func:`~prosplat.train.recipe.run_recipe` of the recipe ``name`` into ``out``: scene sets
    under ``data_root``, the generator recipes' runs in ``generator_runs`` (default: beside
    ``out``, named after the recipe). Returns the last stage's weights."""
    paths = RunPaths(
        Path(out), Path(data_root), {k: Path(v) for k, v in (generator_runs or {}).items()}
    )
    return run_recipe(recipe_named(name), paths, recipes=RECIPES, **options)


__all__ = ["GENERATOR_TINY", "IMPROVE_TINY", "RECIPES", "recipe_named", "run"]
