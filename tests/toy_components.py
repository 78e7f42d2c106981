"""Tiny components registered through a test plugin object (``extra=[ToyPlugin()]``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any

import numpy as np
import pyarrow as pa
from pydantic import Field
from synthetic import random_motion

from mocapflow.framework import Analysis, FeatureSet, Matcher, Params, PipelineError, QueryMatches, StepOutput, hookimpl
from mocapflow.framework.components import ParamsOf
from mocapflow.framework.conformance import ReferenceIndex
from mocapflow.framework.motion_tables import motions_to_tables


def _log_call(ctx, name: str) -> None:
    with open(ctx.workspace / "calls.log", "a") as f:
        f.write(f"{ctx.step_id}:{name}\n")


class ToySource(Analysis):
    """Numbers 0..n-1 times scale."""

    name = "toy_source"
    inputs: Mapping[str, bool] = {}

    class Params(Params):
        n: int = Field(5, ge=1)
        scale: float = 1.0

    def run(self, inputs, ctx):
        _log_call(ctx, self.name)
        (ctx.out_dir / "note.txt").write_text("side file")
        return StepOutput({"data": pa.table({"x": np.arange(self.params.n) * self.params.scale})})


class ToyAdd(Analysis):
    """Adds a constant to the upstream x."""

    name = "toy_add"
    inputs: Mapping[str, bool] = {"source": True, "other": False}

    class Params(Params):
        add: float = 1.0

    def run(self, inputs, ctx):
        _log_call(ctx, self.name)
        x = inputs["source"].table()["x"].to_numpy()
        return StepOutput({"data": pa.table({"x": x + self.params.add})})


class ToyFail(Analysis):
    """Writes a partial file, then fails (or not, when ``fail: false``)."""

    name = "toy_fail"
    inputs: Mapping[str, bool] = {"source": True}

    class Params(Params):
        fail: bool = True

    def run(self, inputs, ctx):
        _log_call(ctx, self.name)
        (ctx.out_dir / "partial.bin").write_bytes(b"half")
        if self.params.fail:
            raise PipelineError("toy failure on purpose")
        return StepOutput({"data": pa.table({"ok": [True]})})


class ToyMotions(Analysis):
    """A motions dataset of synthetic clips (so pipelines run without readers)."""

    name = "toy_motions"
    inputs: Mapping[str, bool] = {}

    class Params(Params):
        clips: int = 3
        frames: int = 40

    def run(self, inputs, ctx):
        motions = [random_motion(self.params.frames, seed=i) for i in range(self.params.clips)]
        return StepOutput(motions_to_tables(motions))


class ToyPlugin:
    @hookimpl
    def register_analyses(self):
        return [ToySource, ToyAdd, ToyFail, ToyMotions, ToySlow, ToyGate]


class RecordingExecutor:
    """An executor from a plugin: runs in-process and records what it mapped."""

    name = "recording"
    seen: list[str] = []
    workers = 1

    class Params(Params):
        jobs: int = 1
        label: str = "x"

    def __init__(self, jobs: int = 1, label: str = "x") -> None:
        self.label = label

    def map(self, fn, items, desc=""):
        RecordingExecutor.seen.append(f"{self.label}:{desc}:{len(items)}")
        return [fn(x) for x in items]

    def close(self) -> None:
        RecordingExecutor.seen.append("closed")


class ExecutorPlugin:
    @hookimpl
    def register_executors(self):
        return [RecordingExecutor]


class ToySlow(Analysis):
    """Writes part of its output, signals, then sleeps (to be killed mid-step in tests)."""

    name = "toy_slow"
    inputs: Mapping[str, bool] = {"source": True}

    class Params(Params):
        seconds: float = 30.0

    def run(self, inputs, ctx):
        import time

        (ctx.out_dir / "data.parquet").write_bytes(b"PAR1 half-written")
        (ctx.workspace / "slow-started").write_text("1")
        time.sleep(self.params.seconds)
        return StepOutput({"data": pa.table({"x": inputs["source"].table()["x"]})})


class RaisingPlugin:
    """A third-party plugin whose every registration hook raises (``RAISING`` is its
    entry-point object in the tests)."""

    @hookimpl
    def register_analyses(self):
        raise RuntimeError("analyses exploded")

    @hookimpl
    def register_executors(self):
        raise RuntimeError("executors exploded")

    @hookimpl
    def register_commands(self):
        raise RuntimeError("commands exploded")


RAISING = RaisingPlugin()


class ToyGate(Analysis):
    """Says it started (``<workspace>/gate-started``), then waits until the test creates
    ``<workspace>/gate-open`` (at most ``timeout`` seconds): a step that ends on cue."""

    name = "toy_gate"
    inputs: Mapping[str, bool] = {}

    class Params(Params):
        timeout: float = 120.0

    def run(self, inputs, ctx):
        import time

        (ctx.workspace / "gate-started").write_text("1")
        deadline = time.monotonic() + self.params.timeout
        while not (ctx.workspace / "gate-open").exists():
            if time.monotonic() > deadline:
                raise PipelineError("toy_gate: nobody opened the gate")
            time.sleep(0.05)
        return StepOutput({"data": pa.table({"x": [1.0]})})


class HookFailures:
    """Lifecycle hooks that raise on the steps named in ``fail`` (hook name -> step ids)."""

    def __init__(self, **fail: tuple[str, ...]) -> None:
        self.fail = fail
        self.seen: list[str] = []

    def _maybe(self, hook: str, step_id: str) -> None:
        self.seen.append(f"{hook}:{step_id}")
        if step_id in self.fail.get(hook, ()):
            raise RuntimeError(f"{hook} hook broke on {step_id}")

    @hookimpl
    def before_step(self, step_id, component, workspace):
        self._maybe("before_step", step_id)

    @hookimpl
    def after_step(self, step_id, output_dir):
        self._maybe("after_step", step_id)

    @hookimpl
    def on_step_error(self, step_id, error):
        self._maybe("on_step_error", step_id)


class ToyNested(Analysis):
    """Holds the parameters of another component, chosen by a sibling parameter."""

    name = "toy_nested"
    inputs: Mapping[str, bool] = {}

    class Params(Params):
        target: str = "toy_source"
        options: Annotated[dict[str, Any], ParamsOf("analyses.{target}")] = Field(default_factory=dict)
        fixed: Annotated[dict[str, Any], ParamsOf("analyses.toy_add")] = Field(default_factory=dict)

    def run(self, inputs, ctx):
        return StepOutput({"data": pa.table({"x": [float(len(self.params.options))]})})


class NestedPlugin:
    @hookimpl
    def register_analyses(self):
        return [ToyNested]


class ToyRoot(FeatureSet):
    """The root position per frame (3 numbers)."""

    name = "toy_root"

    @property
    def dim(self) -> int:
        return 3

    def transform_motion(self, motion):
        return np.asarray(motion.root_translation, np.float32)


class ToyKdtree(ReferenceIndex):
    """Brute force registered as ``indexes.kdtree``: stands in for the built-in when it is blocked."""

    name = "kdtree"


class ToyNearest(Matcher):
    """The database row nearest to the query's first frame, as a one-row match."""

    name = "toy_nearest"

    def match(self, query, space):
        dist, ids = space.neighbors(query[:1], 1)
        row = int(ids[0, 0])
        return QueryMatches(
            np.array([row]), np.array([row + 1]), dist[0, :1].astype(np.float64), np.array([1]), [np.array([[0, row]])]
        )


class StandInPlugin:
    """``features.toy_root``, ``indexes.kdtree`` (a stand-in) and ``matchers.toy_nearest``."""

    @hookimpl
    def register_features(self):
        return [ToyRoot]

    @hookimpl
    def register_indexes(self):
        return [ToyKdtree]

    @hookimpl
    def register_matchers(self):
        return [ToyNearest]
