"""Adaptive segmentation and inverted-list indexes: exact, fuzzy, adaptive fuzzy, m-mismatch hits."""

from __future__ import annotations

import numpy as np
import pytest
from naive import relational as naive

from mocapflow.framework.errors import DataError
from mocapflow.plugins.relational.inverted import InvertedIndex, SetIndex
from mocapflow.plugins.relational.queries import coarsen_fuzzy, search_set
from mocapflow.plugins.relational.segmentation import offsets_from_clip_ids, pack_codes, segment, segment_codes

RNG = np.random.default_rng(3)

# The paper's walking example (eq. 3): F2 = (F^r, F^l), code = F^r + 2 F^l.
WALK = np.array([3, 2, 3, 1, 3, 2, 3, 1, 3, 2])


def walk_index(frames_per_segment=(2, 1, 3, 2, 1, 2, 4, 1, 2, 3)) -> SetIndex:
    codes = np.repeat(WALK, frames_per_segment)
    return SetIndex.build("walk", codes, np.arange(2), np.array([0]), np.array([0, len(codes)]))


def random_index(n_frames=400, n_bits=3, n_clips=5):
    codes = RNG.integers(0, 1 << n_bits, n_frames)
    codes = np.repeat(codes, RNG.integers(1, 4, n_frames))[:n_frames]  # runs
    cuts = np.sort(RNG.choice(np.arange(1, n_frames), n_clips - 1, replace=False))
    offsets = np.r_[0, cuts, n_frames]
    return SetIndex.build("r", codes, np.arange(n_bits), np.arange(n_clips), offsets), codes, offsets


def test_segmentation_matches_naive_and_splits_at_clip_boundaries():
    codes = np.array([1, 1, 2, 2, 2, 1, 1, 1, 0])
    offsets = np.array([0, 4, 4, 6, 9])  # an empty clip too
    seg = segment_codes(codes, offsets)
    want = naive.segments(codes, offsets)
    assert list(zip(seg.start, seg.end, seg.code, seg.clip, strict=True)) == [(a, b, c, k) for a, b, c, k in want]
    assert (seg.end[:-1] == seg.start[1:]).all() and seg.lengths.sum() == len(codes)
    # a one-frame clip, a constant signal
    one = segment_codes(np.array([5]))
    assert (len(one), one.start[0], one.end[0]) == (1, 0, 1)
    assert len(segment_codes(np.zeros(50, int))) == 1
    with pytest.raises(DataError):
        segment_codes(codes, np.array([0, 3]))


def test_subset_segmentation_is_coarser():
    bits = RNG.random((300, 5)) < 0.3
    full = segment(bits)
    sub = segment(bits, [1, 3])
    assert len(sub) <= len(full)
    assert set(sub.start) <= set(full.start)
    np.testing.assert_array_equal(pack_codes(bits, [1, 3])[sub.start], sub.code)
    np.testing.assert_array_equal(offsets_from_clip_ids(np.array([4, 4, 7, 7, 7, 2])), [0, 2, 5, 6])


def test_inverted_lists_are_sorted_and_complete():
    idx, _, _ = random_index()
    for c in range(8):
        p = idx.positions(c)
        assert (np.diff(p) > 0).all()
        np.testing.assert_array_equal(p, np.flatnonzero(idx.seg_code == c))
    assert sum(len(idx.positions(c)) for c in range(8)) == idx.n_segments
    assert len(idx.positions(99)) == 0


def test_paper_example_exact_hits():
    # eq. (8): F[Q] = ((1,0), (1,1), (0,1)) -> hits 4 and 8 (1-based)
    idx = walk_index()
    np.testing.assert_array_equal(idx.exact(np.array([1, 3, 2])), [3, 7])


def test_paper_example_adaptive_fuzzy_hits():
    # §5.2: V1 = V3 = {(0,0), (0,1)}, V2 = {(1,0), (1,1)}: adaptive hits {2, 6} (1-based) with
    # k = (2, 3, 6, 7) and (6, 7, 10, 11); plain fuzzy hits are empty.
    idx = walk_index()
    member = np.zeros((3, 4), bool)
    member[0, [0, 2]] = member[2, [0, 2]] = True
    member[1, [1, 3]] = True
    np.testing.assert_array_equal(idx.adaptive(member) + 1, [[2, 3, 6, 7], [6, 7, 10, 11]])
    assert len(idx.fuzzy(member)) == 0
    # the adaptive hits equal the exact hits of the first component alone (F^r), as the paper notes
    fr = SetIndex.build(
        "fr", np.repeat(WALK & 1, (2, 1, 3, 2, 1, 2, 4, 1, 2, 3)), np.arange(1), np.array([0]), np.array([0, 21])
    )
    hits = fr.exact(np.array([0, 1, 0]))
    levels, _ = search_set(idx, member, "adaptive")
    np.testing.assert_array_equal(fr.seg_start[hits], levels[:, 0, 0])


@pytest.mark.parametrize("seed", range(5))
def test_hits_match_naive_on_random_indexes(seed):
    global RNG
    RNG = np.random.default_rng(seed)
    idx, _, _ = random_index()
    w, clip = idx.seg_code.tolist(), idx.seg_clip.tolist()
    for length in (1, 2, 3, 4):
        k = int(RNG.integers(0, idx.n_segments - length))
        q = idx.seg_code[k : k + length]
        assert idx.exact(q).tolist() == naive.exact_hits(w, clip, q.tolist())
        member = RNG.random((length, 8)) < 0.4
        member[np.arange(length), q] = True
        sets = [set(np.flatnonzero(r)) for r in member]
        assert idx.fuzzy(member).tolist() == naive.fuzzy_hits(w, clip, sets)
        coarse = coarsen_fuzzy(member)
        csets = [set(np.flatnonzero(r)) for r in coarse]
        assert [tuple(b) for b in idx.adaptive(coarse).tolist()] == naive.adaptive_hits(w, clip, csets)
        from mocapflow.plugins.relational._match_kernels import mismatch_scan

        allowed = RNG.random(length) < 0.7
        for m in (0, 1, 2):
            s, bad = mismatch_scan(idx.seg_code, idx.seg_clip, member, allowed, m)
            assert list(zip(s.tolist(), bad.tolist(), strict=True)) == naive.mismatch_hits(w, clip, sets, m, allowed)


@pytest.mark.parametrize("seed", range(3))
def test_adaptive_hits_with_long_runs_match_naive(seed):
    # dense alternative sets make runs of many segments (the jump-ahead path of adaptive())
    rng = np.random.default_rng(100 + seed)
    idx, _, _ = random_index(n_frames=3000, n_bits=4, n_clips=3)
    w, clip = idx.seg_code.tolist(), idx.seg_clip.tolist()
    longest = 0
    for _ in range(4):
        a, b = rng.choice(16, 2, replace=False)
        member = np.zeros((3, 16), bool)
        member[0, a] = member[2, b] = True
        member[1] = True
        member[1, [a, b]] = False  # V_2: every other code, so its runs are long
        sets = [set(np.flatnonzero(r)) for r in member]
        hits = idx.adaptive(member)
        assert [tuple(h) for h in hits.tolist()] == naive.adaptive_hits(w, clip, sets)
        longest = max([longest] + (hits[:, 2] - hits[:, 1]).tolist())
    assert longest > 8


def test_coarsen_fuzzy_merges_intersecting_neighbours():
    m = np.array([[1, 1, 0, 0], [0, 1, 1, 0], [0, 0, 0, 1], [1, 0, 0, 0]], bool)
    np.testing.assert_array_equal(coarsen_fuzzy(m), [[1, 1, 1, 0], [0, 0, 0, 1], [1, 0, 0, 0]])


def test_index_build_save_load_roundtrip(tmp_path):
    bits = RNG.random((500, 31)) < 0.2
    bits = np.repeat(bits, 3, axis=0)
    clip_id = np.repeat([10, 11, 12, 13], [300, 1, 499, 700])
    index = InvertedIndex().build(bits, clip_id)
    index.save(tmp_path / "index")
    back = InvertedIndex.load(tmp_path / "index")
    for name in ("lower", "upper", "mixed"):
        a, b = index.sets[name], back.sets[name]
        for f in (
            "seg_start",
            "seg_end",
            "seg_code",
            "seg_clip",
            "clip_ids",
            "clip_offsets",
            "list_codes",
            "list_offsets",
            "list_positions",
            "columns",
        ):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f"{name}.{f}")
    # no segment crosses a clip boundary; segments tile each clip
    s = index.sets["upper"]
    assert (s.seg_clip == np.searchsorted(s.clip_offsets, s.seg_end - 1, side="right") - 1).all()
    assert s.nbytes() > 0
    with pytest.raises(NotImplementedError):
        index.query(bits[:1].astype(np.float32), 1)
    with pytest.raises(DataError):
        InvertedIndex().build(bits[:, :30])
