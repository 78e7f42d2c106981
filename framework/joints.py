"""The canonical joint vocabulary and the maps from common source namings to it.

Features are defined on canonical joints so that they hold across skeletons. A source
skeleton maps each canonical name it has to one of its joints (``Skeleton.canonical``),
through the naming dialects (:class:`JointMap`) that plugins register; the built-in ones
(Acclaim, the common BVH namings) live in :mod:`mocapflow.plugins.formats.joint_maps`.
This module holds the contract and the matching rule; the registered dialects are kept by
:mod:`mocapflow.framework.plugins`.

Joint *positions* are the points where a segment starts: ``lknee`` is the knee centre,
``lwrist`` the wrist centre, ``ltoes`` the ball of the foot, ``headtop`` the top of the
head (an ASF/BVH end site).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

#: Canonical joints, in a fixed order used by every canonical position array.
CANONICAL_JOINTS: tuple[str, ...] = (
    "root",
    "lhip",
    "lknee",
    "lankle",
    "ltoes",
    "rhip",
    "rknee",
    "rankle",
    "rtoes",
    "lowerback",
    "upperback",
    "chest",
    "neck",
    "head",
    "headtop",
    "lclavicle",
    "lshoulder",
    "lelbow",
    "lwrist",
    "lfingers",
    "rclavicle",
    "rshoulder",
    "relbow",
    "rwrist",
    "rfingers",
)

#: Canonical joints every ingested skeleton must provide (features rely on them).
REQUIRED_JOINTS: tuple[str, ...] = (
    "root",
    "lhip",
    "lknee",
    "lankle",
    "rhip",
    "rknee",
    "rankle",
    "head",
    "lshoulder",
    "lelbow",
    "lwrist",
    "rshoulder",
    "relbow",
    "rwrist",
)


@dataclass(frozen=True)
class JointMap:
    """A skeleton naming dialect: ``candidates`` maps each canonical joint to source names,
    preferred first. It applies to skeletons of ``formats`` (empty: all) that have every
    lower-case ``signature`` name; canonical joints choose in ``pick_order`` (a joint taken
    is not given again); ``self_named`` also accepts the canonical name itself."""

    name: str
    candidates: Mapping[str, tuple[str, ...]]
    formats: tuple[str, ...] = ()
    signature: frozenset[str] = frozenset()
    pick_order: tuple[str, ...] = ()
    self_named: bool = False
    case_sensitive: bool = False

    def __post_init__(self) -> None:
        unknown = sorted(set(self.candidates) - set(CANONICAL_JOINTS))
        if unknown or not self.name:
            raise ValueError(
                f"joint map {self.name!r}: unknown canonical joints {unknown}"
                if unknown
                else "a joint map needs a name"
            )

    def applies(self, joint_names: Sequence[str], fmt: str | None = None) -> bool:
        """Whether the dialect may map a skeleton of format ``fmt`` with these joint names."""
        if fmt is not None and self.formats and fmt not in self.formats:
            return False
        return self.signature <= {n.lower() for n in joint_names}

    def apply(self, joint_names: Sequence[str]) -> dict[str, int]:
        """Canonical joint -> index into ``joint_names`` (joints without a candidate absent)."""
        key = (lambda s: s) if self.case_sensitive else str.lower
        index: dict[str, int] = {}
        for i, n in enumerate(joint_names):
            index.setdefault(key(n), i)
        out: dict[str, int] = {}
        used: set[int] = set()
        for canon in self.pick_order or tuple(self.candidates):
            names = (*self.candidates.get(canon, ()), *((canon,) if self.self_named else ()))
            for cand in names:
                found = index.get(key(cand))
                # dialects may list one name for two joints: never give a joint two names
                if found is not None and found not in used:
                    out[canon] = found
                    used.add(found)
                    break
        return out


def canonical_map(joint_names: Sequence[str], fmt: str | None, maps: Iterable[JointMap]) -> dict[str, int]:
    """Canonical map of a skeleton: canonical joint -> index into ``joint_names``.

    Every dialect of ``maps`` that applies (readers pass
    :func:`~mocapflow.framework.plugins.registered_joint_maps`) is tried; the map with the
    most required joints wins, then one whose signature matched, then the one with the
    most joints, then the first registered. Names carrying a namespace prefix
    (``mixamorig:Hips``, ``Take1:LeftArm``) are also tried without it.
    """
    maps = list(maps)
    best = _best_map(joint_names, fmt, maps)
    bare = [n.rsplit(":", 1)[-1] for n in joint_names]
    if bare != list(joint_names):
        alt = _best_map(bare, fmt, maps)
        if alt is not None and (best is None or alt[0] > best[0]):
            best = alt
    return {} if best is None else best[1]


def _best_map(
    joint_names: Sequence[str], fmt: str | None, maps: Sequence[JointMap]
) -> tuple[tuple[int, int, int, int], dict[str, int]] | None:
    """The best (score, map) of :func:`canonical_map`'s rule, None if no dialect applies."""
    best: tuple[tuple[int, int, int, int], dict[str, int]] | None = None
    for order, m in enumerate(maps):
        if not m.applies(joint_names, fmt):
            continue
        mapped = m.apply(joint_names)
        score = (len(mapped) - len(missing_required(mapped)), bool(m.signature), len(mapped), -order)
        if best is None or score > best[0]:
            best = (score, mapped)
    return best


def missing_required(canonical: Mapping[str, int]) -> list[str]:
    """Required canonical joints absent from a canonical map."""
    return [j for j in REQUIRED_JOINTS if j not in canonical]
