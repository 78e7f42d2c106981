"""glTF 2.0 skeletal animation (``.gltf`` with its buffers, or binary ``.glb``): reader
and writer, numpy + json only.

* **Skeleton**: the joints of the file's skins (the union of all skins), closed under
  their lowest common ancestor (intermediate nodes included); a file without skins
  takes the nodes the animation targets, their common ancestor and its descendants
  without a mesh or camera. Nodes above the skeleton's root (an armature node, a scene
  transform), animated or not, move the root. Node names become joint names (unnamed:
  ``node<index>``; repeats get ``_2``...).
* **Rest pose** is each node's own TRS (or ``matrix``); rotations are re-expressed with
  identity rest rotations (:mod:`._nodes`), positions are the file's exactly.
* **Animation**: one of the file's animations (``animation``: index or name, default
  the first); ``translation``, ``rotation`` and ``scale`` channels with ``LINEAR``
  (slerp for rotations), ``STEP`` and ``CUBICSPLINE`` samplers, float or normalized
  integer outputs; ``weights`` channels are ignored. Frames are sampled on a uniform
  grid from the first to the last key time.
* **Frame rate**: glTF stores key times in seconds, no rate. ``fps="auto"`` takes
  ``extras.fps`` of the animation when present (this writer's files), else the rate of
  the most densely keyed sampler (keys per second, as read: a whole or NTSC
  ``n * 1000 / 1001`` rate only when its frame grid holds every key time within float32
  rounding); ``metadata["fps_source"]`` says which. Frames are the file's own key times
  when the keys are evenly spaced (no resampling); ``fps=`` resamples.
* **Units and axes**: glTF is metres, y up, +z forward: mocapflow's own convention,
  nothing to convert.
* Scales must be uniform (a joint cannot shear); sparse accessors are refused.
* **Hostile files** (docs/formats.md, "Hostile input classes and limits"): buffers are the
  GLB binary chunk, data URIs (no longer than their ``byteLength`` needs, checked before
  decoding) or files confined to the document's folder (:func:`._common.read_sidecar`),
  counted in the 1 GiB per-file cap; every declared offset, length and count is checked
  before a byte is read; the header is checked before the body; JSON nesting, node counts,
  hierarchy depth, skeleton size and the sampled timeline are bounded.

The writer (:func:`write_gltf`) writes one node per joint, a skin over them, and one
animation sampled at the motion's rate (``LINEAR``, float32, key times ``k / fps``,
``extras.fps``); ``.glb`` gives the binary container, ``.gltf`` a JSON file with the
buffer embedded as a data URI. Skeletons read from glTF or FBX get their rest bone
orientations back (``Skeleton.meta["rest_rotations"]``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, Literal, cast

import numpy as np
from pydantic import Field

from mocapflow.framework import quaternions as quat
from mocapflow.framework.components import Format
from mocapflow.framework.components import Params as BaseParams
from mocapflow.framework.errors import DataError
from mocapflow.framework.motion import Motion

from ._common import MAX_FPS, check_timeline, file_metadata, read_bytes
from ._common import MAX_GLB_JSON as MAX_GLB_JSON  # the reader's JSON cap, named here too
from ._gltf_doc import _MAX_VALUE, _PATHS, MAX_NODE_DEPTH, MAX_NODES, _check_head, _Doc
from ._gltf_write import write_gltf
from ._nodes import common_root, motion_from_nodes, uniform_scale, unique_names

__all__ = ["GltfFormat", "read_gltf", "write_gltf"]


def _node_trs(doc: _Doc, i: int, node: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest translation, rotation (w, x, y, z) and scale of a node."""
    w = f"nodes[{i}]"
    if "matrix" in node:
        m = doc.get(node, "matrix", list, w)
        if len(m) != 16 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in m):
            raise doc.error(f"{w}: expected 16 numbers in 'matrix'")
        mat = np.array(m, dtype=float).reshape(4, 4).T  # column-major
        if not np.all(np.abs(mat) <= _MAX_VALUE):
            raise doc.error(f"{w}: expected finite numbers within {_MAX_VALUE:g} in 'matrix'")
        lin = mat[:3, :3]
        s = np.linalg.norm(lin, axis=0)
        if np.any(s <= 0) or np.linalg.det(lin) <= 0:
            raise doc.error(f"{w}: expected a matrix of a rotation and a positive scale")
        return mat[:3, 3].copy(), quat.from_matrix(lin / s), s
    vals = []
    for key, default in (
        ("translation", [0.0, 0.0, 0.0]),
        ("rotation", [0.0, 0.0, 0.0, 1.0]),
        ("scale", [1.0, 1.0, 1.0]),
    ):
        v = doc.get(node, key, list, w, default)
        if len(v) != len(default) or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
            raise doc.error(f"{w}: expected {len(default)} numbers in {key!r}")
        arr = np.array(v, dtype=float)
        if not np.all(np.abs(arr) <= _MAX_VALUE):
            raise doc.error(f"{w}: expected finite numbers within {_MAX_VALUE:g} in {key!r}")
        vals.append(arr)
    t, r, s = vals
    if np.linalg.norm(r) < 1e-6:
        raise doc.error(f"{w}: expected a unit quaternion in 'rotation', found {r.tolist()}")
    return t, np.array([r[3], r[0], r[1], r[2]]), s


def _parents(doc: _Doc) -> np.ndarray:
    """Parent of each node (-1: a root), checked to be a forest of at most
    :data:`MAX_NODES` nodes and :data:`MAX_NODE_DEPTH` levels (iteratively: no recursion,
    each node visited once)."""
    nodes = doc.doc.get("nodes", [])
    if not isinstance(nodes, list) or not nodes:
        raise doc.error("expected a non-empty 'nodes' array")
    if len(nodes) > MAX_NODES:
        raise doc.error(f"expected at most {MAX_NODES:,} nodes, found {len(nodes):,}")
    parent = np.full(len(nodes), -1, dtype=np.int64)
    for i, nd in enumerate(nodes):
        if not isinstance(nd, dict):
            raise doc.error(f"nodes[{i}]: expected a JSON object")
        for c in doc.get(nd, "children", list, f"nodes[{i}]", []):
            doc.item("nodes", c, f"nodes[{i}].children")
            if parent[c] >= 0 or c == i:
                raise doc.error(f"nodes[{c}] has two parents (nodes {parent[c]} and {i}); expected a tree")
            parent[c] = i
    depth = np.full(len(nodes), -1, dtype=np.int64)  # -1: not known yet
    par = parent.tolist()
    for i in range(len(nodes)):  # depths, each node once: cycles and too deep hierarchies
        path, k = [], i
        while k >= 0 and depth[k] < 0:
            path.append(k)
            depth[k] = -2  # on the current path
            k = par[k]
            if len(path) > MAX_NODE_DEPTH:
                raise doc.error(f"nodes[{i}]: more than {MAX_NODE_DEPTH:,} ancestors; expected a shallower hierarchy")
            if k >= 0 and depth[k] == -2:
                raise doc.error(f"nodes[{i}]: its ancestors form a cycle; expected a tree")
        d = int(depth[k]) if k >= 0 else -1
        for m in reversed(path):
            d += 1
            depth[m] = d
        if d > MAX_NODE_DEPTH:
            raise doc.error(f"nodes[{i}]: more than {MAX_NODE_DEPTH:,} ancestors; expected a shallower hierarchy")
    return parent


def _select(doc: _Doc, parent: np.ndarray, animated: set[int]) -> tuple[list[int], int]:
    """Nodes of the skeleton in topological order (ancestors of the root first) and the
    index in that list of the skeleton's root."""
    nodes = doc.doc["nodes"]
    joints: set[int] = set()
    for k, skin in enumerate(doc.get(doc.doc, "skins", list, "the document", []) or []):
        if not isinstance(skin, dict):
            raise doc.error(f"skins[{k}]: expected a JSON object")
        for j in doc.get(skin, "joints", list, f"skins[{k}]"):
            doc.item("nodes", j, f"skins[{k}].joints")
            joints.add(j)
    from_skin = bool(joints)
    if not joints:
        joints = set(animated)
    if not joints:
        raise doc.error("expected skins or animated nodes (a skeleton), found neither")
    par = parent.tolist()
    found = common_root(lambda m: par[m] if par[m] >= 0 else None, joints, MAX_NODE_DEPTH + 1, doc.error)
    if found is None:
        raise doc.error(f"the skeleton's nodes {sorted(joints)[:8]} have no common root node; expected one skeleton")
    root, members, ancestors = found
    if not from_skin:  # descendants of the animated nodes: end effectors and unanimated joints
        kids: dict[int, list[int]] = {}
        for i, p in enumerate(parent):
            kids.setdefault(int(p), []).append(i)
        stack = [root]
        while stack:
            k = stack.pop()
            for c in kids.get(k, []):
                if "mesh" not in nodes[c] and "camera" not in nodes[c]:
                    members.add(c)
                    stack.append(c)
    order, stack = [], [root]
    while stack:  # depth first, children in the file's order (a BVH-like joint order)
        k = stack.pop()
        order.append(k)
        stack.extend(c for c in reversed(nodes[k].get("children", [])) if c in members)
    return ancestors + order, len(ancestors)


def _pick_animation(doc: _Doc, animation: int | str) -> tuple[int, dict[str, Any]]:
    anims = doc.doc.get("animations", [])
    if not isinstance(anims, list) or not anims:
        raise doc.error("expected at least one animation in 'animations'")
    if isinstance(animation, str):
        names = [a.get("name") if isinstance(a, dict) else None for a in anims]
        if animation not in names:
            raise doc.error(f"expected an animation named {animation!r}, found {names}")
        k = names.index(animation)
    else:
        k = animation
    return k, doc.item("animations", k, f"animation {animation!r}")


def _snap_fps(fps: float, times: np.ndarray) -> float:
    """``fps`` measured from key spacing, replaced by a whole or NTSC rate only when that
    rate's frame grid holds every key time within float32 rounding (a rate a writer
    rounded into its float32 times); otherwise the rate as read (Blender writes keys
    1/119.9952 s apart: snapping that to 120 drifts 3.3 ms over 10,000 frames)."""
    tol = 4 * np.finfo(np.float32).eps * max(abs(float(times[-1])), abs(float(times[0])), 1.0)
    for cand in (round(fps), round(fps * 1.001) * 1000 / 1001):
        if cand > 0 and abs(fps - cand) <= 2e-4 * fps:
            rel = times - times[0]
            if np.abs(rel - np.round(rel * cand) / cand).max() <= tol:
                return float(cand)
    return fps


def _snap(times: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, bool]:
    """Key times moved onto the frames they lie on (within float32 rounding of the times),
    and whether there is exactly one key per frame."""
    if len(grid) < 2 or len(times) < 2:
        return times, False
    step = grid[1] - grid[0]
    kf = np.round((times - grid[0]) / step)
    if np.abs(times - (grid[0] + kf * step)).max() > 1e-3 * step + 4 * np.finfo(np.float32).eps * np.abs(times).max():
        return times, False
    every = len(times) == len(grid) and kf[0] == 0 and bool(np.all(np.diff(kf) == 1))
    return grid[0] + kf * step, every


def _sample(
    times: np.ndarray, vals: np.ndarray, interp: str, grid: np.ndarray, rotation: bool, every: bool = False
) -> np.ndarray:
    """Values of one sampler at the ``grid`` times (``every``: one key per frame)."""
    k = len(times)
    if interp == "CUBICSPLINE":
        tri = vals.reshape(k, 3, -1)
        v, a_in, b_out = tri[:, 1], tri[:, 0], tri[:, 2]
    else:
        v = vals
    if k == 1:
        return cast("np.ndarray", np.broadcast_to(v[0], (len(grid), v.shape[1])).copy())
    if every:
        return v  # a key on every frame (the common case): no interpolation
    i = np.clip(np.searchsorted(times, grid, side="right") - 1, 0, k - 2)
    dt = times[i + 1] - times[i]
    u = np.clip((grid - times[i]) / np.where(dt > 0, dt, 1.0), 0.0, 1.0)
    if interp == "STEP":
        return np.where((u >= 1.0)[:, None], v[i + 1], v[i])
    if interp == "CUBICSPLINE":
        u2, u3 = u * u, u * u * u
        d = dt[:, None]
        out = (
            (2 * u3 - 3 * u2 + 1)[:, None] * v[i]
            + (u3 - 2 * u2 + u)[:, None] * d * b_out[i]
            + (-2 * u3 + 3 * u2)[:, None] * v[i + 1]
            + (u3 - u2)[:, None] * d * a_in[i + 1]
        )
        return quat.normalize(out) if rotation else out
    if rotation:
        return quat.slerp(v[i], v[i + 1], u)
    return cast("np.ndarray", v[i] + u[:, None] * (v[i + 1] - v[i]))


def read_gltf(path: str | Path, animation: int | str = 0, fps: float | Literal["auto"] = "auto") -> Motion:
    """Read the skeletal animation of a ``.gltf`` or ``.glb`` file (module doc).
    ``animation``: index or name; ``fps``: sampling rate, ``"auto"`` from the file.

    Metadata: ``path``, ``format`` ("gltf"), ``checksum``, ``source_fps``, ``source_frames``,
    ``fps_source`` ("extras", "key times" or "given"), ``animation`` (its name),
    ``animations`` (all names), ``start_time`` (seconds of the first frame)."""
    path = Path(path)
    data = read_bytes(path, lambda head: _check_head(path, head, path.stat().st_size))
    doc = _Doc(path, data)
    k_anim, anim = _pick_animation(doc, animation)
    aw = f"animations[{k_anim}]"
    samplers = doc.get(anim, "samplers", list, aw)
    parent = _parents(doc)
    channels = _channels(doc, anim, aw, samplers)
    if not channels:
        raise doc.error(f"{aw}: expected translation, rotation or scale channels on nodes")
    rate, source = _rate(doc, anim, channels, fps)
    t0 = min(float(c[3][0]) for c in channels)
    t1 = max(float(c[3][-1]) for c in channels)
    n_frames = int(round((t1 - t0) * rate)) + 1
    if n_frames > 10_000_000:
        raise doc.error(f"{aw}: {t1 - t0:g} s at {rate:g} fps is over 10^7 frames")
    densest = max(len(c[3]) for c in channels)
    if source == "key times" and n_frames < densest / 2:
        raise doc.error(
            f"{aw}: the key spacing implies {rate:g} fps, {n_frames:,} frames from {t0:g} to {t1:g} s for a sampler of "
            f"{densest:,} keys; expected key times spread over the take (a far or corrupt key time?)"
        )
    order, first = _select(doc, parent, {c[0] for c in channels})
    check_timeline(
        path,
        n_frames=n_frames,
        n_nodes=len(order),
        key_times=[c[3] for c in channels],
        t0=t0,
        t1=t1,
        fps=rate,
        size=len(data),
    )
    grid = t0 + np.arange(n_frames) / rate
    nodes = doc.doc["nodes"]
    col = {n: k for k, n in enumerate(order)}
    rest = [_node_trs(doc, n, nodes[n]) for n in order]
    rest_t = np.array([x[0] for x in rest])
    rest_r = np.array([x[1] for x in rest])
    raw_names = [str(nodes[n].get("name") or f"node{n}") for n in order]
    rest_s = np.array([uniform_scale(path, nm, x[2]) for nm, x in zip(raw_names, rest, strict=True)])
    # node-major arrays: each node's frames contiguous (passed on as (F, N, ...) views)
    t = np.broadcast_to(rest_t[:, None], (len(order), n_frames, 3)).copy()
    r = np.broadcast_to(rest_r[:, None], (len(order), n_frames, 4)).copy()
    s = np.broadcast_to(rest_s[:, None], (len(order), n_frames)).copy()
    snapped: dict[int, tuple[np.ndarray, bool]] = {}  # samplers often share their input accessor
    for node, tpath, interp, times, vals in channels:
        if node not in col:
            continue
        k = col[node]
        if id(times) not in snapped:
            snapped[id(times)] = _snap(times, grid)
        keys, every = snapped[id(times)]
        if tpath == "rotation":
            r[k] = _sample(keys, vals[:, [3, 0, 1, 2]], interp, grid, True, every)
            n2 = np.einsum("fc,fc->f", r[k], r[k])
            if n2.min() < 1e-12:
                raise doc.error(f"{aw}: node {raw_names[k]!r} has a zero rotation quaternion")
            if np.abs(n2 - 1.0).max() > 1e-6:  # quantized or sloppy keys (float32 rounding is below 1e-6)
                r[k] /= np.sqrt(n2)[:, None]
        elif tpath == "translation":
            t[k] = _sample(keys, vals, interp, grid, False, every)
        else:
            s[k] = uniform_scale(path, raw_names[k], _sample(keys, vals, interp, grid, False, every))
    par = np.array([col.get(int(parent[n]), -1) for n in order], dtype=np.int64)
    names = unique_names(raw_names)
    meta = file_metadata(path, data, "gltf")
    all_names = [
        a.get("name", f"animation{i}") if isinstance(a, dict) else None for i, a in enumerate(doc.doc["animations"])
    ]
    meta.update(
        subject=path.parent.name,
        source_fps=rate,
        source_frames=n_frames,
        fps_source=source,
        animation=all_names[k_anim],
        animations=all_names,
        start_time=t0,
    )
    return motion_from_nodes(
        path,
        names=names,
        parents=par,
        first_joint=first,
        rest_t=rest_t,
        rest_r=rest_r,
        rest_s=rest_s,
        t=t.transpose(1, 0, 2),
        r=r.transpose(1, 0, 2),
        s=s.T,
        fps=rate,
        fmt="gltf",
        name=path.stem,
        meta=meta,
    )


def _channels(
    doc: _Doc, anim: dict[str, Any], aw: str, samplers: list[Any]
) -> list[tuple[int, str, str, np.ndarray, np.ndarray]]:
    """(node, path, interpolation, key times, values) of the animation's TRS channels."""
    channels = []
    for c, ch in enumerate(doc.get(anim, "channels", list, aw)):
        cw = f"{aw}.channels[{c}]"
        if not isinstance(ch, dict):
            raise doc.error(f"{cw}: expected a JSON object")
        target = doc.get(ch, "target", dict, cw)
        tpath = doc.get(target, "path", str, cw)
        if tpath not in _PATHS or "node" not in target:
            continue  # morph-target weights, extension-driven targets: not skeletal
        node = target["node"]
        doc.item("nodes", node, f"{cw}.target.node")
        si = doc.get(ch, "sampler", int, cw)
        if not 0 <= si < len(samplers) or not isinstance(samplers[si], dict):
            raise doc.error(f"{cw}: expected a sampler index below {len(samplers)}, found {si}")
        smp = samplers[si]
        sw = f"{aw}.samplers[{si}]"
        interp = doc.get(smp, "interpolation", str, sw, "LINEAR")
        if interp not in ("LINEAR", "STEP", "CUBICSPLINE"):
            raise doc.error(f"{sw}: expected interpolation LINEAR, STEP or CUBICSPLINE, found {interp!r}")
        times = doc.accessor(doc.get(smp, "input", int, sw), f"{sw}.input", (1,))[:, 0]
        if np.any(np.diff(times) < 0):
            raise doc.error(f"{sw}.input: expected non-decreasing key times")
        width = _PATHS[tpath]
        vals = doc.accessor(doc.get(smp, "output", int, sw), f"{sw}.output", (width,))
        if len(vals) != len(times) * (3 if interp == "CUBICSPLINE" else 1):
            raise doc.error(f"{sw}: expected {len(times)} output values for {len(times)} key times, found {len(vals)}")
        channels.append((int(node), tpath, interp, times, vals))
    return channels


def _rate(doc: _Doc, anim: dict[str, Any], channels: list[Any], fps: float | str) -> tuple[float, str]:
    if fps != "auto":
        if not 0 < float(fps) <= MAX_FPS:
            raise DataError(f"fps must be in (0, {MAX_FPS:g}] or 'auto', got {fps!r}")
        return float(fps), "given"
    extras = anim.get("extras")
    if isinstance(extras, dict) and isinstance(extras.get("fps"), (int, float)) and not isinstance(extras["fps"], bool):
        f = float(extras["fps"])
        if not 0 < f <= MAX_FPS:
            raise doc.error(f"animation extras.fps: expected a rate in (0, {MAX_FPS:g}], found {f:g}")
        return f, "extras"
    best = max(channels, key=lambda c: len(c[3]))
    times = best[3]
    if len(times) < 2 or times[-1] <= times[0]:
        return 30.0, "default (a single key)"
    steps = np.diff(times)
    mean = (times[-1] - times[0]) / (len(times) - 1)
    tol = 1e-3 * mean + 4 * np.finfo(np.float32).eps * abs(times[-1])
    f = 1.0 / mean if np.abs(steps - mean).max() <= tol else 1.0 / steps[steps > tol].min()
    if not 0 < f <= MAX_FPS:
        raise doc.error(f"key times imply {f:g} fps; expected a rate in (0, {MAX_FPS:g}]")
    return _snap_fps(f, times), "key times"


class GltfFormat(Format):
    """glTF 2.0 / GLB skeletal animation: reader and writer."""

    name: ClassVar[str] = "gltf"
    extensions: ClassVar[tuple[str, ...]] = (".gltf", ".glb")
    produces: ClassVar[str] = "motion"

    class Params(BaseParams):
        animation: int | str = Field(0, description="which animation of the file: index or name")
        fps: float | Literal["auto"] = Field(
            "auto", description="sampling rate, or 'auto' (the file's extras.fps, else its key spacing)"
        )

    params: Params

    def read(self, path: str | Path) -> Motion:
        return read_gltf(path, animation=self.params.animation, fps=self.params.fps)

    def write(self, obj: Any, path: str | Path) -> None:
        write_gltf(obj, path)
