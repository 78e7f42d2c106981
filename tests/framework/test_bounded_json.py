"""The bounded JSON loader (:mod:`mocapflow.framework.bounded_json`): its nesting pre-scan
against a character-by-character twin, deep texts refused without RecursionError, and the
search server's requests parsed with it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from naive import hostile_scenes as HS

from mocapflow.framework.bounded_json import JsonDepthError, loads, nesting_depth


def slow_depth(text: str) -> int:
    """Deepest nesting, one character at a time (strings and escapes followed)."""
    depth = best = 0
    in_str = esc = False
    for ch in text:
        if in_str:
            if esc:
                esc = False
            elif ch == "\\":
                esc = True
            elif ch == '"':
                in_str = False
        elif ch == '"':
            in_str = True
        elif ch in "[{":
            depth += 1
            best = max(best, depth)
        elif ch in "]}":
            depth -= 1
    return best


def _random_json(rng: np.random.Generator, alphabet: str, depth: int = 0):
    k = int(rng.integers(0, 6 if depth < 12 else 3))
    if k == 0:
        return "".join(rng.choice(list(alphabet), int(rng.integers(0, 8))))
    if k == 1:
        return int(rng.integers(-5, 5))
    if k == 2:
        return None
    if k in (3, 4):
        return [_random_json(rng, alphabet, depth + 1) for _ in range(int(rng.integers(0, 4)))]
    return {f"k{i}[": _random_json(rng, alphabet, depth + 1) for i in range(int(rng.integers(0, 4)))}


def test_nesting_depth_equals_the_slow_twin():
    """Both string removals: texts with escaped quotes (the regex) and without (the split)."""
    rng = np.random.default_rng(0)
    paths = set()
    for i in range(400):
        alphabet = 'ab[]{}"\\:,\n\u00e9' if i % 2 else "ab[]{}:,\u00e9"
        text = json.dumps(_random_json(rng, alphabet), ensure_ascii=bool(rng.integers(0, 2)))
        paths.add('\\"' in text)
        assert nesting_depth(text) == slow_depth(text), text
        assert nesting_depth(text.encode()) == slow_depth(text)
        assert loads(text, max_depth=64) == json.loads(text)
    assert paths == {True, False}


def test_deep_texts_are_refused_before_parsing():
    for text in ("[" * 100_000 + "]" * 100_000, '{"a":' * 100_000 + "1" + "}" * 100_000, "[" * 1_000_000):
        with pytest.raises(JsonDepthError, match="nested more than 64"):
            loads(text)
    assert loads("[" * 64 + "]" * 64) is not None
    with pytest.raises(JsonDepthError):
        loads("[" * 65 + "]" * 65)
    assert loads(json.dumps({"a": "[" * 100_000})) == {"a": "[" * 100_000}  # brackets in strings do not count
    for bad in (b"\xff", b'{"a": 1', "9" * 5000):
        with pytest.raises(ValueError):
            loads(bad)


@pytest.mark.parametrize("name, raw, valid", HS.server_requests(), ids=[c[0] for c in HS.server_requests()])
def test_hostile_server_requests_are_config_errors(name, raw, valid):
    from mocapflow.framework.errors import ConfigError
    from mocapflow.plugins.similarity.search.search_server import _handle, _request

    if valid:
        assert _request(raw)[0].query.startswith("[")
        return
    with pytest.raises(ConfigError, match="search server"):
        _request(raw)
    reply = _handle([None], raw, lambda: None)
    assert reply["rc"] == 2 and "internal error" not in reply["stderr"]
