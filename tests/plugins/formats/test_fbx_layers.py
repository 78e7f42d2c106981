"""FBX animation layers: the vectorised blending of ``_fbx_layers`` against the per-sample
transcription of ufbx.c (``tests/naive/fbx_layers.py``), synthetic layered takes read end to
end (weights, animated weights, blend and accumulation modes, mute and solo) against that
twin, and the ufbx corpus's layered files against ufbx (skipped without ufbx or the corpus;
ufbx runs in a subprocess)."""

from __future__ import annotations

import os
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

from mocapflow.plugins.formats import _fbx_layers as fl
from mocapflow.plugins.formats import _fbx_write as fw
from mocapflow.plugins.formats.fbx import read_fbx

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from naive import fbx_layers as naive

ORDERS = ["xyz", "xzy", "yzx", "yxz", "zxy", "zyx"]


def _xyzw(q):
    return (q[1], q[2], q[3], q[0])


@pytest.mark.parametrize("order", range(7))
def test_euler_quaternion_conversions_equal_the_twin(order):
    rng = np.random.default_rng(order)
    ang = rng.uniform(-400, 400, size=(300, 3))
    ang[:20, "xyz".index(ORDERS[order % 6][1])] = rng.choice([90.0, -90.0, 270.0], 20)  # gimbal lock
    q = fl._to_quat(ang, order)
    for k in range(len(ang)):
        np.testing.assert_allclose(_xyzw(q[k]), naive.euler_to_quat(ang[k], order), atol=1e-12)
    e = fl._to_euler(q, order)
    for k in range(len(ang)):
        np.testing.assert_allclose(e[k], naive.quat_to_euler(_xyzw(q[k]), order), atol=1e-7)


@pytest.mark.parametrize("seed", range(24))
def test_combine_equals_the_twin(seed):
    rng = np.random.default_rng(100 + seed)
    n = 64
    mode = [0, 1, 2, 7][seed % 4]
    layer = fl.Layer("L", 1, 1.0, mode, compose_rotation=bool(seed & 4), compose_scale=bool(seed & 8))
    order = int(rng.integers(0, 7))
    weight = rng.uniform(-0.2, 1.2, n)
    weight[:4] = [0.0, 1.0, 0.5, 0.9999995]
    weight = fl.clamp_weight(weight * 100)
    for channel in "trs":
        if channel == "s":
            result = rng.uniform(-3, 3, (n, 3))
            value = rng.uniform(-3, 3, (n, 3))
            value[:3] = 0.0
        else:
            result = rng.uniform(-400, 400, (n, 3))
            value = rng.uniform(-400, 400, (n, 3))
        result[5] = value[5]  # coinciding rotations: slerp's early exit
        got = fl.combine(result, value, weight, layer, channel, order)
        for k in range(n):
            want = naive.combine(
                mode, layer.compose_rotation, layer.compose_scale, weight[k], channel, result[k], value[k], order
            )
            np.testing.assert_allclose(got[k], want, rtol=1e-9, atol=1e-7, err_msg=f"{channel} sample {k}")


def test_weight_clamp_equals_the_twin():
    p = np.array([-5.0, 0.0, 37.5, 99.998, 99.999, 99.9995, 100.0, 250.0])
    np.testing.assert_array_equal(fl.clamp_weight(p), [naive.clamp_weight(x) for x in p])


# --- synthetic layered takes -------------------------------------------------------------

FPS, N = 30.0, 13
TICKS = np.round(np.arange(N) * fw.KTIME / FPS).astype(np.int64)
TIP = (10.0, 0.0, 0.0)  # the child's offset (cm)


def _layered_fbx(layers: list[dict], order: int = 0) -> bytes:
    """A two-joint skeleton (root, tip) whose root is animated by ``layers``: each a dict of
    layer properties (``props``), per property ``"t"``/``"r"`` an (N, 3) array of linear keys
    (NaN column: no curve on that axis, node value 0) and optional ``weight`` keys (percent)."""
    ids = iter(range(1000, 10**6))
    objects, conns = fw._N("Objects"), fw._N("Connections")
    root, tip = next(ids), next(ids)
    for mid, name, t in ((root, "root", (0.0, 0.0, 0.0)), (tip, "tip", TIP)):
        m = objects.add("Model", mid, f"{name}\x00\x01Model", "LimbNode")
        m.kids.append(
            fw._p70(
                ("RotationOrder", "enum", "", "", fw._Int32(order)),
                ("RotationActive", "bool", "", "", fw._Int32(1)),
                ("Lcl Translation", "Lcl Translation", "", "A", *t),
                ("Lcl Rotation", "Lcl Rotation", "", "A", 5.0, 6.0, 7.0),
            )
        )
    conns.add("C", "OO", root, 0)
    conns.add("C", "OO", tip, root)
    stack = next(ids)
    objects.add("AnimationStack", stack, "Take\x00\x01AnimStack", "")

    def curve(owner: int, prop: str, values: np.ndarray) -> None:
        cid = next(ids)
        c = objects.add("AnimationCurve", cid, "\x00\x01AnimCurve", "")
        c.add("KeyTime", TICKS)
        c.add("KeyValueFloat", values.astype(np.float32))
        c.add("KeyAttrFlags", np.array([0x4], dtype=np.int32))
        c.add("KeyAttrDataFloat", np.zeros(4, dtype=np.float32))
        c.add("KeyAttrRefCount", np.array([N], dtype=np.int32))
        conns.add("C", "OP", cid, owner, prop)

    for spec in layers:
        lid = next(ids)
        lay = objects.add("AnimationLayer", lid, f"{spec.get('name', 'L')}\x00\x01AnimLayer", "")
        lay.kids.append(fw._p70(*((k, "double", "Number", "A", float(v)) for k, v in spec.get("props", {}).items())))
        conns.add("C", "OO", lid, stack)
        if "weight" in spec:
            cn = next(ids)
            objects.add("AnimationCurveNode", cn, "Weight\x00\x01AnimCurveNode", "").kids.append(
                fw._p70(("d|Weight", "Number", "", "A", 50.0))
            )
            conns.add("C", "OO", cn, lid)
            conns.add("C", "OP", cn, lid, "Weight")
            curve(cn, "d|Weight", np.asarray(spec["weight"], dtype=float))
        for key, prop in (("t", "Lcl Translation"), ("r", "Lcl Rotation")):
            if key not in spec:
                continue
            cn = next(ids)
            objects.add("AnimationCurveNode", cn, f"{key.upper()}\x00\x01AnimCurveNode", "").kids.append(
                fw._p70(*((f"d|{a}", "Number", "", "A", 0.0) for a in "XYZ"))
            )
            conns.add("C", "OO", cn, lid)
            conns.add("C", "OP", cn, root, prop)
            for a, axis in enumerate("XYZ"):
                if not np.isnan(spec[key][0, a]):
                    curve(cn, f"d|{axis}", spec[key][:, a])
    settings = fw._N("GlobalSettings")
    settings.kids.append(fw._p70(("TimeMode", "enum", "", "", fw._Int32(6))))
    out = bytearray(fw._HEAD + struct.pack("<I", fw.VERSION))
    for node in (settings, objects, conns):
        out += fw._record(node, len(out))
    out += fw._NULL + fw._FOOT_ID
    out += b"\x00" * ((16 - len(out) % 16) % 16 or 16)
    out += b"\x00" * 4 + struct.pack("<I", fw.VERSION) + b"\x00" * 120 + fw._FOOT_MAGIC
    return bytes(out)


def _expected(layers: list[dict], order: int) -> np.ndarray:
    """The tip's positions (metres) by the twin: per frame, the root's static values, the
    first layer's replacing them, the later (not muted, solo-selected) ones combined."""
    solo = any(s.get("props", {}).get("Solo", 0) for s in layers[1:])
    out = np.empty((N, 2, 3))
    for f in range(N):
        chan = {"t": (0.0, 0.0, 0.0), "r": (5.0, 6.0, 7.0)}
        for k, spec in enumerate(layers):
            p = spec.get("props", {})
            if k > 0 and (p.get("Mute", 0) or (solo and not p.get("Solo", 0))):
                continue
            mode = int(p.get("BlendMode", 0))
            animated = "weight" in spec and mode in (0, 2)
            w = naive.clamp_weight(float(np.float32(spec["weight"][f])) if animated else p.get("Weight", 100))
            for key in "tr":
                if key in spec:
                    v = tuple(
                        0.0 if np.isnan(spec[key][0, a]) else float(np.float32(spec[key][f, a])) for a in range(3)
                    )
                    chan[key] = (
                        v
                        if k == 0
                        else naive.combine(
                            mode, p.get("RotationAccumulationMode", 0) == 0, True, w, key, chan[key], v, order
                        )
                    )
        q = naive.euler_to_quat(chan["r"], order)
        x, y, z, w_ = q
        vx, vy, vz = TIP  # rotate TIP by q (ufbx's ufbx_quat_rotate_vec3)
        xy, xz, yz = x * vy - y * vx, x * vz - z * vx, y * vz - z * vy
        rot = (
            2.0 * (w_ * yz + y * xy + z * xz) + vx,
            2.0 * (-x * xy - w_ * xz + z * yz) + vy,
            2.0 * (-x * xz - y * yz + w_ * xy) + vz,
        )
        out[f, 0] = chan["t"]
        out[f, 1] = np.add(chan["t"], rot)
    return out * 0.01


def _keys(rng, scale):
    return rng.uniform(-scale, scale, (N, 3))


CASES = {
    "additive by channel, weight 40": lambda r: [
        {"t": _keys(r, 20), "r": _keys(r, 90)},
        {"props": {"Weight": 40, "RotationAccumulationMode": 1}, "t": _keys(r, 20), "r": _keys(r, 90)},
    ],
    "additive by layer, animated weight": lambda r: [
        {"t": _keys(r, 20), "r": _keys(r, 90)},
        {"props": {"Weight": 100}, "weight": r.uniform(-10, 110, N), "t": _keys(r, 20), "r": _keys(r, 90)},
    ],
    "animated weight without a Weight property": lambda r: [
        {"t": _keys(r, 20), "r": _keys(r, 90)},
        {"props": {"BlendMode": 2}, "weight": r.uniform(0, 100, N), "t": _keys(r, 20), "r": _keys(r, 90)},
    ],
    "passthrough by layer then by channel": lambda r: [
        {"t": _keys(r, 20), "r": _keys(r, 90)},
        {"props": {"BlendMode": 2, "Weight": 70}, "r": _keys(r, 170)},
        {
            "props": {"BlendMode": 2, "RotationAccumulationMode": 1, "Weight": 0},
            "weight": r.uniform(0, 100, N),
            "t": _keys(r, 5),
        },
    ],
    "override ignores the weight, one axis keyed": lambda r: [
        {"t": _keys(r, 20)},
        {"props": {"BlendMode": 1, "Weight": 10}, "t": np.c_[_keys(r, 20)[:, :1], np.full((N, 2), np.nan)]},
    ],
    "muted layer skipped": lambda r: [
        {"t": _keys(r, 20), "r": _keys(r, 90)},
        {"props": {"Mute": 1}, "t": _keys(r, 20), "r": _keys(r, 90)},
        {"props": {"Weight": 30}, "r": _keys(r, 90)},
    ],
    "solo: only soloed later layers": lambda r: [
        {"t": _keys(r, 20)},
        {"t": _keys(r, 20)},
        {"props": {"Solo": 1, "BlendMode": 2, "Weight": 60}, "t": _keys(r, 20), "r": _keys(r, 90)},
    ],
    "later layer only: static values blended": lambda r: [
        {"name": "Base"},
        {"props": {"Weight": 50, "BlendMode": 2}, "r": _keys(r, 90)},
    ],
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("order", [0, 2, 5])
def test_layered_take_equals_the_twin(tmp_path, case, order):
    layers = CASES[case](np.random.default_rng(list(CASES).index(case) * 10 + order))
    path = tmp_path / "layers.fbx"
    path.write_bytes(_layered_fbx(layers, order))
    m = read_fbx(path)
    assert m.n_frames == N and m.fps == FPS
    np.testing.assert_allclose(m.positions, _expected(layers, order), atol=1e-9)


def test_too_many_layers_refused(tmp_path):
    from mocapflow.framework.errors import ParseError
    from mocapflow.plugins.formats import fbx

    path = tmp_path / "many.fbx"
    path.write_bytes(_layered_fbx([{"t": np.zeros((N, 3))}] + [{}] * fbx.MAX_LAYERS))
    with pytest.raises(ParseError, match="animation layers"):
        read_fbx(path)


@pytest.mark.parametrize(
    "props",
    [
        {"Weight": 1e300, "BlendMode": 1e12, "RotationAccumulationMode": -7},
        {"Weight": -1e9, "ScaleAccumulationMode": 3, "Mute": 2, "Solo": -1},
        {"Weight": float("nan")},
        {"BlendMode": float("inf")},
    ],
)
def test_hostile_layer_properties(tmp_path, props):
    """Out-of-range layer properties read as ufbx clamps them, or are refused by name."""
    from mocapflow.framework.errors import ParseError

    rng = np.random.default_rng(5)
    path = tmp_path / "hostile.fbx"
    path.write_bytes(_layered_fbx([{"t": _keys(rng, 20)}, {"props": props, "t": _keys(rng, 20), "r": _keys(rng, 90)}]))
    try:
        m = read_fbx(path)
    except ParseError as e:
        assert "AnimationLayer" in str(e)
    else:
        assert np.all(np.isfinite(m.positions))


def test_mutated_layered_files_are_read_or_refused(tmp_path):
    """Byte flips and truncations of a layered take: a finite motion or a ParseError, nothing
    else (the scene fuzzer's rule, ``benchmarks/fuzz_parsers.py``, on a file with layers)."""
    from mocapflow.framework.errors import ParseError

    rng = np.random.default_rng(11)
    base = _layered_fbx(CASES["passthrough by layer then by channel"](rng), 3)
    path = tmp_path / "case.fbx"
    outcomes = {"read": 0, "refused": 0}
    for i in range(150):
        r = np.random.default_rng([11, i])
        data = bytearray(base)
        if i % 5 == 0:
            data = data[: int(r.integers(30, len(data)))]
        else:
            for p in r.integers(27, len(data) - 200, size=int(r.integers(1, 5))):
                data[p] = int(r.integers(0, 256))
        path.write_bytes(bytes(data))
        try:
            m = read_fbx(path)
        except ParseError:
            outcomes["refused"] += 1
        else:
            assert np.all(np.isfinite(m.positions)), f"case {i}"
            outcomes["read"] += 1
    assert outcomes["read"] and outcomes["refused"]


# --- against ufbx ----------------------------------------------------------------------------


def _ufbx():
    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
    import _ufbx_ref

    if not _ufbx_ref.available():
        pytest.skip("ufbx is not installed (pip install ufbx)")
    return _ufbx_ref


@pytest.mark.parametrize("case", [c for c in CASES if "mute" not in c and "solo" not in c])
def test_layered_take_equals_ufbx(tmp_path, case):
    """ufbx reads the synthetic takes as mocapflow does (mute and solo left out: ufbx ignores
    them)."""
    ref = _ufbx()
    layers = CASES[case](np.random.default_rng(7))
    path = tmp_path / "layers.fbx"
    path.write_bytes(_layered_fbx(layers, 4))
    m = read_fbx(path)
    r = ref.ufbx_positions(path, list(m.skeleton.names), np.arange(N) * (TICKS[1] / fw.KTIME))
    np.testing.assert_allclose(m.positions, r["pos"] * 0.01, atol=1e-9)


def _corpus() -> Path | None:
    p = Path(os.environ.get("MOCAPFLOW_UFBX_DATA", Path(__file__).resolve().parents[2] / "data" / "ufbx"))
    return p if p.is_dir() else None


#: The layered files of ufbx's corpus (Maya: additive and override-passthrough layers,
#: weights static and animated, both accumulation modes) and the files whose leaf models
#: scale non-uniformly.
LAYER_FILES = [
    "maya_anim_layers_7500_binary.fbx",
    "maya_anim_layers_acc_7500_binary.fbx",
    "maya_anim_layers_over_7500_binary.fbx",
    "maya_anim_layers_over_acc_7500_binary.fbx",
    "maya_extrapolate_cube_7700_binary.fbx",
    "maya_null_pivots_7700_binary.fbx",
    "maya_split_pivot_7700_binary.fbx",
    "maya_transform_animation_7500_binary.fbx",
]


def _corpus_file(name: str) -> Path:
    corpus = _corpus()
    if corpus is None or not (corpus / name).exists():
        pytest.skip("ufbx test corpus absent (set MOCAPFLOW_UFBX_DATA to github.com/ufbx/ufbx data/)")
    return corpus / name


@pytest.mark.parametrize("name", LAYER_FILES)
def test_layered_file_equals_ufbx(name):
    path = _corpus_file(name)
    _ufbx()
    from fbx_parity import compare

    r = compare(path, max_frames=40)
    assert r["err"] <= 1e-4
    assert r["fps"] == pytest.approx(r["ufbx_fps"], rel=1e-6)
    assert r["frames"] == r["ufbx_frames"]


@pytest.mark.parametrize(
    "name",
    [
        "maya_anim_layers_7500_binary.fbx",
        "maya_anim_layers_acc_7500_binary.fbx",
        "maya_anim_layers_over_acc_7500_binary.fbx",
        "maya_anim_layers_over_acc_orders_7500_binary.fbx",
    ],
)
def test_layered_local_transforms_equal_ufbx(name):
    """Each animated model's blended local translation, rotation and scale (the files' models
    are unparented cubes, so positions alone would not show the rotations; the ``orders``
    file has six cubes in the six rotation orders, blended by quaternions)."""
    path = _corpus_file(name)
    ref = _ufbx()
    from mocapflow.plugins.formats import _fbx_scene, fbx

    data = path.read_bytes()
    version, root = fbx.parse_fbx(path, data, _fbx_scene.OBJECT_KINDS)
    template, objects, parent, owner = _fbx_scene.scene(path, root)
    stack, _n, _names = _fbx_scene.take_stack(path, objects, 0)
    ktps = _fbx_scene.ktime(root, version)
    layers, curves = fbx._curves(path, root, objects, owner, stack, ktps, data, version)
    models = sorted({m for m, _c in curves})
    names = [objects[m][1] for m in models]
    times = np.linspace(0.0, 5.0, 31)
    r = ref.ufbx_positions(path, names, times)["local"]
    weights = fbx._weights(layers, times)
    for j, m in enumerate(models):
        props = _fbx_scene.Props(path, _fbx_scene.props70(objects[m][2]), template, names[j])
        chan = {
            c: fbx._channel(props, names[j], key, c, d, curves.get((m, c), []), times, (layers, weights))
            for key, c, d in (
                ("Lcl Translation", "t", (0.0, 0.0, 0.0)),
                ("Lcl Rotation", "r", (0.0, 0.0, 0.0)),
                ("Lcl Scaling", "s", (1.0, 1.0, 1.0)),
            )
        }
        q = fl.euler_quat(chan["r"], ORDERS[int(props.num("RotationOrder", 0.0))])
        np.testing.assert_allclose(chan["t"], r[:, j, :3], atol=1e-9)
        np.testing.assert_allclose(np.abs((q * r[:, j, 3:7]).sum(axis=1)), 1.0, atol=1e-12)
        np.testing.assert_allclose(chan["s"], r[:, j, 7:], atol=1e-9)
