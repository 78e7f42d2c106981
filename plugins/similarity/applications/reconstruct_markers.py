"""The control signal of a reconstruction from a marker take or a skeleton take.

A marker set maps each control point (canonical joint: root, head, wrists, ankles) to the
markers whose mean stands for it; a control point may list alternatives, the first whose
markers the take has wins. Labels match case-insensitively after any ``subject:`` prefix.
Skin markers sit a few centimetres off the joint centres the prior is made of (the wrist
markers straddle the wrist; the ankle marker is on the lateral malleolus, about 3 cm
outside the ankle centre): the reconstruction inherits that offset.

Built-in sets (:data:`MARKER_SETS`), covering the marker takes of the development corpus:

==========  =========================================  =====================================
set         takes                                      control points
==========  =========================================  =====================================
``vicon``   Vicon Plug-in-Gait style: CMU and HDM05    root: LFWT RFWT LBWT RBWT; head: LFHD
            C3D (``LFHD``, ``LWRA``, ``LANK``...)      RFHD LBHD RBHD; wrist: WRA WRB; ankle:
                                                       ANK (or ANK HEE)
``opensim`` OpenSim gait TRC (``R.ASIS``,              root: R.ASIS L.ASIS V.Sacral; head:
            ``L.Wrist.Lat``, ``R.Heel``...)            R.Temple L.Temple; wrist: Wrist.Med
                                                       Wrist.Lat; ankle: Ankle.Lat Ankle.Med
                                                       (or Heel)
``isb``     ISB anatomical names (Qualisys sample:     root: L_IAS R_IAS L_IPS R_IPS; head:
            ``L_IAS``, ``L_FAL``, ``L_RSP``...)        L_HDF R_HDF L_HDB R_HDB; wrist: RSP
                                                       USP (or RSP UHE); ankle: FAL TAM
==========  =========================================  =====================================

``auto`` picks the first set whose every control point the take has.
"""

from __future__ import annotations

import numpy as np

from mocapflow.framework import DataError, Motion
from mocapflow.framework.markers import Markers, to_y_up

from .reconstruct import DEFAULT_MARKERS

MarkerSet = dict[str, tuple[tuple[str, ...], ...]]


def _sides(left: tuple[tuple[str, ...], ...]) -> tuple[tuple[tuple[str, ...], ...], tuple[tuple[str, ...], ...]]:
    """Left alternatives as given, right with L->R swapped in the first letter of a label
    ('LWRA' -> 'RWRA') or after a side prefix ('L.Wrist' -> 'R.Wrist', 'L_RSP' -> 'R_RSP')."""

    def flip(label: str) -> str:
        return "R" + label[1:] if label.startswith("L") else label

    return left, tuple(tuple(flip(x) for x in alt) for alt in left)


def _set(root, head, wrist, ankle) -> MarkerSet:
    lw, rw = _sides(wrist)
    la, ra = _sides(ankle)
    return {"root": root, "head": head, "lwrist": lw, "rwrist": rw, "lankle": la, "rankle": ra}


#: Built-in marker sets (module doc).
MARKER_SETS: dict[str, MarkerSet] = {
    "vicon": _set(
        (("LFWT", "RFWT", "LBWT", "RBWT"),),
        (("LFHD", "RFHD", "LBHD", "RBHD"),),
        (("LWRA", "LWRB"),),
        (("LANK",), ("LANK", "LHEE")),
    ),
    "opensim": _set(
        (("R.ASIS", "L.ASIS", "V.Sacral"),),
        (("R.Temple", "L.Temple"),),
        (("L.Wrist.Med", "L.Wrist.Lat"),),
        (("L.Ankle.Lat", "L.Ankle.Med"), ("L.Heel",)),
    ),
    "isb": _set(
        (("L_IAS", "R_IAS", "L_IPS", "R_IPS"),),
        (("L_HDF", "R_HDF", "L_HDB", "R_HDB"),),
        (("L_RSP", "L_USP"), ("L_RSP", "L_UHE")),
        (("L_FAL", "L_TAM"),),
    ),
}


def _key(label: str) -> str:
    return label.rsplit(":", 1)[-1].strip().lower()


def resolve_marker_set(markers: Markers, name: str = "auto") -> tuple[str, dict[str, tuple[str, ...]]]:
    """The set to use and, per control point, the take's labels it averages."""
    have = {_key(lb): lb for lb in markers.labels}
    names = list(MARKER_SETS) if name == "auto" else [name]
    if name != "auto" and name not in MARKER_SETS:
        raise DataError(f"unknown marker set {name!r}; known: {', '.join(MARKER_SETS)} (or auto)")
    missing: dict[str, list[str]] = {}
    for n in names:
        chosen, lacking = {}, []
        for point in DEFAULT_MARKERS:
            alt = next((a for a in MARKER_SETS[n][point] if all(_key(x) in have for x in a)), None)
            if alt is None:
                lacking.append(f"{point} ({' or '.join('+'.join(a) for a in MARKER_SETS[n][point])})")
            else:
                chosen[point] = tuple(have[_key(x)] for x in alt)
        if not lacking:
            return n, chosen
        missing[n] = lacking
    detail = "; ".join(f"{n}: no {', '.join(v)}" for n, v in missing.items())
    raise DataError(f"markers {markers.name!r}: no marker set fits ({detail})")


def fill_gaps(x: np.ndarray, what: str) -> np.ndarray:
    """Linear interpolation over NaN frames of each trajectory (T, M, 3), held at the ends."""
    out = np.array(x, np.float64)
    t = np.arange(len(out))
    for m in range(out.shape[1]):
        ok = np.isfinite(out[:, m]).all(1)
        if not ok.any():
            raise DataError(f"{what}: control point {m} is never seen")
        if not ok.all():
            for a in range(3):
                out[:, m, a] = np.interp(t, t[ok], out[ok, m, a])
    return out


def control_from_markers(markers: Markers, marker_set: str = "auto") -> tuple[np.ndarray, str, dict]:
    """Control points (T, 6, 3) y-up metres (:data:`~.reconstruct.DEFAULT_MARKERS` order),
    the set used and its label mapping; gaps are interpolated."""
    y_up = to_y_up(markers)
    name, mapping = resolve_marker_set(y_up, marker_set)
    pos = np.stack([np.mean(y_up.select(list(mapping[p])).positions, axis=1) for p in DEFAULT_MARKERS], 1)
    return fill_gaps(pos, f"markers {markers.name!r}"), name, mapping


def control_from_motion(motion: Motion) -> np.ndarray:
    """Control points (T, 6, 3) of a skeleton take: its canonical end effectors, head and root."""
    idx = motion.skeleton.canonical_indices(DEFAULT_MARKERS)
    if (idx < 0).any():
        missing = [p for p, i in zip(DEFAULT_MARKERS, idx, strict=True) if i < 0]
        raise DataError(f"motion {motion.name!r}: its skeleton has no joint for {missing}")
    return motion.canonical_positions(DEFAULT_MARKERS)
