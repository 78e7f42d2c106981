"""A short, deterministic run of the parser fuzzer (the long one is
``benchmarks/fuzz_parsers.py``): hypothesis draws a base file, a mutation kind and a seed;
the reader must raise ParseError (naming the file and a line) or read exactly what the
reference reader of ``tests/naive/readers.py`` reads.

Handmade bases keep it meaningful without the corpus; corpus excerpts are used when
``../shared/data`` is present.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_DATA
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from naive import fuzz
from naive import readers as ref
from test_formats_amc import TINY_ASF, tiny_amc
from test_formats_bvh import REST, tiny_bvh
from test_formats_markers import small_markers

from mocapflow.plugins.formats.trc import write_trc

FUZZ = settings(
    max_examples=150,
    derandomize=True,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def handmade_bases(folder: Path) -> list[fuzz.Base]:
    frames = [
        (1.5, 2, -3, 10, 20, 30, 45, -5, 7.25),
        (1.6, 2.1, -3, 11, 21, 31, 46, -6, 7.5),
        (1.7, 2.2, -3.1, 12, 22, 32, 47, -7, 7.75),
    ]
    rows = [list(REST), [1, 91, 2, 10, 20, 30, 1, 2, 3, 0, 50, 0, 4, 5, 6, 7, 8, 9], list(REST)]
    trc = folder / "m.trc"
    write_trc(small_markers(t=5), trc)
    return [
        fuzz.Base("amc", "tiny_01.amc", tiny_amc(frames).encode(), TINY_ASF.encode(), "tiny.asf"),
        fuzz.Base("amc", "tiny_02.amc", tiny_amc(frames[:1], eol="\r\n").encode(), TINY_ASF.encode(), "tiny.asf"),
        fuzz.Base("bvh", "tiny.bvh", tiny_bvh(rows).encode()),
        fuzz.Base("trc", "m.trc", trc.read_bytes()),
    ]


def run_case(folder: Path, base: fuzz.Base, kind: str, seed: int) -> tuple[str, str]:
    rng = np.random.default_rng(seed)
    reference = fuzz.arrays(fuzz.read(base.fmt, fuzz.write_case(folder / "ref", base, base.data, base.asf)))
    data, asf = fuzz.mutate(kind, base, rng)
    return fuzz.check(folder / "case", base, kind, data, asf, reference)


def test_handmade_bases_agree_with_the_reference(tmp_path: Path) -> None:
    for base in handmade_bases(tmp_path):
        assert fuzz.check(tmp_path / "c", base, "none", base.data, base.asf, None) == ("accepted", "")


@given(data=st.data())
@FUZZ
def test_fuzz_handmade(tmp_path: Path, data) -> None:
    bases = handmade_bases(tmp_path)
    base = data.draw(st.sampled_from(bases), label="base")
    kind = data.draw(st.sampled_from(fuzz.KINDS), label="kind")
    seed = data.draw(st.integers(0, 2**32 - 1), label="seed")
    outcome, detail = run_case(tmp_path, base, kind, seed)
    assert outcome in ("accepted", "rejected"), detail


@pytest.fixture(scope="module")
def corpus_bases(tmp_path_factory) -> list[fuzz.Base]:
    if not SHARED_DATA.exists():
        pytest.skip(f"real corpus not found at {SHARED_DATA} (expected ../shared/data beside the repository)")
    sources = fuzz.corpus_sources(SHARED_DATA, with_c3d=False)
    rng = np.random.default_rng(11)
    out = []
    for fmt, paths in sources.items():  # a few files of each source folder
        by_folder: dict[Path, list[Path]] = {}
        for p in paths:
            by_folder.setdefault(p.parent, []).append(p)
        for files in list(by_folder.values())[::3] if fmt == "amc" else by_folder.values():
            data, asf, asf_name = fuzz.load_source(fmt, files[0])
            out.append(fuzz.excerpt(fmt, files[0].name, data, rng, asf, asf_name))
    return out


def test_corpus_excerpts_agree_with_the_reference(corpus_bases, tmp_path: Path) -> None:
    for base in corpus_bases:
        assert fuzz.check(tmp_path, base, "none", base.data, base.asf, None) == ("accepted", ""), base.name


@given(data=st.data())
@FUZZ
def test_fuzz_corpus(corpus_bases, tmp_path: Path, data) -> None:
    base = data.draw(st.sampled_from(corpus_bases), label="base")
    kind = data.draw(st.sampled_from(fuzz.KINDS), label="kind")
    seed = data.draw(st.integers(0, 2**32 - 1), label="seed")
    outcome, detail = run_case(tmp_path, base, kind, seed)
    assert outcome in ("accepted", "rejected"), f"{base.name} {kind}: {detail}"


@given(eols=st.lists(st.sampled_from(["\n", "\r\n", "\r"]), min_size=40, max_size=40), bom=st.booleans())
@FUZZ
def test_any_line_end_mix_reads_the_same(tmp_path: Path, eols: list[str], bom: bool) -> None:
    for base in handmade_bases(tmp_path):
        lines = base.data.decode().replace("\r\n", "\n").split("\n")[:-1]
        text, prev = "", ""
        for k, ln in enumerate(lines):
            eol = eols[k % len(eols)]
            if prev == "\r" and not ln and eol == "\n":
                eol = "\r\n"  # CR then a bare LF would be one CRLF: a line end lost
            text, prev = text + ln + eol, eol
        data = (b"\xef\xbb\xbf" if bom else b"") + text.encode()
        reference = fuzz.arrays(fuzz.read(base.fmt, fuzz.write_case(tmp_path / "r", base, base.data, base.asf)))
        assert fuzz.check(tmp_path / "c", base, "eol", data, base.asf, reference) == ("accepted", "")


# --- the oracle can fail ---------------------------------------------------------------------


def test_the_oracle_catches_a_reader_that_drops_a_frame(tmp_path: Path, monkeypatch) -> None:
    base = handmade_bases(tmp_path)[0]
    real = fuzz._reader("amc")
    monkeypatch.setattr(fuzz, "_reader", lambda fmt: lambda p, **kw: real(p, **kw).slice(0, 2))
    outcome, detail = fuzz.check(tmp_path, base, "none", base.data, base.asf, None)
    assert outcome == "wrong_accept" and detail == "frames"


def test_the_oracle_catches_a_changed_value_and_a_silent_gap(tmp_path: Path, monkeypatch) -> None:
    base = handmade_bases(tmp_path)[3]
    real = fuzz._reader("trc")

    def lying(p, **kw):
        m = real(p, **kw)
        m.positions[2, 1] = np.nan  # inf read as a gap: a wrong acceptance
        return m

    monkeypatch.setattr(fuzz, "_reader", lambda fmt: lying)
    assert fuzz.check(tmp_path, base, "none", base.data, None, None) == ("wrong_accept", "positions")


def test_the_reference_refuses_what_the_policy_refuses() -> None:
    assert ref.number(b"1e308") == 1e308 and ref.number(b"1e309") is None and ref.number(b"inf") is None
    assert ref.number(b"1_0") is None and ref.number(b".5") == 0.5 and ref.number(b"5.") == 5.0
    with pytest.raises(ref.Reject, match="binary"):
        ref.text_lines(b"abc\n\x7fdef")
    assert ref.text_lines(b"\xef\xbb\xbfa\rb\r\nc\nd") == [b"a", b"b", b"c", b"d"]
