"""Shared fixtures: the real corpus (skipped with a reason when absent) and fresh registries."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
TESTS = Path(__file__).resolve().parent
SHARED_DATA = REPO.parent / "shared" / "data"
EXAMPLES_DATA = REPO / "examples" / "data"

if str(TESTS) not in sys.path:  # so that `import naive` works under every import mode
    sys.path.insert(0, str(TESTS))
# test modules live in folders by package (tests/framework, tests/plugins/<capability>,
# tests/repo); a few import helpers from another module (`from test_formats_bvh import
# tiny_bvh`), so every test folder is importable by module name, whatever runs first
for _folder in sorted({p.parent for p in TESTS.rglob("test_*.py")} - {TESTS}):
    if str(_folder) not in sys.path:
        sys.path.append(str(_folder))


def corpus_path(*parts: str) -> Path:
    """A path inside ../shared/data, skipping the test when the corpus is absent."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"real corpus not found at {p} (expected ../shared/data beside the repository)")
    return p


@pytest.fixture
def shared_data() -> Path:
    return corpus_path()


@pytest.fixture
def registries():
    """Registries from a fresh plugin manager (built-ins only, no entry points)."""
    from mocapflow.framework import load_registries

    return load_registries(entry_points=False)
