"""Validating a whole pipeline before anything runs.

Names, parameters (nested ones too, :class:`~.components.ParamsOf`), input slots and the
kinds of dataset they accept, the executor, cycles, and each component's own
:meth:`~.components.Component.check_plan` (warnings such as a glob matching no file).
"""

from __future__ import annotations

import graphlib
import hashlib
import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pydantic import BaseModel, ValidationError

from .components import Component, ParamsOf
from .config import PipelineSource
from .errors import ConfigError
from .params import Params
from .registry import Registries, did_you_mean, params_error

log = logging.getLogger("mocapflow")


@dataclass
class PlannedStep:
    """A validated step: its component instance and which step feeds each input slot."""

    step_id: str
    component: Component
    inputs: dict[str, str] = field(default_factory=dict)

    @property
    def key(self) -> str:
        return self.component.key()


@dataclass
class Plan:
    """Steps in a valid execution order (topological, ties in YAML order)."""

    source: PipelineSource
    steps: list[PlannedStep]
    #: Plan-time warnings (``file:line: step ...: message``), also logged.
    warnings: list[str] = field(default_factory=list)

    def __getitem__(self, step_id: str) -> PlannedStep:
        for s in self.steps:
            if s.step_id == step_id:
                return s
        raise KeyError(step_id)

    def fingerprints(self) -> dict[str, str]:
        """Step id -> fingerprint of (component, version, params, sources, input fingerprints)."""
        out: dict[str, str] = {}
        for s in self.steps:
            payload = {
                "component": s.key,
                "version": s.component.version,
                "params": s.component.get_params(),
                "sources": s.component.source_fingerprint(self.source.base_dir),
                "inputs": {slot: out[up] for slot, up in sorted(s.inputs.items())},
            }
            blob = json.dumps(payload, sort_keys=True, default=str).encode()
            out[s.step_id] = hashlib.sha256(blob).hexdigest()[:24]
        return out


def _param_error(
    source: PipelineSource,
    step_id: str,
    cls: type[Component],
    exc: ValidationError,
    prefix: tuple[str, ...] = (),
    model: type[BaseModel] | None = None,
    what: str = "",
) -> ConfigError:
    """A ConfigError at the YAML line of the offending key (``prefix``: the path of a nested
    parameter dict, ``model``: its Params, ``what``: whose parameters they are)."""
    of = f" (parameters of {what})" if what else ""
    loc, msg = params_error(f"{cls.key()}{of}", exc, model or cls.Params, prefix)
    return source.error(("steps", step_id, "with", *loc), f"step {step_id!r}: {msg}")


class _Fields(dict[str, Any]):
    def __missing__(self, key: str) -> str:
        raise ConfigError(f"ParamsOf key refers to no parameter {key!r}")


def _check_nested(
    source: PipelineSource,
    step_id: str,
    cls: type[Component],
    params: BaseModel,
    registries: Registries,
    prefix: tuple[str, ...] = (),
) -> None:
    """Validate every ``ParamsOf`` dict parameter against its component's ``Params``, recursively.

    The key may name sibling parameters (``ParamsOf("features.{features}")``)."""
    for name, f in type(params).model_fields.items():
        marker = next((m for m in f.metadata if isinstance(m, ParamsOf)), None)
        value = getattr(params, name)
        if marker is None or not isinstance(value, Mapping):
            continue
        here = (*prefix, name)
        try:
            key = marker.key.format_map(_Fields({k: getattr(params, k) for k in type(params).model_fields}))
            target = registries.resolve(key)
        except ConfigError as exc:
            raise source.error(
                ("steps", step_id, "with", *here),
                f"step {step_id!r}: parameter {'.'.join(here)!r} of {cls.key()} holds component parameters: {exc}",
            ) from None
        try:
            nested = target.Params(**value)
        except ValidationError as exc:
            raise _param_error(source, step_id, cls, exc, here, target.Params, target.key()) from None
        _check_nested(source, step_id, cls, nested, registries, here)


def _a(word: str) -> str:
    return f"{'an' if word[:1] in 'aeiou' else 'a'} {word}"


def _check_kinds(source: PipelineSource, steps: dict[str, PlannedStep]) -> None:
    """Each input slot gets a dataset of a kind it accepts (where both sides declare one)."""
    for sid, ps in steps.items():
        cls = type(ps.component)
        single = source.config.steps[sid].input is not None
        for slot, up in ps.inputs.items():
            accepted = cls.input_kinds.get(slot)
            produced = type(steps[up].component).output_kind
            if accepted and produced and produced not in accepted:
                where = ("steps", sid, "input") if single else ("steps", sid, "inputs", slot)
                raise source.error(
                    where,
                    f"step {sid!r}: input {slot!r} of {cls.key()} takes {_a(' or '.join(accepted))} "
                    f"dataset, but step {up!r} ({steps[up].key}) writes {_a(produced)} dataset",
                )


def _check_executor(source: PipelineSource, registries: Registries) -> None:
    """The executor is registered and ``executor_options`` validate against its ``Params``."""
    config, executors = source.config, registries.executors
    if not len(executors):  # a bare Registries() knows none: not checked
        return
    if config.executor not in executors:
        raise source.error(
            ("executor",),
            f"unknown executor {config.executor!r}{did_you_mean(config.executor, executors.names())}; "
            f"registered: {', '.join(executors.names())}",
        )
    model: type[BaseModel] = executors.get(config.executor).Params
    try:
        model(**{"jobs": config.jobs, **config.executor_options})
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = tuple(str(p) for p in err["loc"])
        known = ", ".join(model.model_fields)
        raise source.error(
            ("executor_options", *loc),
            f"executor {config.executor!r}: option {'.'.join(loc)!r}: {err['msg']} (options: {known})",
        ) from None


def _plan_step(source: PipelineSource, step_id: str, registries: Registries) -> PlannedStep:
    """One step checked on its own: component, parameters (nested ones too), input slots."""
    config, sc = source.config, source.config.steps[step_id]
    try:
        cls: type[Component] = registries.resolve(sc.uses)
    except ConfigError as exc:
        raise source.error(("steps", step_id, "uses"), f"step {step_id!r}: {exc}") from None
    if not cls.is_step:
        raise source.error(
            ("steps", step_id, "uses"),
            f"step {step_id!r}: {sc.uses} is a file format, not a step; use formats.load",
        )
    try:
        component = cls(cls.Params(**sc.with_))
    except ValidationError as exc:
        raise _param_error(source, step_id, cls, exc) from None
    _check_nested(source, step_id, cls, component.params, registries)
    slots = dict(cls.inputs)
    if sc.input is not None:
        if not slots:
            raise source.error(("steps", step_id, "input"), f"step {step_id!r}: {sc.uses} takes no input")
        inputs = {next(iter(slots)): sc.input}
    else:
        inputs = dict(sc.inputs)
    for slot, upstream in inputs.items():
        if slot not in slots:
            known = f"{did_you_mean(slot, list(slots))}; slots: {', '.join(slots) or 'none'}"
            raise source.error(
                ("steps", step_id, "inputs", slot), f"step {step_id!r}: {sc.uses} has no input {slot!r}{known}"
            )
        if upstream not in config.steps:
            raise source.error(
                ("steps", step_id, "input" if sc.input is not None else "inputs"),
                f"step {step_id!r}: input {slot!r} refers to unknown step {upstream!r}"
                f"{did_you_mean(upstream, list(config.steps))}",
            )
        if upstream == step_id:
            raise source.error(("steps", step_id), f"step {step_id!r} uses its own output as input")
    missing = [s for s, required in slots.items() if required and s not in inputs]
    if missing:
        raise source.error(
            ("steps", step_id),
            f"step {step_id!r}: missing required input {', '.join(map(repr, missing))} for {sc.uses}",
        )
    return PlannedStep(step_id, component, inputs)


def build_plan(source: PipelineSource, registries: Registries) -> Plan:
    """Validate everything (components, parameters, nested ``ParamsOf``, input slots and
    dataset kinds, executor, no cycle, each ``check_plan``) into a :class:`Plan`; raises
    :class:`ConfigError`. ``check_plan`` warnings are logged and kept in ``Plan.warnings``."""
    config = source.config
    steps = {step_id: _plan_step(source, step_id, registries) for step_id in config.steps}

    _check_kinds(source, steps)
    _check_executor(source, registries)
    sorter = graphlib.TopologicalSorter({sid: set(s.inputs.values()) for sid, s in steps.items()})
    try:
        order = list(sorter.static_order())
    except graphlib.CycleError as exc:
        cycle = exc.args[1]
        raise source.error(("steps", cycle[0]), f"steps form a cycle: {' -> '.join(cycle)}") from None
    # keep YAML order among independent steps, so runs read top to bottom
    yaml_pos = {sid: i for i, sid in enumerate(config.steps)}
    ordered: list[str] = []
    done: set[str] = set()
    remaining = sorted(order, key=yaml_pos.__getitem__)
    while remaining:
        for sid in remaining:
            if set(steps[sid].inputs.values()) <= done:
                ordered.append(sid)
                done.add(sid)
                remaining.remove(sid)
                break
    from .queries import query_spans_error

    for sid in ordered:  # query ranges past their take's end fail here, not halfway through the run
        err = query_spans_error(
            steps[sid].component, steps[sid].inputs.get("query"), steps, source.base_dir, registries
        )
        if err:
            raise source.error(("steps", sid, "with", "queries"), f"step {sid!r}: {err}")
    warnings = []
    for sid in ordered:
        try:
            found = steps[sid].component.check_plan(source.base_dir)
        except ConfigError as exc:
            raise source.error(("steps", sid, "with"), f"step {sid!r}: {exc}") from None
        params = steps[sid].component.params
        found = [*(params.deprecations() if isinstance(params, Params) else []), *(found or [])]
        for w in found:
            warnings.append(f"{source.where('steps', sid, 'with')}: step {sid!r}: {w}")
            log.warning("%s", warnings[-1])
    return Plan(source, [steps[s] for s in ordered], warnings)
