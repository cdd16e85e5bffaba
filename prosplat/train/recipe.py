"""A recipe: the ordered training stages that make a shipped weights file, each resumable, run
into one folder (``OUT/<stage>/``), with the data each stage needs and the command that makes it.

A stage holds its typed training config (:class:`~prosplat.train.generator_config.TrainConfig`
or :class:`~prosplat.train.improve.ImproveTrainConfig`, or a :class:`Blend` of two stages),
the stage it starts from (``init``: its weights, or with ``resumes`` its whole run folder:
optimiser and step), and its data: rendered scenes (:class:`Scenes`, a named set of
:mod:`prosplat.data.scene_sets` or some seeds of one) and, for stage 2, curated sets
(:class:`Curated`) rendered by a stage of a generator recipe. The registry of named recipes is
:mod:`prosplat.train.recipes`; ``prosplat train generator|improve --recipe NAME`` runs one.

Paths in a stage's config are left empty (``data``, ``out``, ``val``) or relative to the
recipe's folder (``init``: ``v14/checkpoint.safetensors``); :func:`run_recipe` fills them in.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shlex
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from prosplat.core.paths import write_text_atomic
from prosplat.data.scene_sets import SCENE_SETS, link_subset, parse_seeds
from prosplat.pipeline.model import ProSplat
from prosplat.train.blend import blend_files
from prosplat.train.common import weights_step
from prosplat.train.curate import curate
from prosplat.train.generator import train
from prosplat.train.generator_config import TrainConfig
from prosplat.train.improve import ImproveTrainConfig, train_improve


@dataclass(frozen=True)
class Scenes:
    """Rendered scenes: the set ``set`` (a folder of the data root), or only its ``seeds``
    (then linked into ``OUT/scenes/<slug>`` so the stage sees exactly those)."""

    set: str
    seeds: str | None = None

    def __post_init__(self) -> None:
        if self.set not in SCENE_SETS:
            raise ValueError(f"no scene set {self.set!r}; one of {list(SCENE_SETS)}")
        if self.seeds is not None:
            parse_seeds(self.seeds)

    @property
    def slug(self) -> str:
        """A folder name for the subset: ``train128_10000-10359_hard0-4``."""
        if self.seeds is None:
            return self.set
        return self.set + "_" + "_".join(p.replace(":", "") for p in self.seeds.split())

    @property
    def count(self) -> int | None:
        """Scenes in the subset (None for a whole set, which may grow)."""
        return None if self.seeds is None else len(parse_seeds(self.seeds))

    def label(self) -> str:
        return self.set if self.seeds is None else f"{self.set} seeds {self.seeds}"

    def path(self, data_root: Path, out: Path) -> Path:
        return data_root / self.set if self.seeds is None else out / "scenes" / self.slug

    def commands(self, data_root: Path, out: Path, seen: set[str] | None = None) -> list[str]:
        """The commands that render these scenes and link the subset; scenes named in
        ``seen`` (``"set/seed"``, which it adds to) are left out as rendered already."""
        seeds = parse_seeds(self.seeds if self.seeds is not None else SCENE_SETS[self.set].seeds)
        seen = set() if seen is None else seen
        todo = [s for s in seeds if f"{self.set}/{s}" not in seen]
        seen.update(f"{self.set}/{s}" for s in todo)
        lines = SCENE_SETS[self.set].render_commands(todo, data_root) if todo else []
        if self.seeds is not None:
            lines.append(
                f"prosplat scenes subset --data {data_root / self.set} "
                f"--seeds {shlex.quote(self.seeds)} --out {self.path(data_root, out)}"
            )
        return lines

    def resolve(self, data_root: Path, out: Path) -> Path:
        """The folder a stage reads, the subset's links made; a clear error naming the render
        commands when scenes are missing."""
        where = self.path(data_root, out)
        try:
            if self.seeds is None:
                folder = data_root / self.set
                if not any(folder.glob("*/transforms.json")):
                    raise FileNotFoundError(f"no rendered scenes in {folder}")
                return folder
            return link_subset(data_root / self.set, parse_seeds(self.seeds), where)
        except FileNotFoundError as e:
            how = "\n  ".join(SCENE_SETS[self.set].render_commands(self.seeds, data_root))
            raise FileNotFoundError(f"{e}\nrender them with:\n  {how}") from None


@dataclass(frozen=True)
class Curated:
    """A stage-2 set of ``prosplat train curate``: the renders of ``generator`` (a stage of a
    generator recipe, ``"generator-tiny/v7"``) of ``scenes``, stored as ``OUT/sets/NAME``
    (``shards`` > 1: ``NAME_<k>`` files of consecutive slices, as a machine with many cores
    curates them; training takes them in ``ls`` order). The defaults of the last three fields
    are how sets were curated before those options existed."""

    name: str
    scenes: tuple[Scenes, ...]
    generator: str
    views: str
    size: int | None = None
    generator_size: int | None = None
    refine_steps: int = 0
    shards: int = 1
    max_splat_radius: float = 0.0  # 0: draw every splat (no cap before stage 2 v22)
    other_views_opacity: float = 1.0  # 1: every view's Gaussians alike (no favouring)
    depth_sweep: bool = False  # the generator's depth sweep (on in the pipeline since v18's sets)

    @property
    def generator_stage(self) -> tuple[str, str]:
        recipe, _, stage = self.generator.partition("/")
        return recipe, stage

    def shards_of(self, out: Path) -> list[tuple[Path, int, int | None]]:
        """(file, first scene, scene count) per shard; one shard: the whole set."""
        if self.shards == 1:
            return [(out / "sets" / f"{self.name}.safetensors", 0, None)]
        n = sum(s.count or 0 for s in self.scenes)
        if not n:
            raise ValueError(f"curated set {self.name}: shards need scenes given by seeds")
        per = math.ceil(n / self.shards)
        return [
            (out / "sets" / f"{self.name}_{k}.safetensors", k * per, per)
            for k in range(self.shards)
        ]

    def files(self, out: Path) -> list[Path]:
        """The set's files in the order training takes them (``ls``'s: _0, _1, _10, ...)."""
        return sorted((path for path, _, _ in self.shards_of(out)), key=lambda p: p.name)

    def commands(self, data_root: Path, out: Path, generator_path: Path) -> list[str]:
        """One ``prosplat train curate`` per shard, in shard order."""
        data = ",".join(str(s.path(data_root, out)) for s in self.scenes)
        opts = f"--generator {generator_path} --views {self.views}"
        opts += f" --size {self.size}" if self.size else ""
        opts += f" --generator-size {self.generator_size}" if self.generator_size else ""
        opts += f" --refine-steps {self.refine_steps} --max-splat-radius {self.max_splat_radius:g}"
        opts += f" --other-views-opacity {self.other_views_opacity:g}"
        opts += "" if self.depth_sweep else " --no-depth-sweep"
        return [
            f"prosplat train curate --data {data} --out {path} {opts}"
            + (f" --first {first} --count {count}" if count else "")
            for path, first, count in self.shards_of(out)
        ]


@dataclass(frozen=True)
class Blend:
    """A stage that trains nothing: ``(1 - weight) * a + weight * b`` of two earlier stages'
    stage-2 weights (``prosplat train blend``)."""

    a: str
    b: str
    weight: float
    fill_input: bool = False  # load both as models that see the filled render (--fill-input)


@dataclass(frozen=True)
class Stage:
    """One step of a recipe (see the module docstring)."""

    name: str
    config: TrainConfig | ImproveTrainConfig | Blend
    init: str | None = None  # the stage of this recipe it starts from; None: from scratch
    resumes: bool = False  # continue init's run (optimiser, step) with this config
    scenes: tuple[Scenes, ...] = ()  # generator: training scenes (config.data)
    val: Scenes | None = None  # generator: validation scenes (config.val)
    sets: tuple[Curated, ...] = ()  # stage 2: curated sets, in the order they train
    val_set: Curated | None = None  # stage 2: curated validation set (config.val)
    about: str = ""

    @property
    def kind(self) -> str:
        if isinstance(self.config, TrainConfig):
            return "generator"
        return "blend" if isinstance(self.config, Blend) else "improve"

    @property
    def weights_name(self) -> str:
        return "checkpoint.safetensors" if self.kind == "generator" else "improve.safetensors"


@dataclass(frozen=True)
class Recipe:
    """Named stages whose last one's weights are the file that ships as ``ships``."""

    name: str
    kind: str  # "generator" | "improve": the `prosplat train` command that runs it
    ships: str  # the file under prosplat/weights/ its last stage makes
    about: str
    stages: tuple[Stage, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        seen: set[str] = set()
        for s in self.stages:
            if s.init is not None and s.init not in seen:
                raise ValueError(f"{self.name}/{s.name} starts from {s.init}, not an earlier stage")
            if isinstance(s.config, Blend) and not {s.config.a, s.config.b} <= seen:
                raise ValueError(f"{self.name}/{s.name} blends stages that do not come before it")
            seen.add(s.name)

    def stage(self, name: str) -> Stage:
        for s in self.stages:
            if s.name == name:
                return s
        raise ValueError(f"recipe {self.name} has no stage {name!r}; its stages: {self.names}")

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.stages]

    @property
    def final(self) -> Stage:
        return self.stages[-1]


@dataclass
class RunPaths:
    """Where a run reads and writes: its folder, the scene sets' root, and the folders of the
    generator recipes its curated sets come from (by recipe name)."""

    out: Path
    data_root: Path = Path("data")
    generators: dict[str, Path] = field(default_factory=dict)

    def generator_run(self, recipe: str) -> Path:
        return self.generators.get(recipe, self.out.parent / recipe)

    def weights(self, stage: Stage) -> Path:
        return self.out / stage.name / stage.weights_name


def _option(name: str, value: Any) -> str:
    flag = f"--{name.replace('_', '-')}"
    if isinstance(value, bool):
        return flag if value else f"--no-{flag[2:]}"
    if isinstance(value, tuple):
        value = ",".join(map(str, value))
    return f"{flag} {shlex.quote(str(value))}"


def config_options(config: Any) -> str:
    """The ``--options`` that set ``config`` (a training config dataclass) from its defaults:
    the fields that differ from them, in field order."""
    parts = []
    for f in fields(config):
        value = getattr(config, f.name)
        default = f.default if f.default is not dataclasses.MISSING else None
        if value != default and value is not None and value != "":
            parts.append(_option(f.name, value))
    return " ".join(parts)


def resolved_config(recipe: Recipe, stage: Stage, paths: RunPaths):
    """The stage's config with its run's paths filled in (what it trains with)."""
    if isinstance(stage.config, Blend):
        return stage.config
    cfg = replace(stage.config, out=str(paths.out / stage.name))
    if stage.init is not None and not stage.resumes:
        cfg = replace(cfg, init=str(paths.weights(recipe.stage(stage.init))))
    if stage.kind == "generator":
        data = ",".join(str(s.path(paths.data_root, paths.out)) for s in stage.scenes)
        val = stage.val.path(paths.data_root, paths.out) if stage.val else None
        return replace(cfg, data=data, val=None if val is None else str(val))
    files = [str(p) for c in stage.sets for p in c.files(paths.out)]
    val_files = stage.val_set.files(paths.out) if stage.val_set else []
    return replace(cfg, data=",".join(files), val=str(val_files[0]) if val_files else None)


def stage_commands(
    recipe: Recipe, stage: Stage, paths: RunPaths, seen: set[str] | None = None
) -> list[str]:
    """The data commands then the training command of one stage, as a person would type them
    (data already made for an earlier stage, named in ``seen``, is not repeated)."""
    seen = set() if seen is None else seen
    lines: list[str] = []

    def once(key: str, more: list[str]) -> None:
        if key not in seen:
            seen.add(key)
            lines.extend(more)

    for s in (*stage.scenes, *([stage.val] if stage.val else [])):
        once(f"scenes {s.label()}", s.commands(paths.data_root, paths.out, seen))
    for c in (*stage.sets, *([stage.val_set] if stage.val_set else [])):
        if f"set {c.name}" in seen:
            continue
        for s in c.scenes:
            once(f"scenes {s.label()}", s.commands(paths.data_root, paths.out, seen))
        gen_recipe, gen_stage = c.generator_stage
        gen_out = paths.generator_run(gen_recipe)
        once(
            f"generator {c.generator}",
            [f"prosplat train generator --recipe {gen_recipe} --out {gen_out} --until {gen_stage}"],
        )
        gen_file = gen_out / gen_stage / "checkpoint.safetensors"
        once(f"set {c.name}", c.commands(paths.data_root, paths.out, gen_file))
    out_dir = paths.out / stage.name
    if isinstance(stage.config, Blend):
        a = paths.weights(recipe.stage(stage.config.a))
        b = paths.weights(recipe.stage(stage.config.b))
        lines.append(
            f"prosplat train blend {a} {b} --weight {stage.config.weight:g} "
            f"--out {out_dir / 'improve.safetensors'}"
            + (" --fill-input" if stage.config.fill_input else "")
        )
        return lines
    if stage.resumes:
        prev = paths.out / stage.init
        lines.append(
            f"cp {prev}/checkpoint.safetensors {prev}/state.pt {prev}/log.jsonl {out_dir}/"
            "   # resumes that run"
        )
    lines.append(
        f"prosplat train {stage.kind} {config_options(resolved_config(recipe, stage, paths))}"
    )
    return lines


def describe(recipe: Recipe, paths: RunPaths) -> str:
    """Every stage with its start, seed, steps and data, and the commands that make it."""
    rows = [f"{recipe.name}: {recipe.about}", f"  ships as prosplat/weights/{recipe.ships}"]
    seen: set[str] = set()
    for s in recipe.stages:
        if isinstance(s.config, Blend):
            head = f"{s.name}: blend of {s.config.a} and {s.config.b} (weight {s.config.weight:g})"
        else:
            start = "from scratch" if s.init is None else f"from {s.init}"
            start = f"resuming {s.init}'s run" if s.resumes else start
            steps = f"{s.config.steps} steps"
            if getattr(s.config, "stop_at", None):
                steps = f"{s.config.stop_at} of a {s.config.steps}-step schedule"
            data = ", ".join(x.label() for x in s.scenes) or ", ".join(c.name for c in s.sets)
            head = f"{s.name}: {start}, seed {s.config.seed}, {steps}; data {data or 'as before'}"
        rows.append(head)
        if s.about:
            rows.append(f"    ({s.about})")
        rows += [f"    {line}" for line in stage_commands(recipe, s, paths, seen)]
    rows.append(f"  cp {paths.weights(recipe.final)} prosplat/weights/{recipe.ships}")
    return "\n".join(rows)


def stage_done(stage: Stage, cfg, weights: Path) -> bool:
    """Whether the stage's weights are there at its last step (a stopped run is not done)."""
    if not weights.is_file():
        return False
    if isinstance(cfg, Blend):
        return True
    if isinstance(cfg, TrainConfig):
        return (weights_step(weights) or 0) >= cfg.last_step
    return (weights_step(weights, key="steps") or 0) >= cfg.steps


def _tiny(stage: Stage, steps: int, done_before: int) -> Stage:
    """The stage with ``steps`` training steps (a resuming stage: that many past its start)."""
    if isinstance(stage.config, Blend):
        return stage
    cfg = replace(stage.config, steps=done_before + steps if stage.resumes else steps)
    if isinstance(cfg, TrainConfig):
        cfg = replace(cfg, stop_at=None)

    def capped(c: Curated) -> Curated:
        return replace(c, refine_steps=min(c.refine_steps, steps))

    sets = tuple(capped(c) for c in stage.sets)
    val_set = capped(stage.val_set) if stage.val_set else None
    return replace(stage, config=cfg, sets=sets, val_set=val_set)


def _with_scenes(stage: Stage, scenes: Path) -> Stage:
    """The stage reading ``scenes`` for every set it names (smoke runs)."""
    one = (_Fixed(str(scenes)),)
    sets = tuple(replace(c, scenes=one, shards=1) for c in stage.sets)
    val_set = replace(stage.val_set, scenes=one, shards=1) if stage.val_set else None
    return replace(
        stage, scenes=one if stage.scenes else (), val=one[0] if stage.val else None,
        sets=sets, val_set=val_set,
    )  # fmt: skip


@dataclass(frozen=True)
class _Fixed:
    """A folder of scenes given as is (the ``scenes`` override of a smoke run)."""

    folder: str
    count = None

    def label(self) -> str:
        return self.folder

    def path(self, data_root: Path, out: Path) -> Path:
        return Path(self.folder)

    def commands(self, data_root: Path, out: Path) -> list[str]:
        return []

    def resolve(self, data_root: Path, out: Path) -> Path:
        return Path(self.folder)


def run_recipe(
    recipe: Recipe,
    paths: RunPaths,
    *,
    until: str | None = None,
    device: str | None = None,
    steps: int | None = None,
    scenes: Path | None = None,
    progress: bool = True,
    recipes: Mapping[str, Recipe] | None = None,
    log: Callable[[str], None] = print,
    announce: bool = True,
) -> Path:
    """Run ``recipe``'s stages in order into ``paths.out/<stage>/`` (up to ``until``), each
    skipped when its weights are there at its last step and resumed when it stopped before;
    returns the last stage's weights. Curated sets come from stages of generator recipes in
    ``paths.generators`` (run there first when missing; ``recipes`` looks them up by name:
    :func:`prosplat.train.recipes.run` passes the registry).

    ``device`` replaces every stage's; ``steps`` (and ``scenes``, one folder for every scene
    set) make a smoke run: each stage ``steps`` steps, refinement in curation capped to it.
    ``log`` takes a line per stage (``announce`` False: only the stages that run).

    Raises:
        FileNotFoundError: scenes that are not rendered (with the commands that render them).
        KeyboardInterrupt: a stage stopped before its last step (its run folder resumes).
    """
    names = recipe.names
    last = names.index(recipe.stage(until).name) if until is not None else len(names) - 1
    paths.out.mkdir(parents=True, exist_ok=True)
    steps_before: dict[str, int] = {}
    for stage in recipe.stages[: last + 1]:
        if steps is not None:
            stage = _tiny(stage, steps, steps_before.get(stage.init or "", 0))
        if scenes is not None:
            stage = _with_scenes(stage, scenes)
        if device is not None and not isinstance(stage.config, Blend):
            stage = replace(stage, config=replace(stage.config, device=device))
        if not isinstance(stage.config, Blend):
            steps_before[stage.name] = stage.config.steps
        cfg = resolved_config(recipe, stage, paths)
        weights = paths.weights(stage)
        if stage_done(stage, cfg, weights):
            if announce:
                log(f"{recipe.name}/{stage.name}: done ({weights})")
            continue
        log(f"{recipe.name}/{stage.name}: " + ("blending" if stage.kind == "blend" else "training"))
        _prepare_data(stage, paths, steps, scenes, device, progress, recipes, log)
        _run_stage(recipe, stage, cfg, paths, progress)
        if not stage_done(stage, cfg, weights):
            raise KeyboardInterrupt(
                f"{recipe.name}/{stage.name} stopped before its last step; the same command resumes"
            )
    final = paths.weights(recipe.stages[last])
    if announce and last == len(names) - 1:
        log(f"{recipe.name}: {final} is prosplat/weights/{recipe.ships}")
    return final


def _prepare_data(stage, paths, steps, scenes, device, progress, recipes, log) -> None:
    """Link the stage's scene subsets and curate its missing sets (their generator stages
    run first where they are missing)."""
    for s in (*stage.scenes, *([stage.val] if stage.val else [])):
        s.resolve(paths.data_root, paths.out)
    for c in (*stage.sets, *([stage.val_set] if stage.val_set else [])):
        if all(p.is_file() for p in c.files(paths.out)):
            continue
        gen_name, gen_stage = c.generator_stage
        if recipes is None or gen_name not in recipes:
            raise ValueError(f"curated set {c.name} needs the generator recipe {gen_name}")
        gen_paths = RunPaths(paths.generator_run(gen_name), paths.data_root, paths.generators)
        generator = run_recipe(
            recipes[gen_name], gen_paths, until=gen_stage, device=device, steps=steps,
            scenes=scenes, progress=progress, recipes=recipes, log=log, announce=False,
        )  # fmt: skip
        _curate(c, paths, generator, progress)


def _curate(c: Curated, paths: RunPaths, generator: Path, progress: bool) -> None:
    model = ProSplat.from_pretrained(generator, improve=False, depth_sweep=c.depth_sweep)
    data = ",".join(str(s.resolve(paths.data_root, paths.out)) for s in c.scenes)
    commands = c.commands(paths.data_root, paths.out, generator)
    for (path, first, count), command in zip(c.shards_of(paths.out), commands, strict=True):
        if path.is_file():
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        curate(
            model, data, path, views=[int(v) for v in c.views.split(",")], progress=progress,
            command=command, refine_steps=c.refine_steps, height=c.size,
            generator_height=c.generator_size, max_splat_radius=c.max_splat_radius or None,
            other_views_opacity=c.other_views_opacity, first=first, count=count,
        )  # fmt: skip


def _run_stage(recipe: Recipe, stage: Stage, cfg, paths: RunPaths, progress: bool) -> None:
    out = paths.out / stage.name
    if isinstance(cfg, Blend):
        a, b = (paths.weights(recipe.stage(n)) for n in (cfg.a, cfg.b))
        blend_files(
            a, b, cfg.weight, out / "improve.safetensors", overwrite=True,
            fill_input=cfg.fill_input,
        )  # fmt: skip
        return
    if stage.resumes and not (out / "state.pt").exists():
        _copy_run(paths.out / stage.init, out, cfg)
    if isinstance(cfg, TrainConfig):
        train(cfg, progress=progress)
    else:
        train_improve(cfg, progress=progress)


def _copy_run(src: Path, dest: Path, cfg) -> None:
    """Start ``dest`` as ``src``'s run at its last checkpoint, to go on with ``cfg`` (its
    ``train_config.json``; the settings it ran with before are kept beside it)."""
    dest.mkdir(parents=True, exist_ok=True)
    for name in ("checkpoint.safetensors", "state.pt", "log.jsonl"):
        if (src / name).exists():
            shutil.copy2(src / name, dest / name)
    step = weights_step(dest / "checkpoint.safetensors") or 0
    if (src / "train_config.json").exists():
        shutil.copy2(src / "train_config.json", dest / f"train_config.before_{step}.json")
    write_text_atomic(dest / "train_config.json", json.dumps(dataclasses.asdict(cfg), indent=1))


def final_config(recipe: Recipe) -> Any:
    """The last training stage's config (paths left out): what the shipped file was trained with."""
    for s in reversed(recipe.stages):
        if not isinstance(s.config, Blend):
            return s.config
    raise ValueError(f"recipe {recipe.name} trains nothing")


__all__ = [
    "Blend",
    "Curated",
    "Recipe",
    "RunPaths",
    "Scenes",
    "Stage",
    "describe",
    "final_config",
    "run_recipe",
    "stage_commands",
]
