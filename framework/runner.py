"""Running a validated plan: one step after another into a workspace, skipping unchanged
steps, holding the workspace lock; each output committed atomically with its provenance."""

from __future__ import annotations

import contextlib
import errno
import logging
import shutil
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pluggy
from pydantic import ValidationError

from .config import PipelineSource, apply_overrides, load_pipeline
from .context import Executor, StepContext
from .datasets import Dataset, StepOutput
from .errors import ConfigError, MocapflowError, PipelineError, PluginError
from .plan import Plan, PlannedStep, build_plan
from .plugins import build_registries, call_lifecycle, describe, get_plugin_manager
from .progress import heartbeat
from .registry import Registries, did_you_mean
from .steps import run_step
from .workspace import Workspace, write_error

log = logging.getLogger("mocapflow")

#: errnos of a write that found no room: the runner says so instead of a traceback
_DISK_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


@dataclass
class StepReport:
    """What happened to one step: ``status`` is ``"computed"`` or ``"up to date"``."""

    step_id: str
    component: str
    status: str
    seconds: float = 0.0
    rows: dict[str, int] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)


def default_workspace(plan: Plan) -> Path:
    cfg = plan.source.config
    ws = Path(cfg.workspace) if cfg.workspace else Path("runs") / cfg.name
    return ws if ws.is_absolute() else plan.source.base_dir / ws


class Runner:
    """Executes a :class:`Plan` into a workspace with the run's ``registries`` and
    ``executor``; ``hook``: the lifecycle hook relay; ``force``: recompute every step;
    ``wait``: seconds to wait for another run holding the workspace."""

    def __init__(
        self,
        plan: Plan,
        workspace: Path,
        executor: Executor,
        registries: Registries,
        hook: Any = None,
        force: bool = False,
        echo: Callable[[str], None] | None = None,
        wait: float = 0.0,
    ) -> None:
        self.plan = plan
        self.workspace = Workspace(workspace)
        self.executor = executor
        self.registries = registries
        self.hook = hook
        self.force = force
        self.echo: Callable[[str], None] = echo or (lambda msg: None)
        self.wait = wait

    def _notify(self, hook_name: str, **kwargs: Any) -> None:
        if self.hook is not None:
            call_lifecycle(self.hook, hook_name, **kwargs)

    def run(self) -> list[StepReport]:
        ws, step_ids = self.workspace, [s.step_id for s in self.plan.steps]
        ws.check_outputs(step_ids)
        with ws.lock(self.wait, self.plan.source.config.name, self.echo):
            ws.check_outputs(step_ids)  # again: another run may have finished meanwhile
            ws.clean_leftovers()
            try:
                return self._run_steps()
            finally:
                ws.clean_leftovers()

    def _run_steps(self) -> list[StepReport]:
        fingerprints = self.plan.fingerprints()
        reports = []
        for step in self.plan.steps:
            fp = fingerprints[step.step_id]
            if not self.force and self.workspace.fingerprint(step.step_id) == fp:
                reports.append(StepReport(step.step_id, step.key, "up to date"))
                self.echo(f"  {step.step_id:<16} {step.key:<28} up to date")
                continue
            reports.append(self._compute(step, fp, fingerprints))
        return reports

    def _compute(self, step: PlannedStep, fp: str, fingerprints: Mapping[str, str]) -> StepReport:
        ws = self.workspace
        inputs = {slot: Dataset(ws.path / up) for slot, up in step.inputs.items()}
        # a failing lifecycle hook is the plugin's error (PluginError naming it), not the step's
        self._notify("before_step", step_id=step.step_id, component=step.component, workspace=str(ws.path))
        tmp = ws.temp_dir(step.step_id)
        ctx = StepContext(step.step_id, tmp, self.plan.source.base_dir, ws.path, self.registries, self.executor)
        self.echo(f"  {step.step_id:<16} {step.key:<28} running...")
        last = ws.path / step.step_id  # the step's previous output: how long it took then
        expected = None
        with contextlib.suppress(Exception):  # no or unreadable previous output: no ETA
            expected = float(Dataset(last).manifest["seconds"])
        t0 = time.perf_counter()
        try:
            with heartbeat(f"  {step.step_id}", expected):  # a step with no bar of its own still moves
                output = run_step(step.component, inputs, ctx)
            if not isinstance(output, StepOutput):
                raise PipelineError(f"{step.key}.run() returned {type(output).__name__}, expected StepOutput")
            seconds = time.perf_counter() - t0
            provenance = {
                "step": step.step_id,
                "component": step.key,
                "version": step.component.version,
                "params": step.component.get_params(),
                "inputs": {slot: {"step": up, "fingerprint": fingerprints[up]} for slot, up in step.inputs.items()},
                "fingerprint": fp,
                "pipeline": self.plan.source.config.name,
                "seconds": round(seconds, 3),
                "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "summary": output.summary,
            }
            ws.write_step(tmp, step.step_id, output.tables, provenance)
        except BaseException as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            if isinstance(exc, OSError) and exc.errno in _DISK_FULL:  # while the step streamed its tables
                exc = write_error(exc)
            if isinstance(exc, Exception):
                try:
                    self._notify("on_step_error", step_id=step.step_id, component=step.component, error=exc)
                except PluginError as hook_exc:
                    raise PluginError(f"{hook_exc} (while reporting that step {step.step_id!r} failed: {exc})") from exc
            if isinstance(exc, MocapflowError):
                raise PipelineError(f"step {step.step_id!r} ({step.key}) failed: {exc}") from exc
            if isinstance(exc, SystemExit):  # a component's sys.exit(): its step failed, our exit status
                raise PipelineError(f"step {step.step_id!r} ({step.key}) failed: it raised {describe(exc)}") from exc
            raise
        self._notify(
            "after_step",
            step_id=step.step_id,
            component=step.component,
            workspace=str(ws.path),
            output_dir=str(ws.path / step.step_id),
            seconds=seconds,
        )
        rows = {name: t.num_rows for name, t in output.tables.items()}
        counts = ", ".join(f"{k}: {v} rows" for k, v in rows.items())
        reused = output.summary.get("reused_clips")
        if isinstance(reused, int) and reused:  # a step that computed only what changed says so
            counts += f"; {reused} unchanged clips copied from the last run, only the rest computed"
        self.echo(f"  {step.step_id:<16} {step.key:<28} computed in {seconds:.2f} s ({counts})")
        return StepReport(step.step_id, step.key, "computed", seconds, rows, output.summary)


def _source(path: str | Path, overrides: tuple[str, ...] | list[str]) -> PipelineSource:
    source = load_pipeline(path)
    return apply_overrides(source, overrides) if overrides else source


def plan_pipeline(
    path: str | Path,
    overrides: tuple[str, ...] | list[str] = (),
    registries: Registries | None = None,
    pm: pluggy.PluginManager | None = None,
) -> Plan:
    """Load, override and validate a pipeline file; nothing runs. Without ``registries``
    they are built from ``pm`` (default: a plugin manager of every installed plugin)."""
    if registries is None:
        registries = build_registries(pm or get_plugin_manager())
    return build_plan(_source(path, overrides), registries)


def make_executor(
    registries: Registries, name: str, jobs: int = 1, options: Mapping[str, Any] | None = None
) -> Executor:
    """The executor registered as ``name``, its options validated by its ``Params``."""
    executors = registries.executors
    if name not in executors:
        known = executors.names()
        raise ConfigError(f"unknown executor {name!r}{did_you_mean(name, known)}; known: {', '.join(known)}")
    cls = executors.get(name)
    try:
        params = cls.Params(**{"jobs": jobs, **(options or {})})
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        raise ConfigError(f"executor {name!r}: bad executor_options: {where}: {err['msg']}") from None
    executor: Executor = cls(**params.model_dump())
    return executor


def run_pipeline(
    path: str | Path,
    workspace: str | Path | None = None,
    overrides: tuple[str, ...] | list[str] = (),
    jobs: int | None = None,
    force: bool = False,
    pm: pluggy.PluginManager | None = None,
    executor: Executor | None = None,
    echo: Callable[[str], None] | None = None,
    wait: float = 0.0,
) -> list[StepReport]:
    """Plan and run a pipeline file (one :class:`StepReport` per step). ``workspace``,
    ``jobs`` (0: all cores) and ``executor`` override the pipeline's; ``overrides`` are
    ``"step.key=value"``; ``pm`` defaults to every installed plugin; ``wait`` as in
    :class:`Runner`."""
    pm = pm or get_plugin_manager()
    registries = build_registries(pm)
    source = _source(path, overrides)
    cfg = source.config
    own = executor is None
    ex = executor
    n_jobs = cfg.jobs if jobs is None else jobs
    if own and cfg.executor in registries.executors:  # an unknown one: build_plan says so
        ex = make_executor(registries, cfg.executor, n_jobs, cfg.executor_options)
    start = getattr(ex, "start", None)
    if start is not None:  # workers come up (a cluster's start-up) while the client plans
        start()
    try:
        plan = build_plan(source, registries)
        ws = Path(workspace).resolve() if workspace is not None else default_workspace(plan)
        if ex is None:
            ex = make_executor(registries, cfg.executor, n_jobs, cfg.executor_options)
        return Runner(plan, ws, ex, registries, hook=pm.hook, force=force, echo=echo, wait=wait).run()
    finally:
        if own and ex is not None:
            ex.close()
