"""Running a validated plan: atomic step outputs, provenance, skipping unchanged steps.

A run holds the workspace's lock (:mod:`.locking`) from start to end, writes temporary
outputs only inside the runner's own marked folder ``<workspace>/.mocapflow/`` and replaces
only step folders that are finished mocapflow datasets: nothing the user put in the
workspace folder is ever modified or deleted.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from .config import apply_overrides, load_pipeline
from .context import StepContext
from .datasets import MANIFEST, Dataset, StepOutput
from .errors import ConfigError, MocapflowError, PipelineError, PluginError
from .executors import ROW_GROUP_ROWS, Executor
from .locking import WorkspaceLock, remove_owned
from .plan import Plan, build_plan
from .plugins import build_registries, call_lifecycle, get_plugin_manager

log = logging.getLogger("mocapflow")
#: Inside the runner's own folder (``<workspace>/.mocapflow/``).
TMP_DIR = "tmp"
TRASH_DIR = "trash"


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


def _write_table(table: pa.Table, path: Path, provenance: dict[str, Any]) -> None:
    meta = dict(table.schema.metadata or {})
    meta[b"mocapflow"] = json.dumps(provenance, sort_keys=True, default=str).encode()
    # dictionaries only pay for strings, statistics only for flat columns (DuckDB prunes row
    # groups on clip_id/frame); both cost seconds on large nested float columns
    flat = [f.name for f in table.schema if not pa.types.is_nested(f.type)]
    strings = [f.name for f in table.schema if pa.types.is_string(f.type) or pa.types.is_large_string(f.type)]
    pq.write_table(
        table.replace_schema_metadata(meta),
        path,
        compression="zstd",
        use_dictionary=strings or False,
        write_statistics=flat or False,
        row_group_size=ROW_GROUP_ROWS,
    )


class Runner:
    """Executes a :class:`Plan` into a workspace.

    Parameters
    ----------
    plan : Plan
    workspace : Path
    executor : Executor
        Fans out per-clip work (``LocalExecutor(jobs)`` by default).
    hook : pluggy hook relay or None
        Lifecycle hooks (``before_step``, ``after_step``, ``on_step_error``).
    force : bool
        Recompute every step even when its fingerprint is unchanged.
    wait : float
        Seconds to wait for another run holding the workspace before refusing
        (:class:`~.errors.LockError`); ``0`` refuses at once.
    """

    def __init__(
        self,
        plan: Plan,
        workspace: Path,
        executor: Executor,
        registries,
        hook=None,
        force: bool = False,
        echo: Callable[[str], None] | None = None,
        wait: float = 0.0,
    ) -> None:
        self.plan = plan
        self.workspace = Path(workspace)
        self.executor = executor
        self.registries = registries
        self.hook = hook
        self.force = force
        self.echo = echo or (lambda msg: None)
        self.wait = wait
        self._own: Path | None = None

    def _clean_leftovers(self) -> None:
        """Remove half-written outputs of an interrupted run (never read, never kept); only
        inside the runner's own folder, and only while holding the lock."""
        remove_owned(self.workspace, TMP_DIR, TRASH_DIR)

    def _check_outputs_are_ours(self) -> None:
        """Refuse, before anything runs, to replace a folder the runner did not write."""
        for step in self.plan.steps:
            out = self.workspace / step.step_id
            if (out.exists() or out.is_symlink()) and (
                out.is_symlink() or not out.is_dir() or not (out / MANIFEST).is_file()
            ):
                raise ConfigError(
                    f"{out} exists and is not a mocapflow dataset (no {MANIFEST}); step {step.step_id!r} "
                    "would replace it: move it away, rename the step, or choose another workspace"
                )

    def _notify(self, hook_name: str, **kwargs: Any) -> None:
        if self.hook is not None:
            call_lifecycle(self.hook, hook_name, **kwargs)

    def run(self) -> list[StepReport]:
        self._check_outputs_are_ours()
        with WorkspaceLock(self.workspace, self.wait, self.plan.source.config.name, self.echo) as lock:
            self._own = lock.path.parent
            self._check_outputs_are_ours()  # again: another run may have finished meanwhile
            self._clean_leftovers()
            try:
                return self._run_steps()
            finally:
                self._clean_leftovers()

    def _run_steps(self) -> list[StepReport]:
        fingerprints = self.plan.fingerprints()
        reports = []
        for step in self.plan.steps:
            fp = fingerprints[step.step_id]
            out = self.workspace / step.step_id
            if not self.force and (out / MANIFEST).is_file():
                try:
                    previous = json.loads((out / MANIFEST).read_text()).get("fingerprint")
                except (OSError, ValueError):
                    previous = None
                if previous == fp:
                    reports.append(StepReport(step.step_id, step.key, "up to date"))
                    self.echo(f"  {step.step_id:<16} {step.key:<28} up to date")
                    continue
            reports.append(self._compute(step, fp, fingerprints))
        return reports

    def _compute(self, step, fp: str, fingerprints: dict[str, str]) -> StepReport:
        inputs = {slot: Dataset(self.workspace / up) for slot, up in step.inputs.items()}
        # a failing lifecycle hook is the plugin's error (PluginError naming it), not the step's
        self._notify("before_step", step_id=step.step_id, component=step.component, workspace=str(self.workspace))
        tmp = self._own / TMP_DIR / f"{step.step_id}-{uuid.uuid4().hex[:8]}"
        tmp.mkdir(parents=True)
        ctx = StepContext(step.step_id, tmp, self.plan.source.base_dir, self.workspace, self.registries, self.executor)
        self.echo(f"  {step.step_id:<16} {step.key:<28} running...")
        t0 = time.perf_counter()
        try:
            output = step.component.run(inputs, ctx)
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
            for name, table in output.tables.items():
                _write_table(table, tmp / f"{name}.parquet", provenance)
            provenance["tables"] = {name: t.num_rows for name, t in output.tables.items()}
            # the manifest is written last: a directory without it is never a dataset
            (tmp / MANIFEST).write_text(json.dumps(provenance, indent=2, sort_keys=True, default=str))
            self._commit(tmp, self.workspace / step.step_id)
        except BaseException as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            if isinstance(exc, Exception):
                try:
                    self._notify("on_step_error", step_id=step.step_id, component=step.component, error=exc)
                except PluginError as hook_exc:
                    raise PluginError(f"{hook_exc} (while reporting that step {step.step_id!r} failed: {exc})") from exc
            if isinstance(exc, MocapflowError):
                raise PipelineError(f"step {step.step_id!r} ({step.key}) failed: {exc}") from exc
            raise
        self._notify(
            "after_step",
            step_id=step.step_id,
            component=step.component,
            workspace=str(self.workspace),
            output_dir=str(self.workspace / step.step_id),
            seconds=seconds,
        )
        rows = {name: t.num_rows for name, t in output.tables.items()}
        self.echo(
            f"  {step.step_id:<16} {step.key:<28} computed in {seconds:.2f} s ({', '.join(f'{k}: {v} rows' for k, v in rows.items())})"
        )
        return StepReport(step.step_id, step.key, "computed", seconds, rows, output.summary)

    def _commit(self, tmp: Path, final: Path) -> None:
        """Swap the finished temporary directory in with renames (atomic on one filesystem)."""
        if final.exists():
            trash = self._own / TRASH_DIR / f"{final.name}-{uuid.uuid4().hex[:8]}"
            trash.parent.mkdir(parents=True, exist_ok=True)
            os.replace(final, trash)
            os.replace(tmp, final)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            os.replace(tmp, final)


def plan_pipeline(path: str | Path, overrides: tuple[str, ...] | list[str] = (), registries=None, pm=None) -> Plan:
    """Load, override and validate a pipeline file; nothing runs."""
    source = load_pipeline(path)
    if overrides:
        source = apply_overrides(source, overrides)
    if registries is None:
        pm = pm or get_plugin_manager()
        registries = build_registries(pm)
    return build_plan(source, registries)


def executor_classes(pm) -> dict[str, type]:
    """Executor classes registered through the ``register_executors`` hook, by name."""
    return dict(build_registries(pm).executors)


def make_executor(pm, name: str, jobs: int = 1, options: dict[str, Any] | None = None, registries=None) -> Executor:
    classes = dict(registries.executors) if registries is not None else executor_classes(pm)
    if name not in classes:
        from .registry import did_you_mean

        raise ConfigError(
            f"unknown executor {name!r}{did_you_mean(name, list(classes))}; known: {', '.join(sorted(classes))}"
        )
    try:
        return classes[name](jobs=jobs, **(options or {}))
    except TypeError as exc:
        raise ConfigError(f"executor {name!r}: bad executor_options: {exc}") from None


def run_pipeline(
    path: str | Path,
    workspace: str | Path | None = None,
    overrides: tuple[str, ...] | list[str] = (),
    jobs: int | None = None,
    force: bool = False,
    pm=None,
    executor: Executor | None = None,
    echo: Callable[[str], None] | None = None,
    wait: float = 0.0,
) -> list[StepReport]:
    """Plan and run a pipeline file; returns one :class:`StepReport` per step.

    Parameters
    ----------
    path : str or Path
        The YAML file.
    workspace : path, optional
        Overrides the pipeline's ``workspace`` (relative paths are relative to the cwd).
    overrides : list of ``"step.key=value"``
    jobs : int, optional
        Local executor workers (``0`` = all cores); overrides the pipeline's ``jobs``.
    force : bool
        Recompute steps even if up to date.
    pm : pluggy.PluginManager, optional
        A plugin manager (default: built-ins and entry points).
    executor : Executor, optional
        Use this executor instead of the configured one.
    wait : float
        Seconds to wait while another run holds the workspace (default: refuse at once
        with a :class:`~.errors.LockError` naming it).
    """
    pm = pm or get_plugin_manager()
    registries = build_registries(pm)
    source = load_pipeline(path)
    if overrides:
        source = apply_overrides(source, overrides)
    cfg = source.config
    own = executor is None
    ex = executor
    if own and cfg.executor in dict(registries.executors):  # an unknown one: build_plan says so
        ex = make_executor(pm, cfg.executor, cfg.jobs if jobs is None else jobs, cfg.executor_options, registries)
    start = getattr(ex, "start", None)
    if start is not None:  # workers come up (a cluster's start-up) while the client plans
        start()
    try:
        plan = build_plan(source, registries)
        ws = Path(workspace).resolve() if workspace is not None else default_workspace(plan)
        if ex is None:
            ex = make_executor(pm, cfg.executor, cfg.jobs if jobs is None else jobs, cfg.executor_options, registries)
        return Runner(plan, ws, ex, registries, hook=pm.hook, force=force, echo=echo, wait=wait).run()
    finally:
        if own and ex is not None:
            ex.close()
