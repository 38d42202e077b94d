"""Builds a 10-frame animation in `bpy` (the camera dollies and turns, a sphere moves,
the Cornell box stays) and exports it with `export_animation` into WORK/shot: one scene
file per frame, the unchanged meshes once. Prints one JSON line (frames, files, OBJs,
export time); exits non-zero if a mesh was written more than once. FRAMES (default 10)
stretches the same motion over more frames, for measuring a long shot's upload.

    python blender/tests/animation.py WORK [FRAMES]
"""

import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

import bpy  # noqa: E402

import compare_cycles as cc  # noqa: E402
from tilefarm_blender.export import export_animation  # noqa: E402


def main():
    work = sys.argv[1]
    last = int(sys.argv[2]) if len(sys.argv) > 2 else 10
    scene = cc.cornell(work)
    cc.cycles_settings(scene, 16, seed=1)
    scene.frame_start, scene.frame_end = 1, last
    cam = scene.camera
    for frame, x, yaw in [(1, -0.4, -0.1), (last, 0.4, 0.1)]:
        cam.location.x = x
        cam.rotation_euler.z = yaw
        cam.keyframe_insert("location", frame=frame)
        cam.keyframe_insert("rotation_euler", frame=frame)
    ball = bpy.data.objects["Sphere"]
    for frame, z in [(1, 0.31), (last, 1.0)]:
        ball.location.z = z
        ball.keyframe_insert("location", frame=frame)
    folder = os.path.join(work, "shot")
    report = export_animation(folder, 1, last, scene)
    files = sorted(os.listdir(folder))
    objs = [f for f in files if f.endswith(".obj")]
    meshes_per_frame = report.meshes // last
    print(json.dumps({"frames": last, "files": len(files), "objs": len(objs), "meshes_per_frame": meshes_per_frame,
                      "export_s": round(report.seconds, 3), "warnings": report.warnings}))
    # Nothing changes shape: every frame's meshes are the same files.
    code = 0 if len(objs) == meshes_per_frame else 1
    if code:
        print(f"FAILED: {len(objs)} OBJ files for {meshes_per_frame} meshes a frame", file=sys.stderr)
    sys.stdout.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
