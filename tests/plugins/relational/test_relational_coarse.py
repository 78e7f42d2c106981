"""Coarse-rate template search (plugins/relational/template_coarse.py) against a plain decimation
by hand, and the rival check's window kernel against its definition."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.plugins.relational.template_coarse import (
    CoarseCodes,
    coarse_layout,
    coarse_search,
    coarse_template,
    template_step,
)
from mocapflow.plugins.relational.template_model import MotionTemplate, fit_class_template, frame_codes, search_costs


def _naive_layout(offsets, step):
    frames, off = [], [0]
    for a, b in zip(offsets[:-1], offsets[1:], strict=True):
        r = list(range(a, b, step))
        frames += r
        off.append(off[-1] + len(r))
    return np.array(frames, np.int64), np.array(off, np.int64)


@pytest.mark.parametrize("step", [1, 2, 3, 5])
def test_coarse_layout_matches_naive(step):
    offsets = np.array([0, 7, 7, 8, 20, 33], np.int64)  # an empty clip and a one-frame clip
    frames, off = coarse_layout(offsets, step)
    nf, no = _naive_layout(offsets, step)
    np.testing.assert_array_equal(frames, nf)
    np.testing.assert_array_equal(off, no)


def _setup(seed=0):
    rng = np.random.default_rng(seed)
    base = (rng.random((24, 31)) < 0.3).astype(np.float32)
    base = np.repeat(base, 3, axis=0)  # runs of 3 frames, like smooth features
    ex = [np.clip(base + (rng.random(base.shape) < 0.02), 0, 1).astype(np.float32) for _ in range(3)]
    t = fit_class_template("a", ex, features="all", calibrate=False)
    noise = (rng.random((200, 31)) < 0.3).astype(np.float32)
    db = np.concatenate([noise[:50], ex[0], noise[50:130], ex[1][::-1], noise[130:], ex[2]])
    offsets = np.array([0, 60, 200, len(db)], np.int64)
    return t, frame_codes(db), offsets


@pytest.mark.parametrize("step", [1, 2, 3])
def test_coarse_search_is_the_search_of_the_decimated_sequence(step):
    t, codes, offsets = _setup()
    ranges = np.stack([offsets[:-1], offsets[1:]], axis=1)
    s, e, c = coarse_search(t, CoarseCodes(codes, offsets), ranges, 0.5, 0.5, step)
    frames, off = _naive_layout(offsets, step)
    q = MotionTemplate("a", t.mean[::step], t.columns, t.delta, t.threshold, t.n_examples)
    ws, we, wc, _ = search_costs(codes[frames], q.table(), np.stack([off[:-1], off[1:]], axis=1), 0.5, 0.5)
    np.testing.assert_array_equal(s, frames[ws])
    np.testing.assert_array_equal(e, frames[we - 1] + 1)
    np.testing.assert_allclose(c, wc)
    assert len(s) >= 2  # the planted occurrences are found at every step
    assert np.all(np.searchsorted(offsets, s, side="right") == np.searchsorted(offsets, e - 1, side="right"))


def test_coarse_template_rows_and_steps():
    t, _, _ = _setup()
    assert coarse_template(t, 1) is t
    c3 = coarse_template(t, 3)
    np.testing.assert_array_equal(c3.mean, t.mean[::3])
    assert coarse_template(t, 3) is c3  # cached: its lookup table is built once
    assert template_step(t, 2) == 2
    # auto: at least 7 coarse rows, at most every 4th frame (a 22-frame hop at 30 Hz: every 3rd)
    for k, want in ((6, 1), (13, 1), (22, 3), (28, 4), (181, 4)):
        tk = MotionTemplate("k", np.zeros((k, 31), np.float32), np.arange(31), 0.2, 1.0, 1)
        assert template_step(tk, "auto") == want, k


def test_cutoff_hits_coarse_step_keeps_the_rival_decision():
    from mocapflow.plugins.relational.template import cutoff_hits

    t, codes, offsets = _setup()
    full = cutoff_hits([t], codes, offsets, threshold=0.5)
    for step in (2, "auto"):
        got = cutoff_hits([t], codes, offsets, threshold=0.5, step=step)
        clips = set((np.searchsorted(offsets, got[0][0], side="right") - 1).tolist())
        assert clips == set((np.searchsorted(offsets, full[0][0], side="right") - 1).tolist())
