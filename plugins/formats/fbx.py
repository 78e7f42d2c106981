"""Autodesk FBX skeletal animation (binary FBX 7.x): reader, pure Python + numpy.

* **Container**: :mod:`._fbx_parse` (node records, typed properties, zlib arrays).
  ASCII FBX is refused with a clear error. Only the object kinds read below are parsed
  (meshes, materials, media are skipped unparsed); header, inflation, record count, key
  times and timeline are bounded (docs/formats.md, "Hostile input classes and limits").
* **Skeleton**: the ``LimbNode`` models (a file without them: the animated models),
  closed under their lowest common ancestor; models above the skeleton's root (an
  armature ``Null``), animated or not, move the root. Model names become joint names.
* **Transforms**: each model's local transform follows the FBX SDK,
  ``T Roff Rp Rpre R Rpost^-1 Rp^-1 Soff Sp S Sp^-1``, with ``R`` the ``Lcl Rotation``
  Euler angles in ``RotationOrder`` and pre/post rotations in XYZ order, both only when
  ``RotationActive`` (as the FBX SDK and Blender do); property defaults come from the
  file's ``PropertyTemplate``. Scales must be uniform (a leaf model's need not: it moves
  no joint). Rotations are re-expressed with
  identity rest rotations (:mod:`._nodes`); positions are the file's exactly.
* **Animation**: one ``AnimationStack`` (``animation``: index or name, default the first),
  every ``AnimationLayer`` of it blended as ufbx and the FBX SDK do (:mod:`._fbx_layers`:
  weights, blend modes, accumulation modes, mute/solo); ``Lcl Translation/Rotation/Scaling``
  curves (:mod:`._fbx_curves`: the SDK's interpolation, tangents and extrapolation), sampled
  over the take (``LocalStart``..``LocalStop``, else the keys) at the file's frame rate
  (``GlobalSettings`` ``TimeMode``, or ``CustomFrameRate``).
  Key times are KTime ticks: 46,186,158,000 per second (141,120,000 from FBX 8000, or
  when ``TCDefinition`` is 0).
* **Units and axes**: ``UnitScaleFactor`` (centimetres per file unit) converts to metres;
  ``UpAxis``/``FrontAxis``/``CoordAxis`` (and signs) are rotated to mocapflow's y-up with the
  file's front axis along -z, as Blender's importer followed by its y-up glTF export does
  (an axis triple that is not right-handed falls back to z-up, y-front, as in Blender).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from mocapflow.framework import quaternions as quat
from mocapflow.framework.components import Format
from mocapflow.framework.components import Params as BaseParams
from mocapflow.framework.errors import ParseError
from mocapflow.framework.motion import Motion

from ._common import MAX_DEGREES, MAX_FPS, MAX_METRES, check_timeline, file_metadata, read_bytes
from ._fbx_curves import evaluate, read_curve
from ._fbx_layers import Layer, clamp_weight, combine
from ._fbx_layers import euler_quat as _euler
from ._fbx_parse import Node, check_head, parse_fbx
from ._fbx_scene import (
    KTIME_V7,
    MAX_VALUE,
    OBJECT_KINDS,
    Props,
    file_axes,
    ktime,
    props70,
    scene,
    take_span,
    take_stack,
    templates,
)
from ._fbx_write import write_fbx
from ._nodes import common_root, motion_from_nodes, uniform_scale, unique_names

__all__ = ["FbxFormat", "read_fbx", "write_fbx"]

#: TimeMode enum -> frames per second (14: CustomFrameRate).
TIME_MODES = {
    0: 30.0, 1: 120.0, 2: 100.0, 3: 60.0, 4: 50.0, 5: 48.0, 6: 30.0, 7: 30.0, 8: 30 / 1.001, 9: 30 / 1.001,
    10: 25.0, 11: 24.0, 12: 1000.0, 13: 24 / 1.001, 15: 96.0, 16: 72.0, 17: 60 / 1.001, 18: 120 / 1.001,
}  # fmt: skip
#: InheritType: 0 RrSs (parent scale applied after the child's rotation), 1 RSrs (the
#: plain matrix product), 2 Rrs (the parent's own scale ignored: Maya's segment scale
#: compensate). With uniform scales RrSs and RSrs give the same pose.
INHERIT_RRS = 2
_ORDERS = {0: "xyz", 1: "xzy", 2: "yzx", 3: "yxz", 4: "zxy", 5: "zyx", 6: "xyz"}
_CHANNELS = {"Lcl Translation": "t", "Lcl Rotation": "r", "Lcl Scaling": "s"}
#: Deepest model hierarchy (a skeleton is < 100 deep); the common-root search is linear in
#: the models whatever the shape (:func:`._nodes.common_root`).
MAX_MODEL_DEPTH = 1_000
#: Most animation layers in a take (a scene has a handful).
MAX_LAYERS = 1_000
#: Largest |key time| in KTime ticks: 10^7 s (115 days) at the finer v7 tick (no overflow of
#: int64 differences).
MAX_KTIME = 10_000_000 * KTIME_V7


def read_fbx(path: str | Path, animation: int | str = 0) -> Motion:
    """Read the skeletal animation of a binary FBX file (module doc). ``animation``:
    index or name of the AnimationStack.

    Metadata: ``path``, ``format`` ("fbx"), ``checksum``, ``source_fps``, ``source_frames``,
    ``animation``, ``animations``, ``unit_scale`` (metres per file unit), ``fbx_version``,
    ``start_time`` (seconds)."""
    path = Path(path)
    data = read_bytes(path, lambda head: check_head(path, head, path.stat().st_size))
    version, root = parse_fbx(path, data, OBJECT_KINDS)
    gs = Props(path, props70(root.find("GlobalSettings")), {}, "GlobalSettings")
    unit = gs.num("UnitScaleFactor", 1.0) / 100.0
    if not 0 < unit * 100 <= 1e7:
        raise ParseError(path, None, f"GlobalSettings: expected a positive UnitScaleFactor, found {unit * 100:g}")
    mode = int(gs.num("TimeMode", 0))
    fps = TIME_MODES.get(mode, gs.num("CustomFrameRate", 24.0) if mode == 14 else 0.0)
    if not 0 < fps <= MAX_FPS:
        raise ParseError(
            path, None, f"GlobalSettings: expected a frame rate in (0, {MAX_FPS:g}], found TimeMode {mode}, {fps:g} fps"
        )
    ktps = ktime(root, version)
    template, objects, parent, owner = scene(path, root)
    stack_id, stack_name, stack_names = take_stack(path, objects, animation)
    layers, curves = _curves(path, root, objects, owner, stack_id, ktps, data, version)
    models = {oid: v for oid, v in objects.items() if v[0] == "Model"}
    if not models:
        raise ParseError(path, None, "expected Model objects (a skeleton), found none")
    joints = {oid for oid, (_k, _n, node) in models.items() if node.props[2:3] == ["LimbNode"]}
    if not joints:
        joints = {m for m, _ in curves if m in models}
    if not joints:
        raise ParseError(path, None, "expected LimbNode models or animated models (a skeleton), found neither")
    order, first = _order(path, models, parent, joints)
    members = set(order)
    keyed = [c for (m, _), driving in curves.items() if m in members for _i, axes, _d in driving for c in axes if c]
    span = take_span(objects[stack_id][2], templates(root, "AnimationStack"))
    if span is not None:
        k0, k1 = span
        span_source = "take"
    elif keyed:
        k0 = min(int(c.ticks[0]) for c in keyed)
        k1 = max(int(c.ticks[-1]) for c in keyed)
        span_source = "keys"
    else:
        k0 = k1 = 0
        span_source = "keys"
    n_frames = int(round((k1 - k0) / ktps * fps)) + 1
    if not 1 <= n_frames <= 10_000_000:
        raise ParseError(path, None, f"the take spans {(k1 - k0) / ktps:g} s at {fps:g} fps: expected 1 to 10^7 frames")
    check_timeline(
        path,
        n_frames=n_frames,
        n_nodes=len(order) + 1,
        key_times=[t / ktps for t in {c.ticks.tobytes(): c.ticks for c in keyed}.values()],  # shared key times once
        t0=k0 / ktps,
        t1=k1 / ktps,
        fps=fps,
        size=len(data),
    )
    grid = (k0 + np.arange(n_frames) * (ktps / fps)) / ktps  # seconds
    weights = _weights(layers, grid)
    names = unique_names(["__fbx_axes__"] + [models[m][1] or f"model{m}" for m in order])
    n = len(order) + 1
    rest_t, rest_r, rest_s = np.zeros((n, 3)), np.zeros((n, 4)), np.ones(n)
    ignore_scale = np.zeros(n, dtype=bool)
    rest_r[0] = file_axes(path, gs)
    rest_s[0] = unit
    t = np.empty((n_frames, n, 3))
    r = np.empty((n_frames, n, 4))
    s = np.empty((n_frames, n))
    t[:, 0], r[:, 0], s[:, 0] = 0.0, rest_r[0], unit
    inner = {parent[m] for m in order if m in parent}  # models with a child in the skeleton
    scale_ignored: list[str] = []
    for k, m in enumerate(order, start=1):
        props = Props(path, props70(models[m][2]), template, f"model {names[k]!r}")
        ignore_scale[k] = int(props.num("InheritType", 0.0)) == INHERIT_RRS
        leaf = m not in inner
        tr = _transform(props, names[k], m, {}, grid, rest=True, leaf=leaf)
        rest_t[k], rest_r[k], rest_s[k] = tr[0][0], tr[1][0], tr[2][0]
        t[:, k], r[:, k], s[:, k], odd = _transform(
            props, names[k], m, curves, grid, rest=False, layers=(layers, weights), leaf=leaf
        )
        if odd or tr[3]:  # a leaf's non-uniform scale moves no joint: left out (1)
            s[:, k] = rest_s[k] = 1.0
            scale_ignored.append(names[k])
    par = np.array([-1] + [1 + order.index(parent[m]) if parent.get(m) in order else 0 for m in order], dtype=np.int64)
    meta = file_metadata(path, data, "fbx")
    meta.update(
        subject=path.parent.name,
        source_fps=fps,
        source_frames=n_frames,
        animation=stack_name,
        animations=stack_names,
        unit_scale=unit,
        fbx_version=version,
        start_time=k0 / ktps,
        span_source=span_source,
        ktime_per_second=ktps,
        axes=rest_r[0].tolist(),
        layers=[lay.name for lay in layers if lay.active],
    )
    if scale_ignored:
        meta["non_uniform_leaf_scale"] = scale_ignored[:20]
    return motion_from_nodes(
        path,
        names=names,
        parents=par,
        first_joint=first + 1,
        rest_t=rest_t,
        rest_r=rest_r,
        rest_s=rest_s,
        t=t,
        r=r,
        s=s,
        fps=fps,
        fmt="fbx",
        name=path.stem,
        meta=meta,
        ignore_parent_scale=ignore_scale & (par > 0),
    )


def _layers(
    path: Path,
    root: Node,
    objects: dict[int, tuple[str, str, Node]],
    owner: dict[int, list[tuple[int, str]]],
    stack_id: int,
) -> tuple[list[Layer], list[int]]:
    """The take's animation layers (and their ids) in the order of its connections
    (:mod:`._fbx_layers`)."""
    template = templates(root, "AnimationLayer")
    ids: list[int] = []
    for c, _p in owner.get(stack_id, []):
        if objects.get(c, ("",))[0] == "AnimationLayer" and c not in ids:
            ids.append(c)
            if len(ids) > MAX_LAYERS:
                raise ParseError(path, None, f"the take has more than {MAX_LAYERS:,} animation layers; expected fewer")
    layers = []
    for k, lid in enumerate(ids):
        props = Props(path, props70(objects[lid][2]), template, f"AnimationLayer {objects[lid][1]!r}")
        layers.append(
            Layer(
                name=objects[lid][1],
                index=k,
                weight=float(clamp_weight(props.num("Weight", 100.0))),
                mode=int(props.num("BlendMode", 0.0)),
                compose_rotation=int(props.num("RotationAccumulationMode", 0.0)) == 0,
                compose_scale=int(props.num("ScaleAccumulationMode", 0.0)) == 0,
                has_weight=props.get("Weight", None) is not None,
                muted=props.num("Mute", 0.0) != 0,
                solo=props.num("Solo", 0.0) != 0,
            )
        )
    solo = any(lay.solo for lay in layers[1:])
    for lay in layers[1:]:  # the base layer always counts
        lay.active = not lay.muted and (lay.solo or not solo)
    return layers, ids


def _curves(
    path: Path,
    root: Node,
    objects: dict[int, tuple[str, str, Node]],
    owner: dict[int, list[tuple[int, str]]],
    stack_id: int,
    ktps: int,
    data: bytes,
    version: int,
) -> tuple[list[Layer], dict[tuple[int, str], list[Any]]]:
    """The take's layers and, per (model id, "t"/"r"/"s"), the layers that drive it:
    ``(layer index, per axis curve or None, the curve node's values (3,))`` in layer order
    (skipped layers left out). A layer's animated ``Weight`` lands in its ``weight_curve``.
    Curves attach to a node's axis by name as in ufbx (``Y``/``d|Y``: y, ``Z``/``d|Z``: z,
    any other: x; in name order, the last one winning)."""
    layers, ids = _layers(path, root, objects, owner, stack_id)
    node_template = templates(root, "AnimationCurveNode")
    read: dict[int, Any] = {}  # curve id -> Curve (a curve shared by nodes or layers is read once)

    def curve(cv: int) -> Any:
        if cv not in read:
            read[cv] = read_curve(path, objects[cv][2], ktps, MAX_VALUE, data, version, max_ticks=MAX_KTIME)
        return read[cv]

    driven: dict[int, list[tuple[int, str]]] = {}  # curve node -> the (model/layer, property) pairs it drives
    for par, kids in owner.items():  # one pass over the connections (per curve node: quadratic)
        if objects.get(par, ("",))[0] in ("Model", "AnimationLayer"):
            for child, prop in kids:
                driven.setdefault(child, []).append((par, prop))
    weighted = {m for pairs in driven.values() for m, p in pairs if p == "Weight"}
    curves: dict[tuple[int, str], list[Any]] = {}
    for lay, lid in zip(layers, ids, strict=True):
        if not lay.has_weight and lid in weighted:  # ufbx: an animated Weight the layer lacks is 0 until keyed
            lay.weight = 0.0
        seen: set[tuple[int, str]] = set()
        for cn, _p in owner.get(lid, []):
            if objects.get(cn, ("",))[0] != "AnimationCurveNode":
                continue
            targets = [(m, p) for m, p in driven.get(cn, []) if p in _CHANNELS or (m == lid and p == "Weight")]
            if not targets:
                continue
            axes, dflt = _curve_node(path, cn, objects, owner, node_template, curve)
            for m, prop in targets:
                if m == lid:  # the layer's own weight, animated (percent)
                    if lay.weight_curve is None:
                        lay.weight_curve = (axes[0], float(dflt[0]))
                    continue
                key = (m, _CHANNELS[prop])
                if lay.active and key not in seen:  # two nodes on one property in one layer: the first counts
                    seen.add(key)
                    curves.setdefault(key, []).append((lay.index, axes, dflt))
    return layers, curves


def _curve_node(
    path: Path,
    cn: int,
    objects: dict[int, tuple[str, str, Node]],
    owner: dict[int, list[tuple[int, str]]],
    template: dict[str, Any],
    curve: Any,
) -> tuple[list[Any], np.ndarray]:
    """A curve node's per-axis curves (``curve(id)`` reads one) and values (3,)."""
    what = f"AnimationCurveNode {objects[cn][1]!r}"
    cprops = Props(path, props70(objects[cn][2]), template, what)
    dflt = np.array([cprops.num(f"d|{x}", cprops.num(x, 0.0)) for x in "XYZ"])
    axes: list[Any] = [None, None, None]
    kids = sorted((p, cv) for cv, p in owner.get(cn, []) if objects.get(cv, ("",))[0] == "AnimationCurve")
    for cprop, cv in kids:
        a = 1 if cprop in ("Y", "d|Y") else 2 if cprop in ("Z", "d|Z") else 0
        dflt[a] = cprops.num(cprop, dflt[a]) if cprop else dflt[a]
        axes[a] = curve(cv)
    if not np.abs(dflt).max() <= MAX_VALUE:
        raise ParseError(path, None, f"{what}: expected values within {MAX_VALUE:g}, found {dflt.tolist()}")
    return axes, dflt


def _order(
    path: Path, models: dict[int, tuple[str, str, Node]], parent: dict[int, int], joints: set[int]
) -> tuple[list[int], int]:
    def error(msg: str) -> ParseError:
        return ParseError(path, None, msg)

    def parent_of(m: int) -> int | None:
        p = parent.get(m)
        return p if p in models else None

    found = common_root(parent_of, joints, MAX_MODEL_DEPTH, error)
    if found is None:
        roots = set()
        for j in sorted(joints)[:1000]:
            m, k = j, 0
            while (up := parent_of(m)) is not None and k < MAX_MODEL_DEPTH:
                m, k = up, k + 1
            roots.add(models[m][1])
        raise ParseError(
            path, None, f"the skeleton's models have no common root (roots {sorted(roots)[:6]}); expected one skeleton"
        )
    root, members, ancestors = found
    kids: dict[int, list[int]] = {}
    for m in models:  # children in the file's order of objects
        if m in members and parent.get(m) in members:
            kids.setdefault(parent[m], []).append(m)
    order, stack = [], [root]
    while stack:
        m = stack.pop()
        order.append(m)
        stack.extend(reversed(kids.get(m, [])))
    return ancestors + order, len(ancestors)


def _weights(layers: list[Layer], grid: np.ndarray) -> list[Any]:
    """Each layer's weight on ``grid``: its animated ``Weight`` when it has one and blends,
    else its static weight (:mod:`._fbx_layers`)."""
    out: list[Any] = []
    for lay in layers:
        w: Any = lay.weight
        if lay.index > 0 and lay.active and lay.blended and lay.weight_curve is not None:
            cv, default = lay.weight_curve
            w = clamp_weight(evaluate(cv, grid) if cv is not None else np.full(len(grid), default))
        out.append(w)
    return out


def _channel(
    props: Props,
    name: str,
    key: str,
    c: str,
    default: tuple[Any, ...],
    driving: list[Any],
    grid: np.ndarray,
    layers: tuple[Any, ...],
) -> np.ndarray:
    """One transform property (F, 3) on ``grid``: its static value, replaced by the take's
    first layer and combined with the later ones that drive it (:mod:`._fbx_layers`)."""
    n = len(grid)
    v = np.broadcast_to(props.vec(key, default), (n, 3))
    for index, axes, dflt in driving:
        val = np.empty((n, 3))
        for a, cv in enumerate(axes):
            val[:, a] = evaluate(cv, grid) if cv is not None else dflt[a]
        if index == 0:
            v = val
            continue
        order = int(props.num("RotationOrder", 0.0))
        v = combine(v, val, layers[1][index], layers[0][index], c, order if 0 <= order <= 6 else 0)
        if not np.all(np.abs(v) <= MAX_VALUE):
            raise ParseError(
                props.path, None, f"model {name!r}: {key!r} blended over animation layers leaves {MAX_VALUE:g}"
            )
    return v if v.flags.writeable else v.copy()


def _transform(
    props: Props,
    name: str,
    m: int,
    curves: dict[tuple[int, str], list[Any]],
    grid: np.ndarray,
    rest: bool,
    layers: tuple[Any, ...] = ([], []),
    leaf: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Translation (F, 3), rotation (F, 4) and uniform scale (F,) of a model's local
    transform, rest (one frame, the static values) or sampled on ``grid`` with the take's
    ``layers`` (their list and weights), and whether the scale was not uniform. A scale must
    be uniform unless the model is a ``leaf`` (no model below it: its scale moves no joint;
    its own translation takes the scale per axis)."""
    chan = {}
    for key, c, default in (
        ("Lcl Translation", "t", (0.0, 0.0, 0.0)),
        ("Lcl Rotation", "r", (0.0, 0.0, 0.0)),
        ("Lcl Scaling", "s", (1.0, 1.0, 1.0)),
    ):
        if rest:
            chan[c] = props.vec(key, default)[None].copy()
        else:
            chan[c] = _channel(props, name, key, c, default, curves.get((m, c), []), grid, layers)
    if np.abs(chan["r"]).max(initial=0.0) > MAX_DEGREES:
        raise ParseError(props.path, None, f"model {name!r}: expected rotations within {MAX_DEGREES:g} degrees")
    active = props.num("RotationActive", 0.0) != 0
    order = _ORDERS.get(int(props.num("RotationOrder", 0.0)), "xyz") if active else "xyz"
    rot = _euler(chan["r"], order)
    if active:
        pre_a, post_a = props.vec("PreRotation", (0.0, 0.0, 0.0)), props.vec("PostRotation", (0.0, 0.0, 0.0))
        if pre_a.any():
            rot = quat.mul(_euler(pre_a, "xyz")[None], rot)
        if post_a.any():
            rot = quat.mul(rot, quat.conjugate(_euler(post_a, "xyz"))[None])
    sv, odd = chan["s"], False
    try:
        scale = uniform_scale(props.path, name, sv)
    except ParseError:
        if not leaf or not np.all(np.isfinite(sv)):
            raise
        scale, odd = np.ones(len(sv)), True
    roff, rp = props.vec("RotationOffset", (0.0, 0.0, 0.0)), props.vec("RotationPivot", (0.0, 0.0, 0.0))
    soff, sp = props.vec("ScalingOffset", (0.0, 0.0, 0.0)), props.vec("ScalingPivot", (0.0, 0.0, 0.0))
    t = chan["t"] + roff + rp
    if rp.any() or soff.any() or sp.any():
        t = t + quat.rotate(rot, -rp + soff + sp - (sv if odd else scale[:, None]) * sp)
    if np.abs(t).max(initial=0.0) > MAX_METRES * 1e3:  # file units: up to 10^3 per metre (mm)
        raise ParseError(
            props.path, None, f"model {name!r}: expected translations within {MAX_METRES * 1e3:g} file units"
        )
    return t, rot, scale, odd


class FbxFormat(Format):
    """Autodesk FBX (binary) skeletal animation: reader and writer."""

    name: ClassVar[str] = "fbx"
    extensions: ClassVar[tuple[str, ...]] = (".fbx",)
    produces: ClassVar[str] = "motion"

    class Params(BaseParams):
        animation: int | str = Field(0, description="which animation stack (take) of the file: index or name")

    params: Params

    def read(self, path: str | Path) -> Motion:
        return read_fbx(path, animation=self.params.animation)

    def write(self, obj: Any, path: str | Path) -> None:
        """Binary FBX 7.4: the skeleton as LimbNode models and every frame keyed
        (:mod:`._fbx_write`)."""
        write_fbx(obj, path)
