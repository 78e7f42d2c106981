"""Validating a whole pipeline before anything runs (names, parameters, inputs, cycles)."""
from __future__ import annotations

import graphlib
import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

from pydantic import ValidationError

from .components import Component
from .config import PipelineSource
from .errors import ConfigError
from .registry import Registries, did_you_mean


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

    def downstream(self, step_id: str) -> set[str]:
        """Steps that (transitively) consume ``step_id``'s output."""
        found: set[str] = set()
        frontier = {step_id}
        while frontier:
            nxt = {s.step_id for s in self.steps if set(s.inputs.values()) & frontier} - found
            found |= nxt
            frontier = nxt
        return found


def _param_error(source: PipelineSource, step_id: str, cls: type[Component], exc: ValidationError) -> ConfigError:
    err = exc.errors()[0]
    loc = tuple(str(p) for p in err["loc"])
    key = ".".join(loc) or "with"
    if err["type"] == "extra_forbidden":
        known = list(cls.Params.model_fields)
        msg = f"unknown parameter {key!r} for {cls.key()}{did_you_mean(loc[-1], known)}; known: {', '.join(known) or 'none'}"
    else:
        got = err.get("input")
        msg = f"parameter {key!r} of {cls.key()}: {err['msg']} (got {got!r})"
    return source.error(("steps", step_id, "with", *loc[:1]), f"step {step_id!r}: {msg}")


def build_plan(source: PipelineSource, registries: Registries) -> Plan:
    """Validate everything and return a :class:`Plan`; raises :class:`ConfigError`.

    Checks, for every step: the component exists (with "did you mean"), it can be a step,
    its ``with`` parameters validate against its ``Params``, every input slot exists and
    every required one is filled, every referenced step exists; then the graph has no cycle.
    """
    config = source.config
    steps: dict[str, PlannedStep] = {}
    for step_id, sc in config.steps.items():
        try:
            cls = registries.resolve(sc.uses)
        except ConfigError as exc:
            raise source.error(("steps", step_id, "uses"), f"step {step_id!r}: {exc}") from None
        if not getattr(cls, "is_step", True):
            raise source.error(("steps", step_id, "uses"), f"step {step_id!r}: {sc.uses} is a file format, not a step; use formats.load")
        try:
            component = cls(cls.Params(**sc.with_))
        except ValidationError as exc:
            raise _param_error(source, step_id, cls, exc) from None
        slots = dict(cls.inputs)
        if sc.input is not None:
            if not slots:
                raise source.error(("steps", step_id, "input"), f"step {step_id!r}: {sc.uses} takes no input")
            inputs = {next(iter(slots)): sc.input}
        else:
            inputs = dict(sc.inputs)
        for slot, upstream in inputs.items():
            if slot not in slots:
                raise source.error(("steps", step_id, "inputs", slot),
                                   f"step {step_id!r}: {sc.uses} has no input {slot!r}{did_you_mean(slot, list(slots))}; slots: {', '.join(slots) or 'none'}")
            if upstream not in config.steps:
                raise source.error(("steps", step_id, "input" if sc.input is not None else "inputs"),
                                   f"step {step_id!r}: input {slot!r} refers to unknown step {upstream!r}{did_you_mean(upstream, list(config.steps))}")
            if upstream == step_id:
                raise source.error(("steps", step_id), f"step {step_id!r} uses its own output as input")
        missing = [s for s, required in slots.items() if required and s not in inputs]
        if missing:
            raise source.error(("steps", step_id), f"step {step_id!r}: missing required input {', '.join(map(repr, missing))} for {sc.uses}")
        steps[step_id] = PlannedStep(step_id, component, inputs)

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
    return Plan(source, [steps[s] for s in ordered])


def describe(plan: Plan) -> list[dict[str, Any]]:
    """Rows describing a plan (for ``mocapflow plan``)."""
    return [
        {"step": s.step_id, "uses": s.key, "inputs": s.inputs, "params": s.component.get_params()}
        for s in plan.steps
    ]
