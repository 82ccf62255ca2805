"""What the IR does not carry from a .blend, one warning each (the package docstring):
armatures (put in their rest pose here), actions, a file from a newer Blender."""

from __future__ import annotations

import numpy as np


def _listed(names: list[str], most: int = 5) -> str:
    names = sorted(names)
    more = f" and {len(names) - most} more" if len(names) > most else ""
    return ", ".join(names[:most]) + more


def rest_armatures() -> dict[str, str]:
    """Every armature in its rest pose (before any evaluation reads a mesh); one
    warning naming them and, where the file showed one, the pose it was saved in."""
    import bpy

    armatures = [ob for ob in bpy.data.objects if ob.type == "ARMATURE"]
    if not armatures:
        return {}
    posed = []
    for ob in armatures:
        action = ob.animation_data.action if ob.animation_data else None
        moved = ob.pose is not None and any(not np.allclose(np.array(pb.matrix_basis), np.eye(4)) for pb in ob.pose.bones)
        if ob.data.pose_position == "POSE" and (action is not None or moved):
            posed.append(f"{ob.name} showed {'action ' + repr(action.name) if action else 'a pose'}")
    for arm in bpy.data.armatures:
        arm.pose_position = "REST"
    bpy.context.evaluated_depsgraph_get().update()
    names = [f"{ob.name} ({len(ob.data.bones)} bones)" for ob in armatures]
    saved = f"; the file was saved posed ({'; '.join(sorted(posed))} at frame {bpy.context.scene.frame_current})" \
        if posed else ""
    return {"armature": f"armatures are not carried: {_listed(names)}; the meshes they deform or carry are read "
                        f"in the rest pose{saved}"}


def animation_warning() -> dict[str, str]:
    """One warning for the actions of the file, which the IR does not carry."""
    import bpy

    actions = [a.name for a in bpy.data.actions]
    if not actions:
        return {}
    return {"animation": f"{len(actions)} actions are not carried ({_listed(actions)}): objects are read as the "
                         f"file shows them at frame {bpy.context.scene.frame_current}, armatures at rest"}


def newer_file_warning() -> dict[str, str]:
    """A warning when the file was saved by a newer Blender than the one reading it
    (its file version beyond bpy's): Blender reads it, but may drop what it does not know."""
    import bpy

    saved, reader = tuple(bpy.data.version), tuple(bpy.app.version_file)
    if saved <= reader:
        return {}
    return {"blender_version": f"saved by Blender {saved[0]}.{saved[1]} (file version {'.'.join(map(str, saved))}), "
                               f"newer than the Blender {bpy.app.version_string} reading it: data it does not know is "
                               "lost (save it from this version, or update bpy)"}
