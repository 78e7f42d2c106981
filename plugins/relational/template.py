"""``matchers.template``: motion templates learned from labelled examples (Müller & Röder 2006).

The step fits one template per class from the relational feature matrices of labelled
example clips (:mod:`.template_model`), stores them in its output (``templates.npz``, like
``features.pca`` stores its model) and retrieves every template in the database by
subsequence DTW whose local cost ignores don't-care cells. A later step reuses fitted
templates by naming this step as its ``reference`` input::

    templates: {uses: matchers.template, inputs: {database: relational, motions: motions},
                with: {train: "HDM_(bd|bk)_"}}
    again:     {uses: matchers.template, inputs: {database: other, motions: m2, reference: templates}}

Labels come from the motions' ``labels`` table when the ingest wrote one (``formats.load``
with ``labels``: a CSV, or ``label_pattern``), else from clip names (``label_pattern`` here,
a regular expression with a group ``label``); the training clips are those whose names
match ``train``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework.components import Matcher
from mocapflow.framework.components import Params as BaseParams
from mocapflow.framework.errors import ConfigError, DataError, PipelineError
from mocapflow.framework.params import Removed
from mocapflow.framework.schema import MATCHES

from .labels import labels_of
from .template_model import (
    MotionTemplate,
    fit_class_template,
    frame_codes,
    load_templates,
    save_templates,
    search_costs,
)

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.context import StepContext
    from mocapflow.framework.datasets import Dataset, StepOutput

    from .template_coarse import CoarseCodes
    from .template_cutoff import RivalTable

#: HDM05 cut names ``HDM_<actor>_<class>_<nnn>_<rate>``.
HDM05_LABEL = r"^HDM_[A-Za-z]+_(?P<label>[A-Za-z0-9]+)_\d+"
#: The HDM05 actor.
HDM05_GROUP = r"^HDM_(?P<group>[A-Za-z]+)_"


def clip_labels(names: list[str], pattern: str, group: str = "label") -> list[str | None]:
    """The ``group`` of ``pattern`` in each clip name (class label, actor; None if no match)."""
    rx = re.compile(pattern)
    if group not in rx.groupindex:
        raise ConfigError(f"pattern {pattern!r} needs a named group (?P<{group}>...)")
    out = []
    for n in names:
        m = rx.search(n)
        out.append(m.group(group) if m else None)
    return out


def fit_templates(
    bits: np.ndarray,
    offsets: np.ndarray,
    labels: list[str | None],
    train: np.ndarray,
    groups: list[str | None] | None = None,
    classes: list[str] | None = None,
) -> list[MotionTemplate]:
    """One template per class from the ``train`` clips (n_clips,) of ``bits`` (N, 31) split at
    ``offsets``, with ``labels`` per clip (or None). ``groups`` (e.g. actor per clip): leave-
    one-group-out threshold calibration, also against the other classes' training clips."""
    lab = np.array([x if x is not None else "" for x in labels], dtype=object)
    use = np.asarray(train, bool) & (lab != "")
    if not use.any():
        raise DataError("matchers.template: no training clip matches both 'train' and 'label_pattern'")
    classes = classes or sorted(set(lab[use]))
    clip = [bits[offsets[i] : offsets[i + 1]] for i in range(len(offsets) - 1)]
    bg = np.concatenate([clip[i] for i in np.flatnonzero(use)]).mean(axis=0)
    grp = np.array([g if g is not None else "" for g in groups], dtype=object) if groups is not None else None
    out = []
    for c in classes:
        mine = np.flatnonzero(use & (lab == c))
        if not len(mine):
            raise DataError(f"matchers.template: class {c!r} has no training clip")
        neg = [clip[i] for i in np.flatnonzero(use & (lab != c))]
        out.append(
            fit_class_template(
                c, [clip[i] for i in mine], bg, groups=None if grp is None else list(grp[mine]), negatives=neg
            )
        )
    return out


def feature_ids(columns: np.ndarray) -> str:
    from .feature_table import FEATURE_IDS

    return ",".join(FEATURE_IDS[int(c)] for c in columns)


def search_template(
    t: MotionTemplate, codes: np.ndarray, offsets: np.ndarray, threshold: float | None = None, index: object = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hits ``(start, end, cost)`` (global frames, ascending cost) of one template below its
    threshold, without the rival check.

    ``codes`` (N,) :func:`.template_model.frame_codes`; ``offsets`` (n_clips + 1,) clip
    offsets. Every clip is searched; the kernel skips a clip (and abandons cells) only where a
    lower bound of the DP's cost exceeds the threshold (admissible: ``sdtw_cost``);
    ``index``: deprecated, ignored.
    """
    _index_shim(index)
    bound = t.threshold if threshold is None else threshold
    return search_costs(codes, t.table(), np.stack([offsets[:-1], offsets[1:]], axis=1), bound)[:3]


def _index_shim(index: object) -> None:
    """The ``index`` argument (anchor regions from the inverted lists) lost true hits; the
    search's own pre-filter is admissible and needs no index. Kept one release: warns, otherwise ignored."""
    if index is not None:
        import warnings

        warnings.warn(
            "matchers.template: the 'index' input is ignored (deprecated, removed next release): the inverted-list "
            "anchors lost true hits; every clip is searched with the admissible per-clip bound; remove the input",
            DeprecationWarning,
            stacklevel=3,
        )


def cutoff_hits(
    templates: list[MotionTemplate],
    codes: np.ndarray,
    offsets: np.ndarray,
    index: object = None,
    threshold: float | None = None,
    min_gap: float = 0.5,
    only: list[int] | None = None,
    rival_table: RivalTable | None = None,
    step: int | str = 1,
    coarse: CoarseCodes | None = None,
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, float]]:
    """The hits the matcher reports, per template ``(start, end, cost, bound)`` (global
    frames, ascending cost): key-feature cost <= the template's acceptance bound and no
    other template cheaper on the stretch (all-feature costs, :mod:`.template_cutoff`).

    ``threshold`` overrides the bound of every template. ``only``: search these templates
    (indices) only, the others still competing as rivals. ``rival_table``: a
    :class:`.template_cutoff.RivalTable` of the same frames answers the rival check by
    lookups (many queries on one database) instead of scanning the hits' windows.
    ``index``: deprecated, ignored (every clip is searched; the kernel's admissible bound
    skips clips that cannot hold a hit).
    ``step``: search every ``step``-th frame (``"auto"``: per template,
    :func:`.template_coarse.template_step`), the rival check at the full rate
    (:mod:`.template_coarse`); ``coarse``: a :class:`.template_coarse.CoarseCodes` of
    ``codes`` reused between calls.
    """
    from .template_coarse import CoarseCodes, coarse_search, template_step
    from .template_cutoff import acceptance_bound, rival_mask

    _index_shim(index)
    coarse = coarse if coarse is not None else CoarseCodes(codes, offsets)
    out = []
    for qid, t in enumerate(templates):
        if only is not None and qid not in only:
            continue
        bound = float(threshold) if threshold is not None else acceptance_bound(t)
        s, e, c = coarse_search(t, coarse, None, bound, min_gap, template_step(t, step))
        keep = (
            rival_table.mask(qid, s, e, offsets)
            if rival_table is not None
            else rival_mask(templates, qid, s, e, codes, offsets)
        )
        out.append((s[keep], e[keep], c[keep], bound))
    return out


class TemplateMatcher(Matcher):
    """Motion templates: fit per class from labelled clips, retrieve with don't-care DTW.

    Inputs: ``database`` (a ``features.relational`` dataset: the frames searched and the
    examples), ``motions`` (clip names: labels and training selection) and optionally
    ``reference`` (a ``matchers.template`` step whose templates are reused); ``index`` is
    deprecated and ignored (one release: every clip is searched with an admissible bound). Output: the
    shared match table (``query_id`` = template number) plus ``label``, ``threshold`` (the
    acceptance bound the hit passed) and ``features``; a ``templates`` table;
    ``templates.npz`` and ``template_<label>.png``. Which hits are reported:
    :mod:`.template_cutoff`.
    """

    name = "template"
    version = "3"
    inputs = {"database": True, "motions": True, "reference": False, "index": False}
    #: Conformance (mocapflow.framework.testing): one template from synthetic clips.
    test_pipeline = {
        "steps": {
            "feat": {"uses": "features.relational", "input": "motions"},
            "inv": {"uses": "indexes.inverted", "input": "feat"},
        },
        "inputs": {"database": "feat", "motions": "motions"},
        "with": {"label_pattern": r"^(?P<label>synthetic)\d", "group_pattern": None, "plots": False},
        "bad_inputs": {"database": "inv", "motions": "motions"},
    }

    class Params(BaseParams):
        label_pattern: str = Field(
            HDM05_LABEL,
            description="regular expression on clip names with a group (?P<label>...), "
            "used when the motions have no labels table",
        )
        train: str = Field(".", description="regular expression: clips whose names match are training examples")
        classes: tuple[str, ...] = Field((), description="labels to learn (default: every label of the training clips)")
        group_pattern: str | None = Field(
            HDM05_GROUP,
            description="regular expression with a group (?P<group>...) "
            "(e.g. the actor): thresholds are calibrated leaving one group out at a time",
        )
        threshold: float | None = Field(
            None, gt=0.0, le=1.0, description="fixed acceptance bound for every template (default: calibrated)"
        )
        max_hits: int | None = Field(None, ge=1, description="keep the best max_hits per template")
        step: Annotated[int, Field(ge=1, le=8)] | Literal["auto"] = Field(
            "auto",
            description="search every step-th "
            "frame of template and clips (the rival check stays at the full rate); "
            "auto: K // 7, 1 to 4 (docs/templates.md); 1: the full-rate search",
        )
        plots: bool = Field(True, description="write template_<label>.png per template")
        removed: ClassVar = {
            "features": Removed(
                "retrieval always uses each template's key features (the all-31 mode lost its measurement, "
                "docs/templates.md); remove the parameter",
                accepts=("key",),
            ),
            "cutoff": Removed(
                "hits are always cut off by the rival rule of docs/templates.md (the threshold rule lost its "
                "measurement); remove the parameter",
                accepts=("rivals",),
            ),
        }

    params: Params

    def fit(
        self,
        bits: np.ndarray,
        offsets: np.ndarray,
        labels: list[str | None],
        train: np.ndarray,
        groups: list[str | None] | None = None,
    ) -> list[MotionTemplate]:
        """Templates from labelled clips (:func:`fit_templates` with this step's parameters)."""
        return fit_templates(bits, offsets, labels, train, groups, list(self.params.classes) or None)

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.datasets import StepOutput

        db_ds = inputs["database"]
        if db_ds.producer != "features.relational":
            raise PipelineError(f"matchers.template needs database=features.relational, got {db_ds.producer}")
        feats = db_ds.features()
        clips = inputs["motions"].table("clips", columns=["clip_id", "name"])
        name_of = dict(zip(clips["clip_id"].to_pylist(), clips["name"].to_pylist(), strict=True))
        bits, clip_ids, offsets = _clip_layout(feats)
        names = [name_of.get(int(c), str(c)) for c in clip_ids]
        if "reference" in inputs:
            ref = inputs["reference"]
            if ref.producer != "matchers.template":
                raise PipelineError(
                    f"matchers.template: reference must be a matchers.template step, got {ref.producer}"
                )
            templates, _ = load_templates(ref.path)
        else:
            rx = re.compile(self.params.train)
            train = np.array([bool(rx.search(n)) for n in names])
            groups = clip_labels(names, self.params.group_pattern, "group") if self.params.group_pattern else None
            labels = labels_of(inputs["motions"], clip_ids, names, self.params.label_pattern)
            templates = self.fit(bits, offsets, labels, train, groups)
        save_templates(templates, ctx.out_dir, {"label_pattern": self.params.label_pattern, "train": self.params.train})
        codes = frame_codes(bits)
        if "index" in inputs:  # deprecated, one release (_index_shim)
            _index_shim(inputs["index"])
        rows = []
        prm = self.params
        table = None
        if len(templates) > 1:  # every template is a query: the rivals' costs once
            from .template_cutoff import RivalTable

            table = RivalTable.build(templates, codes, offsets)
        lists = cutoff_hits(templates, codes, offsets, None, prm.threshold, rival_table=table, step=prm.step)
        for qid, (t, (s, e, c, bound)) in enumerate(zip(templates, lists, strict=True)):
            if prm.max_hits:
                s, e, c = s[: prm.max_hits], e[: prm.max_hits], c[: prm.max_hits]
            pos = np.searchsorted(offsets, s, side="right") - 1
            for rank, (a, b, cc, p) in enumerate(zip(s, e, c, pos, strict=True), start=1):
                rows.append(
                    {
                        "query_id": qid,
                        "rank": rank,
                        "clip_id": int(clip_ids[p]),
                        "start_frame": int(a - offsets[p]),
                        "end_frame": int(b - offsets[p]),
                        "cost": float(cc),
                        "label": t.label,
                        "threshold": bound,
                        "features": feature_ids(t.columns),
                    }
                )
        if self.params.plots:
            for t in templates:
                plot_template(t, ctx.out_dir / f"template_{_safe(t.label)}.png", fps=_fps(inputs["motions"]))
        return StepOutput(
            {"data": template_hits_table(rows), "templates": templates_table(templates)},
            {"templates": len(templates), "hits": len(rows)},
        )


def _safe(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label)


def _fps(motions: Dataset) -> float | None:
    try:
        t = motions.table("clips", columns=["fps"])
        v = t["fps"].to_pylist()
        return float(v[0]) if v else None
    except Exception:
        return None


def _clip_layout(feats: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames grouped by clip (in the order they appear): bits (N, 31), clip ids, offsets."""
    cid = np.asarray(feats.clip_id)
    # clips in order of first appearance (clip ids are hashes: sorting by id would reorder
    # the clips away from the dataset's, and the inverted index's, frame order)
    _, first, inv = np.unique(cid, return_index=True, return_inverse=True)
    order = np.lexsort((np.asarray(feats.frame), first[inv].reshape(-1))) if len(cid) else np.arange(0)
    cid = cid[order]
    bits = np.asarray(feats.x)[order] > 0.5
    brk = np.flatnonzero(np.r_[True, cid[1:] != cid[:-1]]) if len(cid) else np.zeros(0, np.int64)
    return bits, cid[brk], np.append(brk, len(cid)).astype(np.int64)


def template_hits_table(rows: list[dict[str, Any]]) -> pa.Table:
    fields = list(MATCHES) + [
        pa.field("label", pa.string()),
        pa.field("threshold", pa.float64()),
        pa.field("features", pa.string()),
    ]
    schema = pa.schema(fields)
    return pa.table({f.name: pa.array([r[f.name] for r in rows], f.type) for f in schema}, schema=schema)


def templates_table(templates: list[MotionTemplate]) -> pa.Table:
    """One row per template: label, frames, examples, threshold, key features, don't-care share."""
    return pa.table(
        {
            "template_id": pa.array(list(range(len(templates))), pa.int32()),
            "label": pa.array([t.label for t in templates], pa.string()),
            "n_frames": pa.array([t.n_frames for t in templates], pa.int32()),
            "n_examples": pa.array([t.n_examples for t in templates], pa.int32()),
            "threshold": pa.array([float(t.threshold) for t in templates], pa.float64()),
            "features": pa.array([feature_ids(t.columns) for t in templates], pa.string()),
            "dont_care_fraction": pa.array([t.dont_care_fraction() for t in templates], pa.float64()),
        }
    )


def plot_template(t: MotionTemplate, path: str | Path, fps: float | None = None) -> Path:
    """PNG of one template: features x time, colour = fraction of examples with the feature
    on, don't-care cells hatched, key features marked."""
    from mocapflow.framework.plotting import pyplot

    plt = pyplot("template plots")
    from matplotlib.patches import Patch

    from .feature_table import FEATURE_IDS, FEATURE_NAMES

    k = t.n_frames
    scale = 1.0 / fps if fps else 1.0
    m = t.mean
    fig, ax = plt.subplots(figsize=(min(4 + k * 0.06, 14), 8), dpi=100)
    im = ax.imshow(
        t.mean.T,
        aspect="auto",
        origin="upper",
        cmap="viridis",
        vmin=0.0,
        vmax=1.0,
        interpolation="nearest",
        extent=(-0.5 * scale, (k - 0.5) * scale, 30.5, -0.5),
    )
    dc = np.ma.masked_where(~((t.delta < m.T) & (1 - t.delta > m.T)), np.ones_like(m.T))
    ax.imshow(
        dc,
        aspect="auto",
        origin="upper",
        cmap="Greys",
        vmin=0,
        vmax=1.5,
        alpha=0.55,
        interpolation="nearest",
        extent=(-0.5 * scale, (k - 0.5) * scale, 30.5, -0.5),
    )
    key = set(int(c) for c in t.columns)
    ax.set_yticks(range(31))
    ax.set_yticklabels(
        [f"{'* ' if i in key else ''}{FEATURE_IDS[i]} {FEATURE_NAMES[i]}" for i in range(31)], fontsize=6
    )
    ax.set_xlabel("template time (s)" if fps else "template frame")
    ax.set_ylabel("relational feature (* = key feature used for retrieval)")
    ax.set_title(
        f"motion template '{t.label}': {t.n_examples} examples, {k} frames, threshold {t.threshold:.3f}", fontsize=9
    )
    cb = fig.colorbar(im, ax=ax)
    cb.set_label("fraction of aligned examples with the feature on (0-1)")
    ax.legend(
        handles=[Patch(facecolor="0.6", alpha=0.7, label=f"don't care ({t.delta:g} < value < {1 - t.delta:g})")],
        loc="upper right",
        fontsize=7,
        framealpha=0.9,
    )
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    plt.close(fig)
    return out
