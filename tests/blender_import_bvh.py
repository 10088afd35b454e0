"""Run by Blender, not by pytest: import BVH files with Blender's own importer and write what
Blender read back as JSON (used by ``tests/test_blender.py``).

    blender -b --factory-startup --python-exit-code 1 --python tests/blender_import_bvh.py -- \\
        OUT.json FRAME_START GLOBAL_SCALE FILE.bvh [FILE.bvh ...]

Each file is imported into an empty factory scene with ``bpy.ops.import_anim.bvh`` as an
armature (Euler angles in the file's own rotation order, ``rotate_mode="NATIVE"``), its first
frame keyed at Blender frame ``FRAME_START``, scaled by ``GLOBAL_SCALE`` and turned by the axis
conversion ``AXIS_FORWARD``/``AXIS_UP`` (BVH's Y-up, -Z-forward frame into Blender's Z-up,
-Y-forward one). Per file the JSON holds: the 4 x 4 conversion matrix the importer applied,
the scene's frame rate (``fps``, ``fps_base``) and range, the action's frame range and every
F-curve's keyframe times, the bones (name, parent) in creation order, and per Blender frame from
``FRAME_START`` to the last keyframe the world position of every pose bone's head and tail
(``matrix_world @ pose_bone.head`` of the evaluated armature after ``scene.frame_set``).

Blender 3.4's importer opens the file in mode ``"rU"``, which Python 3.11 removed; Debian's
Blender 3.4 runs on the system Python 3.11, where every import fails with ``ValueError: invalid
mode: 'rU'``. The importer's ``open`` is therefore given mode ``"r"``, what ``"U"`` has meant
since Python 3.0 (universal newlines), on any Python; all parsing stays Blender's.
"""

import json
import sys

import bpy
from bpy_extras.io_utils import axis_conversion

AXIS_FORWARD, AXIS_UP = "-Z", "Y"  # the importer's defaults, passed explicitly


def _open_without_u(file, mode="r", *args, **kwargs):
    return open(file, mode.replace("U", ""), *args, **kwargs)


def _patch_importer() -> None:
    """Mode ``"rU"`` -> ``"r"`` for the importer's ``open`` (module docstring)."""
    from io_anim_bvh import import_bvh

    import_bvh.open = _open_without_u


def _import(path: str, frame_start: int, scale: float) -> dict:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.frame_start = scene.frame_end = frame_start  # the importer only ever extends the end
    _patch_importer()
    result = bpy.ops.import_anim.bvh(
        filepath=path, target="ARMATURE", rotate_mode="NATIVE", global_scale=scale,
        frame_start=frame_start, axis_forward=AXIS_FORWARD, axis_up=AXIS_UP,
        use_fps_scale=False, update_scene_fps=True, update_scene_duration=True)
    if result != {"FINISHED"}:
        raise RuntimeError(f"{path}: import_anim.bvh returned {result}")
    (arm,) = [o for o in scene.objects if o.type == "ARMATURE"]
    action = arm.animation_data.action
    last = max(k.co[0] for fc in action.fcurves for k in fc.keyframe_points)
    heads, tails = [], []
    for frame in range(frame_start, int(round(last)) + 1):
        scene.frame_set(frame)
        ev = arm.evaluated_get(bpy.context.evaluated_depsgraph_get())
        heads.append([list(ev.matrix_world @ pb.head) for pb in ev.pose.bones])
        tails.append([list(ev.matrix_world @ pb.tail) for pb in ev.pose.bones])
    conversion = axis_conversion(from_forward=AXIS_FORWARD, from_up=AXIS_UP).to_4x4()
    return {
        "conversion": [list(row) for row in conversion],
        "fps": scene.render.fps, "fps_base": scene.render.fps_base,
        "scene_frames": [scene.frame_start, scene.frame_end],
        "action_frames": list(action.frame_range),
        "keyframes": {f"{fc.data_path}[{fc.array_index}]": [k.co[0] for k in fc.keyframe_points]
                      for fc in action.fcurves},
        "bones": [b.name for b in arm.data.bones],
        "parents": [b.parent.name if b.parent else None for b in arm.data.bones],
        "pose_bones": [pb.name for pb in arm.pose.bones],
        "heads": heads, "tails": tails,
    }


def main(argv: list[str]) -> None:
    out, frame_start, scale, *files = argv
    read = {path: _import(path, int(frame_start), float(scale)) for path in files}
    with open(out, "w", encoding="utf-8") as f:
        json.dump(read, f)


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1:])
