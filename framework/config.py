"""Pipeline YAML -> pydantic models, remembering where every key came from.

The YAML syntax::

    name: cmu-search
    workspace: runs/cmu-search        # relative to the YAML file unless absolute
    executor: local                   # optional; `jobs:` sets the local pool size
    steps:
      motions: {uses: formats.load, with: {paths: ["../examples/data/cmu/**/*.amc"], fps: 30}}
      fe15:    {uses: features.end_effectors, input: motions}
      tree:    {uses: indexes.kdtree, input: fe15}
      matches: {uses: matchers.search, inputs: {database: tree, query: motions}, with: {count: 10}}

Step ids are dataset names (letters, digits, ``_`` and ``-``); ``input`` fills a
component's first input slot, ``inputs`` names slots explicitly.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .errors import ConfigError

_STEP_ID = re.compile(r"^[A-Za-z_][A-Za-z0-9_-]*$")
#: The longest step id: it names a folder (``<step>-<8 hex>`` while written), well under the
#: 255 bytes a file name may take on common filesystems.
MAX_STEP_ID = 100


class StepConfig(BaseModel):
    """One step of a pipeline as written in YAML."""

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

    uses: str
    input: str | None = None
    inputs: dict[str, str] = Field(default_factory=dict)
    with_: dict[str, Any] = Field(default_factory=dict, alias="with")

    @model_validator(mode="after")
    def _one_input_form(self) -> StepConfig:
        if self.input is not None and self.inputs:
            raise ValueError("give either `input` or `inputs`, not both")
        return self


class PipelineConfig(BaseModel):
    """A whole pipeline file."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    workspace: str | None = None
    executor: str = "local"
    jobs: int = Field(default=1, ge=0, description="local executor workers (0 = all cores)")
    executor_options: dict[str, Any] = Field(default_factory=dict)
    steps: dict[str, StepConfig]

    @field_validator("steps")
    @classmethod
    def _step_ids(cls, steps: dict[str, StepConfig]) -> dict[str, StepConfig]:
        if not steps:
            raise ValueError("a pipeline needs at least one step")
        for sid in steps:
            if not _STEP_ID.match(str(sid)):
                raise ValueError(
                    f"step id {str(sid)[:40]!r}{'...' if len(str(sid)) > 40 else ''} must start with a letter "
                    "or _ and hold only letters, digits, _ and -"
                )
            if len(str(sid)) > MAX_STEP_ID:
                raise ValueError(
                    f"step id {str(sid)[:40]!r}... has {len(str(sid))} characters; at most {MAX_STEP_ID} "
                    "(it names the step's folder)"
                )
        return steps


class _LineLoader(yaml.SafeLoader):  # type: ignore[misc]  # PyYAML has no type information
    """SafeLoader that records the line of every mapping key (path tuple -> 1-based line)."""


def _yaml_error(exc: yaml.YAMLError, source: str) -> ConfigError:
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    where = f"{source}:{mark.line + 1}" if mark is not None else source
    problem = getattr(exc, "problem", None) or str(exc)
    if isinstance(exc, yaml.constructor.ConstructorError) and "tag" in problem:
        problem = f"{problem.replace('could not determine a constructor for the', 'unsupported')}: pipelines are plain YAML (mappings, lists, strings, numbers, booleans)"
    return ConfigError(f"{where}: invalid YAML: {problem}")


#: Largest number of YAML nodes a document may expand to, aliases counted at every use: a
#: pipeline has hundreds; a 1 kB "billion laughs" of nested anchors expands to billions.
MAX_YAML_NODES = 100_000


def _too_large(source: str, node: yaml.Node) -> ConfigError:
    return ConfigError(
        f"{source}:{node.start_mark.line + 1}: anchors and aliases expand to more than {MAX_YAML_NODES} "
        "values (nested aliases multiply); write the values out or use fewer aliases"
    )


def _load_with_lines(text: str, source: str) -> tuple[Any, dict[tuple[str, ...], int]]:
    """Parse once; construct plain data only (an unknown or Python tag is a ConfigError at its
    line, never constructed); a key repeated in one mapping is an error too (YAML forbids
    it; PyYAML would keep the last one silently); aliases expanding past
    :data:`MAX_YAML_NODES` values are a ConfigError at the line of the node reached."""
    lines: dict[tuple[str, ...], int] = {}
    loader = _LineLoader(text)
    try:
        root = loader.get_single_node()

        active: set[int] = set()
        seen = [0]

        def walk(node: yaml.Node, path: tuple[str, ...]) -> None:
            if id(node) in active:
                raise ConfigError(f"{source}:{node.start_mark.line + 1}: an alias refers to a node that contains it")
            seen[0] += 1
            if seen[0] > MAX_YAML_NODES:
                raise _too_large(source, node)
            active.add(id(node))
            if isinstance(node, yaml.MappingNode):
                for k, v in node.value:
                    key = (*path, str(k.value))
                    if key in lines:
                        raise ConfigError(
                            f"{source}:{k.start_mark.line + 1}: key {k.value!r} appears twice "
                            f"(first at line {lines[key]})"
                        )
                    lines[key] = k.start_mark.line + 1
                    walk(v, key)
            elif isinstance(node, yaml.SequenceNode):
                for i, v in enumerate(node.value):
                    lines[path + (str(i),)] = v.start_mark.line + 1
                    walk(v, (*path, str(i)))
            active.discard(id(node))

        if root is None:
            return None, lines
        walk(root, ())
        return loader.construct_document(root), lines
    except yaml.YAMLError as exc:
        raise _yaml_error(exc, source) from None
    finally:
        loader.dispose()


class PipelineSource:
    """A parsed pipeline with its file name and key lines, for errors that point at the YAML."""

    def __init__(
        self,
        config: PipelineConfig,
        path: Path | None,
        lines: dict[tuple[str, ...], int],
        overrides: dict[tuple[str, ...], str] | None = None,
    ) -> None:
        self.config = config
        self.path = path
        self.lines = lines
        #: key path (``("steps", step, "with", ...)``) -> the ``--set`` item that gave it
        self.overrides = dict(overrides or {})

    @property
    def base_dir(self) -> Path:
        return self.path.parent if self.path is not None else Path.cwd()

    def where(self, *keys: str) -> str:
        """``file:line`` of the deepest known key along ``keys`` (plus the ``--set`` item
        when the value came from one)."""
        name = str(self.path) if self.path is not None else "<pipeline>"
        via = next(
            (
                f" (--set {self.overrides[tuple(keys[:n])]!r})"
                for n in range(len(keys), 0, -1)
                if tuple(keys[:n]) in self.overrides
            ),
            "",
        )
        for n in range(len(keys), 0, -1):
            line = self.lines.get(tuple(keys[:n]))
            if line is not None:
                return f"{name}:{line}{via}"
        return name + via

    def error(self, keys: tuple[str, ...], message: str) -> ConfigError:
        return ConfigError(f"{self.where(*keys)}: {message}")


def parse_pipeline(text: str, path: Path | None = None) -> PipelineSource:
    """Parse YAML text into a :class:`PipelineSource` (structure only; see :mod:`.plan`)."""
    source = str(path) if path is not None else "<pipeline>"
    data, lines = _load_with_lines(text, source)
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a pipeline is a mapping with `name` and `steps`")
    try:
        config = PipelineConfig.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        keys = tuple(str(p) for p in err["loc"])
        keys = tuple("with" if k == "with_" else k for k in keys)
        src = PipelineSource(PipelineConfig.model_construct(name="", steps={}), path, lines)
        field = ".".join(keys) or "pipeline"
        raise src.error(keys, f"{field}: {err['msg']}") from None
    return PipelineSource(config, path, lines)


def load_pipeline(path: str | Path) -> PipelineSource:
    """Read and parse a pipeline YAML file."""
    p = Path(path)
    try:
        if p.exists() and not p.is_file():  # a FIFO would block the read forever
            raise ConfigError(f"cannot read pipeline {p}: not a regular file")
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read pipeline {p}: {exc.strerror or exc}") from None
    return parse_pipeline(text, p.resolve())


def apply_overrides(source: PipelineSource, overrides: list[str] | tuple[str, ...]) -> PipelineSource:
    """Apply ``step.key=value`` overrides (value parsed as YAML) to the steps' ``with``."""
    steps = {k: v.model_dump(by_alias=True) for k, v in source.config.steps.items()}
    given = dict(source.overrides)
    for item in overrides:
        lhs, sep, rhs = item.partition("=")
        step, dot, key = lhs.strip().partition(".")
        if not sep or not dot or not key:
            raise ConfigError(f"--set {item!r}: expected STEP.KEY=VALUE")
        if step not in steps:
            from .registry import did_you_mean

            raise ConfigError(f"--set {item!r}: no step {step!r}{did_you_mean(step, list(steps))}")
        try:
            value = _load_with_lines(rhs, f"--set {item!r}")[0]
        except ConfigError as exc:
            if "invalid YAML" not in str(exc):
                raise
            value = rhs
        target = steps[step].setdefault("with", {})
        *parents, last = key.split(".")
        for part in parents:
            target = target.setdefault(part, {})
            if not isinstance(target, dict):
                raise ConfigError(f"--set {item!r}: {step}.{key.rpartition('.')[0]} is not a mapping")
        target[last] = value
        given[("steps", step, "with") + tuple(key.split("."))] = item
    data = source.config.model_dump()
    data["steps"] = steps
    return PipelineSource(PipelineConfig.model_validate(data), source.path, source.lines, given)
