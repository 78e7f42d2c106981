"""Make the glTF/GLB/FBX test files and their Blender reference positions.

Stage 1 (run with mocapflow's python): cut clips from the bundled CMU takes
(``examples/data/cmu``), write them as BVH with mocapflow's writer, then run stage 2
with Blender's python (``pip install bpy``)::

    python tests/data/blender/make_blender_files.py --blender-python /path/to/bpy-venv/bin/python

``--check-writer`` instead writes clips with mocapflow's glTF and FBX writers (``.gltf``, ``.glb``, ``.fbx``),
imports them with Blender's importer and prints the largest joint-position difference
(nothing is written to the repository).

Stage 2 (Blender): for each clip, a factory-empty scene imports the BVH (``update_scene_fps``)
and exports it with Blender's own exporters (glTF separate, GLB, binary FBX; settings in
``CLIPS``); then a fresh empty scene imports each exported file with Blender's importer
(default settings; the scene rate set to the clip's before a glTF import, FBX sets it
itself) and records every bone head's world position at every frame of the imported action
in ``<file>.npz``: ``names`` (B,), ``positions`` (T, B, 3) in metres, converted from
Blender's z-up to y-up as ``(x, z, -y)``, ``fps``, ``blender`` (version string).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent.parent

#: name -> (AMC take, first frame, stop, step, export kind, export options)
CLIPS = {
    "walk_120.gltf": ("02/02_01.amc", 0, 60, 1, "gltf", {"export_format": "GLTF_SEPARATE"}),
    "jump_60.glb": ("02/02_04.amc", 120, 240, 2, "gltf", {"export_format": "GLB"}),
    "walk_120.fbx": ("16/16_15.amc", 0, 60, 1, "fbx", {}),
    "run_30_zup_cm.fbx": ("02/02_03.amc", 0, 172, 4, "fbx", {"axis_up": "Z", "axis_forward": "Y", "unit_cm": True}),
}


def stage1(blender_python: str) -> None:
    from mocapflow.plugins.formats.asf_amc import read_amc
    from mocapflow.plugins.formats.bvh import write_bvh

    with tempfile.TemporaryDirectory() as tmp:
        jobs = []
        for name, (take, a, b, step, kind, opts) in CLIPS.items():
            m = read_amc(ROOT / "examples" / "data" / "cmu" / take)
            m = m.slice(a, b)
            if step > 1:
                m = m.with_arrays(
                    root_translation=m.root_translation[::step], rotations=m.rotations[::step], fps=m.fps / step
                )
            bvh = Path(tmp) / (Path(name).stem + ".bvh")
            write_bvh(m, bvh)
            jobs.append({"name": name, "bvh": str(bvh), "kind": kind, "opts": opts, "fps": m.fps, "frames": m.n_frames})
        spec = Path(tmp) / "jobs.json"
        spec.write_text(json.dumps(jobs))
        subprocess.run([blender_python, __file__, "--stage2", str(spec), str(HERE)], check=True)


def check_writer(blender_python: str) -> None:
    import numpy as np

    from mocapflow.plugins.formats.asf_amc import read_amc
    from mocapflow.plugins.formats.fbx import read_fbx, write_fbx
    from mocapflow.plugins.formats.gltf import read_gltf, write_gltf

    with tempfile.TemporaryDirectory() as tmp:
        jobs = []
        sources = [("02/02_01.amc", None), ("16/16_35.amc", None), ("jump_60.glb", "glb")]
        for k, (take, kind) in enumerate(sources):
            m = read_gltf(HERE / take) if kind else read_amc(ROOT / "examples" / "data" / "cmu" / take).slice(0, 120)
            for ext in (".gltf", ".glb", ".fbx"):
                out = Path(tmp) / f"w{k}{ext}"
                (write_fbx if ext == ".fbx" else write_gltf)(m, out)
                ours = (read_fbx if ext == ".fbx" else read_gltf)(out)
                np.save(out.with_suffix(out.suffix + ".npy"), ours.positions)
                jobs.append({"path": str(out), "fps": m.fps, "names": list(ours.skeleton.names), "n": ours.n_frames})
        spec = Path(tmp) / "jobs.json"
        spec.write_text(json.dumps(jobs))
        subprocess.run([blender_python, __file__, "--stage-check", str(spec)], check=True)


def stage_check(spec: Path) -> None:
    import bpy
    import numpy as np

    worst = 0.0
    for job in json.loads(spec.read_text()):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        scene.render.fps, scene.render.fps_base = round(job["fps"]), round(job["fps"]) / job["fps"]
        if job["path"].endswith(".fbx"):
            bpy.ops.import_scene.fbx(filepath=job["path"])
        else:
            bpy.ops.import_scene.gltf(filepath=job["path"])
        arm = next(o for o in scene.objects if o.type == "ARMATURE")
        f0 = int(round(arm.animation_data.action.frame_range[0]))
        want = np.load(job["path"] + ".npy")
        got = np.zeros_like(want)
        for f in range(job["n"]):
            scene.frame_set(f0 + f)
            for j, name in enumerate(job["names"]):
                v = arm.matrix_world @ arm.pose.bones[name].head
                got[f, j] = (v[0], v[2], -v[1])
        err = float(np.abs(got - want).max())
        worst = max(worst, err)
        print(
            f"{Path(job['path']).name}: {job['n']} frames, {len(job['names'])} joints, max |Blender - mocapflow| {err:.2e} m"
        )
    print(f"writer check (Blender {bpy.app.version_string}): worst {worst:.2e} m")


def stage2(spec: Path, out: Path) -> None:
    import bpy
    import numpy as np

    for job in json.loads(spec.read_text()):
        target = out / job["name"]
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.import_anim.bvh(filepath=job["bvh"], update_scene_fps=True, update_scene_duration=True)
        scene = bpy.context.scene
        scene.frame_start, scene.frame_end = 1, job["frames"]  # the FBX exporter bakes the scene's range
        opts = dict(job["opts"])
        if job["kind"] == "gltf":
            bpy.ops.export_scene.gltf(filepath=str(target), **opts)
        else:
            if opts.pop("unit_cm", False):
                scene.unit_settings.system = "METRIC"
                scene.unit_settings.scale_length = 0.01  # a centimetre scene: the file's UnitScaleFactor is 1
                opts["global_scale"] = 100.0  # the metre-sized armature written in centimetres
            bpy.ops.export_scene.fbx(
                filepath=str(target),
                object_types={"ARMATURE"},
                bake_anim_use_all_actions=False,
                bake_anim_use_nla_strips=False,
                **opts,
            )
        # reference: Blender's importer on the exported file, in a fresh scene
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        if job["kind"] == "gltf":
            scene.render.fps, scene.render.fps_base = round(job["fps"]), round(job["fps"]) / job["fps"]
            bpy.ops.import_scene.gltf(filepath=str(target))
        else:
            bpy.ops.import_scene.fbx(filepath=str(target))
        arm = next(o for o in scene.objects if o.type == "ARMATURE")
        action = arm.animation_data.action
        f0, f1 = (int(round(v)) for v in action.frame_range)
        names = [pb.name for pb in arm.pose.bones]
        pos = []
        for f in range(f0, f1 + 1):
            scene.frame_set(f)
            mw = arm.matrix_world
            pos.append([list(mw @ pb.head) for pb in arm.pose.bones])
        p = np.array(pos)
        p = np.stack([p[..., 0], p[..., 2], -p[..., 1]], axis=-1)
        fps = scene.render.fps / scene.render.fps_base
        np.savez_compressed(
            target.with_name(target.name + ".npz"),
            names=np.array(names),
            positions=p,
            fps=fps,
            blender=bpy.app.version_string,
        )
        print(job["name"], p.shape, fps, f0, f1)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blender-python", default=None)
    ap.add_argument("--stage2", nargs=2, default=None)
    ap.add_argument("--check-writer", action="store_true")
    ap.add_argument("--stage-check", default=None)
    a = ap.parse_args()
    if a.stage_check:
        stage_check(Path(a.stage_check))
    elif a.check_writer:
        check_writer(a.blender_python or sys.exit("--blender-python is required"))
    elif a.stage2:
        stage2(Path(a.stage2[0]), Path(a.stage2[1]))
    else:
        stage1(a.blender_python or sys.exit("--blender-python is required"))
