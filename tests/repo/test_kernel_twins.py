"""Every compiled kernel module has a slow, obviously correct twin that a test compares it
with (STYLE.md, principle 7): :data:`TWINS` pairs each ``_*kernels.py`` module with the test
modules that do, and a new kernel module without an entry fails here."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

#: kernel module (repository path) -> the test modules comparing it with its naive twin
#: (``tests/naive/*`` or a twin written in the test module itself).
TWINS: dict[str, tuple[str, ...]] = {
    "framework/_fk_kernels.py": ("test_data_model.py",),
    "plugins/formats/_kernels.py": ("test_formats_kernels.py",),
    "plugins/formats/_text_kernels.py": ("test_formats_kernels.py",),
    "plugins/relational/_feature_kernels.py": ("test_relational_features.py",),
    "plugins/relational/_hit_kernels.py": ("test_relational_templates.py",),
    "plugins/relational/_match_kernels.py": ("test_relational_index.py", "test_relational_matcher.py"),
    "plugins/relational/_template_kernels.py": ("test_relational_templates.py",),
    "plugins/selfsim/paper/_cdtw_kernels.py": ("test_mdm_kernels.py",),
    "plugins/selfsim/paper/_mdm_kernels.py": ("test_mdm_kernels.py",),
    "plugins/similarity/applications/_fat_graph_kernels.py": ("test_fat_graph.py",),
    "plugins/similarity/applications/_reconstruct_kernels.py": ("test_reconstruct.py", "test_reconstruct_sides.py"),
    "plugins/similarity/knn/_brute_kernels.py": ("test_kdtree.py", "test_kdtree_boxes.py"),
    "plugins/similarity/knn/_knn_kernels.py": ("test_kdtree.py", "test_kdtree_boxes.py"),
    "plugins/similarity/knn/_tree_kernels.py": ("test_kdtree.py",),
    "plugins/similarity/search/_coarse_kernels.py": ("test_exact_search.py", "test_subspace_bounds.py"),
    "plugins/similarity/search/_dtw_kernels.py": ("test_sdtw.py", "test_exact_search.py", "test_fast_search.py"),
    "plugins/similarity/search/_gap_kernels.py": ("test_lng_gaps.py",),
    "plugins/similarity/search/_lng_kernels.py": ("test_lng.py",),
    "plugins/similarity/search/_subspace_kernels.py": ("test_subspace_bounds.py",),
}


def _test_file(name: str) -> Path:
    """A test module by file name, wherever it lives under tests/."""
    found = sorted((ROOT / "tests").rglob(name))
    assert found, f"tests/**/{name} is missing"
    return found[0]


def test_every_kernel_module_has_a_twin_test():
    kernels = sorted(
        p.relative_to(ROOT).as_posix() for top in ("framework", "plugins") for p in (ROOT / top).rglob("_*kernels.py")
    )
    missing = [k for k in kernels if k not in TWINS]
    assert not missing, f"kernel modules without a naive twin test (add them to TWINS): {missing}"
    gone = [k for k in TWINS if k not in kernels]
    assert not gone, f"TWINS lists kernel modules that no longer exist: {gone}"


@pytest.mark.parametrize("kernel", sorted(TWINS))
def test_twin_tests_compare_against_a_naive_reference(kernel):
    package = ".".join(Path(kernel).parent.parts[1:])  # e.g. similarity.search
    for name in TWINS[kernel]:
        text = _test_file(name).read_text(encoding="utf-8")
        assert "naive" in text or "twin" in text, f"{name}: no naive twin in sight for {kernel}"
        assert not package or package in text, f"{name}: does not exercise mocapflow.plugins.{package} ({kernel})"
