"""What Blender makes of a .glb of ours (run it with Blender, not with recon's Python):

    blender -b --factory-startup -noaudio --python scripts/blender_check.py -- FILE.glb [VERTICES.npy]

Prints one JSON line: armatures, bones, meshes (vertex groups, armature modifier, shape keys),
actions, cameras; with VERTICES.npy also saves the body as Blender poses it (world, Z up) for a
comparison with our own vertices. Checked by hand with Debian's blender 3.4 (docs/formats.md).
"""
import json
import sys

import numpy

if not hasattr(numpy, "bool"):
    numpy.bool = bool  # Blender 3.4's glTF importer still uses the alias numpy 1.24 removed

import bpy  # noqa: E402 - Blender's own module

args = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath=args[0])
arm = [o for o in bpy.data.objects if o.type == "ARMATURE"]
meshes = [o for o in bpy.data.objects if o.type == "MESH"]
info = {"file": args[0], "armatures": len(arm), "bones": [b.name for b in arm[0].data.bones] if arm else [],
        "meshes": {m.name: {"vertices": len(m.data.vertices), "vertex_groups": len(m.vertex_groups),
                            "armature_modifier": any(md.type == "ARMATURE" for md in m.modifiers),
                            "shape_keys": len(m.data.shape_keys.key_blocks) if m.data.shape_keys else 0}
                   for m in meshes},
        "actions": {a.name: {"fcurves": len(a.fcurves), "frames": list(a.frame_range)} for a in bpy.data.actions},
        "cameras": len([o for o in bpy.data.objects if o.type == "CAMERA"])}
print(json.dumps(info))
if len(args) > 1:
    body = next(m for m in meshes if m.name.startswith("body"))
    evaluated = body.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh()
    numpy.save(args[1], numpy.array([tuple(body.matrix_world @ v.co) for v in evaluated.vertices]))
