"""Loading and validating pipeline files.

Validation runs in four passes, and each reports every problem it finds
with the file, the YAML path and the line:

1. structure: the file against :class:`~surgiplan.config.PipelineModel`, and
   each stage against the keys of its kind (:attr:`surgiplan.kinds.StageKind.model`:
   unknown keys, wrong types, negative or NaN lengths);
2. plugins: each stage's plugin is looked up by name in the registry, its
   ``settings`` validated with that plugin's own model, and the kind resolves
   its keys (:meth:`~surgiplan.kinds.StageKind.resolve`: a plan stage's space
   and clearance threshold, a guide stage's analysis);
3. meaning: the scene is built (meshes loaded), and each kind checks what
   needs it (:meth:`~surgiplan.kinds.StageKind.check`: starts and goals known,
   inside the bounds and free; the plan stage a path comes from);
4. resources: each stage estimates from its settings what it will need
   (:mod:`surgiplan.resources`); more memory than the machine has is an error
   naming the setting.

Stage kinds come from the registry (the built-in ones and any third party's),
so this module knows none of them. :func:`load_pipeline` returns a
:class:`Pipeline` ready to run; nothing has been written anywhere. Deprecated
spellings are accepted and reported in ``Pipeline.warnings``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .config import PipelineModel
from .errors import ConfigError, ConfigErrors, PlanningInputError, SurgiplanError
from .kinds import FileContext, StageKind, StageModel, StageSpec
from .registry import PluginRegistry, default_registry
from .resources import too_large
from .scene import Scene
from .scene_files import _load_scene_collecting, load_scene, looks_like_scene, scene_with_errors
from .validation import RECORD_KEY, declared_unit, sorted_errors, validate_model, validation_context
from .yamlio import LineMap, format_path, line_of, load_yaml

__all__ = ["Pipeline", "StageSpec", "load_pipeline", "load_scene", "looks_like_scene"]


@dataclass
class Pipeline:
    """A validated, resolved pipeline file (:func:`load_pipeline`): its ``name``, parsed ``model``, the ``scene``
    built in SI, the ``stages`` in order, the ``output_dir`` a run writes to, the file's directory (``base_dir``,
    which relative paths in it start from) and the ``registry`` its plugins came from."""

    file: Path
    name: str
    model: PipelineModel
    scene: Scene
    stages: list[StageSpec]
    output_dir: Path
    base_dir: Path
    registry: PluginRegistry = field(repr=False, default_factory=default_registry)
    #: the trainee record guide stages write to (relative to the current directory)
    record: Path = Path("out/trainees.sqlite")
    #: deprecated spellings and other things worth saying that do not stop the run (with file and line)
    warnings: list[ConfigError] = field(default_factory=list)

    def kind(self, spec: StageSpec) -> StageKind:
        """The kind of stage ``spec`` is."""
        return self.registry.stage_kind(spec.kind)


def load_pipeline(
    path: str | Path, *, registry: PluginRegistry | None = None, output_dir: str | Path | None = None
) -> Pipeline:
    """Read, validate and resolve a pipeline file (all four passes).

    Every problem found is reported at once (:class:`~surgiplan.errors.ConfigErrors`, sorted by line): a stage whose
    structure is wrong is left out of the later passes, the others go on, so a file with three
    mistakes needs one ``surgiplan validate``, not three.
    """
    registry = registry or default_registry()
    path = Path(path)
    data, lines = load_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError("a pipeline file must be a mapping with name, scene and pipeline", file=path)
    if looks_like_scene(data):
        raise ConfigError(
            "this is a scene file (bounds, obstacles, points), not a pipeline; `surgiplan validate` checks it as "
            "a scene, and a pipeline uses it with 'scene: <this file>'",
            file=path,
        )
    base_dir = path.resolve().parent
    unit = declared_unit(data, "m", path, lines, ())
    context = validation_context(unit, base_dir)
    record = data.get("record")
    context[RECORD_KEY] = Path(record if isinstance(record, str) else "out/trainees.sqlite")
    errors: list[ConfigError] = []

    # pass 1: structure (every error; the parts that are sound go on to the next passes)
    model: PipelineModel | None = None
    try:
        model = validate_model(PipelineModel, data, file=path, lines=lines, context=context)
    except ConfigErrors as exc:
        errors.extend(exc.errors)
    raw_stages = data.get("pipeline") if isinstance(data.get("pipeline"), list) else []
    stage_keys: dict[int, tuple[StageKind, StageModel]] = {}
    for index, raw in enumerate(raw_stages):
        try:
            stage_keys[index] = _stage_keys(index, raw, registry, path, lines, context)
        except ConfigErrors as exc:
            errors.extend(exc.errors)

    # the scene: inline (this file's unit unless it declares its own) or a scene file
    scene: Scene | None = None
    raw_scene = data.get("scene")
    try:
        if isinstance(raw_scene, str):
            scene_path = (base_dir / raw_scene).resolve()
            if not scene_path.is_file():
                raise ConfigError(
                    f"scene file not found: {scene_path}", file=path, location="scene", line=line_of(lines, ("scene",))
                )
            scene, scene_errors = _load_scene_collecting(scene_path)
            errors.extend(scene_errors)
        elif isinstance(raw_scene, dict):
            scene_unit = declared_unit(raw_scene, unit, path, lines, ("scene",))
            scene, scene_errors = scene_with_errors(
                raw_scene, file=path, lines=lines, prefix=("scene",), unit=scene_unit, base_dir=base_dir
            )
            known = {(e.location, e.message) for e in errors}  # pass 1 reported the same ones already
            errors.extend(e for e in scene_errors if (e.location, e.message) not in known)
    except SurgiplanError as exc:
        errors.append(exc if exc.file is not None else ConfigError(exc.message, file=path, location=exc.location))

    if scene is not None:
        scene.unit = unit  # messages in the pipeline's unit, whatever the scene file's
    files = FileContext(path, lines, context, registry, scene)

    # pass 2: plugins and their settings (and spaces, when the scene is there to build them on)
    stages: list[StageSpec] = []
    names: set[str] = set()
    for index, (kind, keys) in stage_keys.items():
        try:
            spec = _resolve_stage(index, kind, keys, raw_stages[index], registry, files, names)
        except ConfigErrors as exc:
            errors.extend(exc.errors)
            continue
        except SurgiplanError as exc:
            errors.append(ConfigError(exc.message, file=path, location=exc.location, line=exc.line))
            continue
        names.add(spec.name)
        stages.append(spec)

    # pass 3: meaning (needs the scene, and the stages before each)
    complete: list[StageSpec] = []
    if scene is not None:
        files.earlier = stages
        for spec in stages:
            try:
                registry.stage_kind(spec.kind).check(spec, files)
            except ConfigErrors as exc:
                errors.extend(exc.errors)
                continue
            except SurgiplanError as exc:
                errors.append(
                    exc
                    if isinstance(exc, ConfigError | PlanningInputError)
                    else ConfigError(exc.message, file=path, location=exc.location, line=exc.line)
                )
                continue
            complete.append(spec)

    # pass 4: resources, estimated from the settings before any work
    for spec in complete:
        errors.extend(_resource_errors(registry.stage_kind(spec.kind), spec, path, lines))
    if errors:
        raise ConfigErrors(sorted_errors(errors))
    assert model is not None and scene is not None

    out = Path(output_dir) if output_dir is not None else Path(model.output.dir or Path("out") / model.name)
    return Pipeline(
        path,
        model.name,
        model,
        scene,
        stages,
        out,
        base_dir,
        registry,
        Path(model.record),
        sorted_errors(files.warnings),
    )


def _stage_keys(index: int, raw: Any, registry: PluginRegistry, file: Path, lines: LineMap, context) -> tuple:
    """Pass 1 for one stage: its kind, and its keys validated against the kind's model."""
    where = ("pipeline", index)

    def error(message: str, *keys: Any) -> ConfigErrors:
        return ConfigErrors(
            [
                ConfigError(
                    message, file=file, location=format_path((*where, *keys)), line=line_of(lines, (*where, *keys))
                )
            ]
        )

    if not isinstance(raw, dict):
        raise error(f"a stage is a mapping with stage, plugin, settings, ...; got {type(raw).__name__}")
    if "stage" not in raw:
        raise error("required key is missing", "stage")
    name = raw["stage"]
    try:
        kind = registry.stage_kind(str(name))
    except SurgiplanError as exc:
        raise error(exc.message, "stage") from None
    problems: list[ConfigError] = []
    own = set(kind.model.model_fields)
    elsewhere = {}
    for other in registry.stage_kinds.values():
        for key in other.kind.model.model_fields:
            elsewhere.setdefault(key, []).append(other.name)
    keys = dict(raw)
    for key in [k for k in raw if k not in own and k in elsewhere]:
        kinds = elsewhere[key]
        listed = " and ".join([", ".join(kinds[:-1]), kinds[-1]] if len(kinds) > 1 else kinds)
        problems += error(f"{key} applies to {listed} stages only, not to {kind.name} stages", key).errors
        keys.pop(key)
    if kind.plugin_kind is None and raw.get("plugin") is not None:
        problems += error(f"{kind.name} stages take no plugin; remove 'plugin'", "plugin").errors
        keys.pop("plugin")
    elif kind.plugin_kind is not None and "plugin" not in raw:
        problems += error("required key is missing", "plugin").errors
    try:
        model = validate_model(kind.model, keys, file=file, lines=lines, prefix=where, context=context)
    except ConfigErrors as exc:
        problems += exc.errors
    if problems:
        raise ConfigErrors(problems)
    return kind, model


def _resolve_stage(
    index: int, kind: StageKind, keys: StageModel, raw: dict, registry: PluginRegistry, files: FileContext, names
) -> StageSpec:
    """Pass 2 for one stage: its plugin and settings, its name, and what its kind resolves from its keys."""
    where = ("pipeline", index)
    info, settings = None, None
    if kind.plugin_kind is not None:
        try:
            info = registry.get(kind.plugin_kind.name, keys.plugin)
        except SurgiplanError as exc:
            raise files.error(exc.message, *where, "plugin") from None
        settings = validate_model(
            info.settings_model,
            raw.get("settings") or {},
            file=files.file,
            lines=files.lines,
            prefix=(*where, "settings"),
            context=files.validation,
        )
    elif keys.settings:
        raise files.error(f"{kind.name} stages take no settings; their keys are their own", *where, "settings")
    name = keys.name or _unique(keys.plugin or kind.name, names)
    if name in names:
        raise files.error(f"stage name '{name}' is used twice; give each stage a unique name", *where, "name")
    spec = kind.spec_type(index, kind.name, name, info, settings, format_path(where), files.scene, keys)
    kind.resolve(spec, files)
    return spec


def _unique(base: str, names: set[str]) -> str:
    if base not in names:
        return base
    k = 2
    while f"{base}-{k}" in names:
        k += 1
    return f"{base}-{k}"


def _resource_errors(kind: StageKind, spec: StageSpec, file: Path, lines: LineMap) -> list[ConfigError]:
    """Estimates above the machine's memory, each a :class:`ConfigError` at the setting that drives it."""
    try:
        estimates = list(kind.estimate_resources(spec) or [])
    except Exception as exc:
        where = ("pipeline", spec.index, "plugin")
        who = f"plugin '{spec.plugin.name}' ({spec.plugin.package} {spec.plugin.version})" if spec.plugin else kind.name
        return [
            ConfigError(
                f"{who} failed to estimate its resources: {type(exc).__name__}: {exc}",
                file=file,
                location=format_path(where),
                line=line_of(lines, where),
            )
        ]
    errors = []
    for estimate, message in too_large(estimates):
        where = ("pipeline", spec.index, "settings", *([estimate.setting] if estimate.setting else []))
        errors.append(ConfigError(message, file=file, location=format_path(where), line=line_of(lines, where)))
    return errors
