"""Authors the small .blend fixtures of tests/ingest/test_ingest_blend.py.

Run in a subprocess (a clean Blender state): python blend_fixtures.py OUT_DIR MARKER
MARKER is a path prefix the hostile file's driver and text block would write to.
"""

import math
import sys
from pathlib import Path

import bpy

OUT = Path(sys.argv[1])
MARKER = sys.argv[2]

CUBE_V = [(x, y, z) for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
# Outward (counter-clockwise seen from outside) quads of CUBE_V.
CUBE_F = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def reset():
    bpy.ops.wm.read_factory_settings(use_empty=True)


def material(name, color, metallic=0.0, roughness=0.5, emission=None, alpha=1.0):
    if name in bpy.data.materials:
        return bpy.data.materials[name]
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Alpha"].default_value = alpha
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Roughness"].default_value = roughness
    if emission:
        bsdf.inputs["Emission Color"].default_value = (*emission[0], 1.0)
        bsdf.inputs["Emission Strength"].default_value = emission[1]
    return mat


def mesh(name, verts=CUBE_V, faces=CUBE_F, mats=("steel",), parent=None, location=(0, 0, 0), scale=(1, 1, 1)):
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    for m in mats:
        me.materials.append(material(m, (0.6, 0.6, 0.6), 1.0, 0.4))
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    ob.scale = scale
    bpy.context.scene.collection.objects.link(ob)
    if parent is not None:
        ob.parent = parent
    return ob


def empty(name, kind, location, parent=None, rotation=(0, 0, 0), **props):
    ob = bpy.data.objects.new(name, None)
    ob.location = location
    ob.rotation_euler = rotation
    bpy.context.scene.collection.objects.link(ob)
    if parent is not None:
        ob.parent = parent
    ob["joint"] = kind
    for k, v in props.items():
        ob[k] = v
    return ob


def save(name):
    bpy.context.preferences.filepaths.save_version = 0
    bpy.ops.wm.save_as_mainfile(filepath=str(OUT / f"{name}.blend"), compress=False)


def full():
    reset()
    material("lamp_off", (0.1, 0.1, 0.02))
    # Used by no object: a fake user keeps it in the saved file.
    material("lamp_alarm", (1.0, 0.1, 0.0), roughness=0.3, emission=((1.0, 0.5, 0.25), 4.0), alpha=0.8).use_fake_user = True
    frame = mesh("frame", location=(0, 0, 0.5))
    col = mesh("frame_collision", location=(0, 0, 0.5), scale=(1.1, 1.1, 1.1))
    col["collision"] = True
    rail = mesh("rail", location=(2, 0, 0))
    arr = rail.modifiers.new("array", "ARRAY")
    arr.count = 5
    arr.use_merge_vertices = False
    hinge = empty("hinge", "revolute", (1, 0, 1), rotation=(0, 0, math.radians(30)),
                  joint_lower=-0.5, joint_upper=1.2, joint_effort=10.0, joint_velocity=1.5)
    arm = mesh("arm", parent=hinge, location=(0.5, 0, 0), scale=(1, 0.2, 0.2))
    slider = empty("slider", "prismatic", (1, 0, 0), parent=arm, joint_axis=[1.0, 0.0, 1.0],
                   joint_lower=0.0, joint_upper=0.3)
    mesh("carriage", parent=slider)
    # Mirrored: the reader must bake the scale and keep faces outward.
    mesh("mirrored", location=(-2, 0, 0), scale=(-1, 1, 2))
    # Two materials on one object: two visuals.
    two = mesh("twotone", location=(0, 3, 0), mats=("steel", "paint"))
    for i, poly in enumerate(two.data.polygons):
        poly.material_index = i % 2
    # A gauge level with a shape key and a binding.
    level = mesh("level", location=(0, -3, 0))
    level.shape_key_add(name="Basis")
    key = level.shape_key_add(name="full")
    for i, v in enumerate(CUBE_V):
        if v[2] > 0:
            key.data[i].co = (v[0], v[1], 1.5)
    key.value = 0.7  # the base mesh must still be the basis
    level["state"] = "oil_level"
    level["state_effect"] = "shape"
    level["state_domain"] = [0.0, 1.0]
    level["state_range"] = [0.0, 1.0]
    lamp = mesh("lamp", location=(3, 3, 0), mats=("lamp_off",))
    lamp["state"] = "alarm"
    lamp["state_effect"] = "material"
    lamp["state_domain"] = [0.0, 1.0]
    lamp["state_materials"] = ["lamp_off", "lamp_alarm"]
    lamp["state_thresholds"] = [0.5]
    pointer = mesh("pointer", location=(3, -3, 1), scale=(0.1, 0.5, 0.05))
    pointer["state"] = "oil_level"
    pointer["state_effect"] = "rotate"
    pointer["state_domain"] = [0.0, 1.0]
    pointer["state_range"] = [0.0, 4.0]
    # UVs: every face gets the full square, so corners shared by faces disagree.
    uvbox = mesh("uvbox", location=(-3, 3, 0))
    layer = uvbox.data.uv_layers.new(name="uv")
    square = [(0, 0), (1, 0), (1, 1), (0, 1)]
    for poly in uvbox.data.polygons:
        for corner, loop in enumerate(poly.loop_indices):
            layer.data[loop].uv = square[corner]
    save("full")


def shape_with_modifier():
    reset()
    ob = mesh("gauge")
    ob.shape_key_add(name="Basis")
    key = ob.shape_key_add(name="high")
    for i, v in enumerate(CUBE_V):
        key.data[i].co = (v[0], v[1], v[2] * 3)
    ob.modifiers.new("sub", "SUBSURF").levels = 1
    ob["state"] = "oil"
    ob["state_effect"] = "shape"
    ob["state_domain"] = [0.0, 1.0]
    save("shape_modifier")


def hostile():
    reset()
    ob = mesh("tri")
    fc = ob.driver_add("location", 0)
    fc.driver.type = "SCRIPTED"
    fc.driver.expression = f"(open({MARKER + '.driver'!r}, 'w').write('x') and 0) or 1.0"
    text = bpy.data.texts.new("evil.py")
    text.write(f"open({MARKER + '.text'!r}, 'w').write('x')\n")
    text.use_module = True
    save("hostile")


def bad_files():
    reset()
    mesh("box")
    empty("hinge", "rotary", (0, 0, 1))
    save("bad_joint")

    reset()
    mesh("box")
    h = empty("hinge", "revolute", (0, 0, 1), joint_axis=[0.0, 1e-12, 0.0])
    mesh("arm", parent=h)
    save("zero_axis")

    reset()
    ob = mesh("box")
    ob["state"] = "oil_level"
    ob["state_effect"] = "wobble"
    ob["state_domain"] = [0.0, 1.0]
    save("bad_effect")

    reset()
    mesh("box")
    mesh("nothing", verts=[(0, 0, 0), (1, 0, 0)], faces=[])
    save("empty_mesh")

    reset()
    mesh("box")
    h = empty("hinge", "revolute", (0, 0, 1))
    c = mesh("hinge_collision", parent=h)
    c["collision"] = True
    save("orphan_collision")

    reset()
    mesh("box")
    nan = mesh("bad_points", verts=[(0, 0, 0), (1, 0, 0), (0, float("nan"), 0)], faces=[(0, 1, 2)])
    assert nan is not None
    save("nan")


def visibility():
    reset()
    mesh("shown")
    hidden = mesh("hidden", location=(2, 0, 0))
    hidden.modifiers.new("sub", "SUBSURF").levels = 1
    hidden.hide_viewport = True
    shelf = bpy.data.collections.new("shelf")
    bpy.context.scene.collection.children.link(shelf)
    shelf.hide_viewport = True
    mesh("on_shelf", location=(4, 0, 0))
    bpy.context.scene.collection.objects.unlink(bpy.data.objects["on_shelf"])
    shelf.objects.link(bpy.data.objects["on_shelf"])
    old = bpy.data.collections.new("old")
    bpy.context.scene.collection.children.link(old)
    old.objects.link(mesh("excluded", location=(6, 0, 0)))
    bpy.context.scene.collection.objects.unlink(bpy.data.objects["excluded"])
    bpy.context.view_layer.layer_collection.children["old"].exclude = True
    save("visibility")

    reset()
    empty("lonely", "fixed", (0, 0, 0))
    save("no_geometry")


def textured():
    """A quad with UVs whose material takes Base Color from a packed image and Normal,
    through a Normal Map node, from an image beside the .blend; a second material's
    image lies outside the .blend's folder (it must not be read)."""
    reset()
    ob = mesh("panel", verts=[(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)], faces=[(0, 1, 2, 3)], mats=("painted",))
    uv = ob.data.uv_layers.new(name="UVMap")
    for loop, (u, v) in zip(uv.data, [(0, 0), (1, 0), (1, 1), (0, 1)]):
        loop.uv = (u, v)
    mat = bpy.data.materials["painted"]
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    albedo = bpy.data.images.new("albedo", 4, 2)
    albedo.pixels = [0.9, 0.1, 0.1, 1.0] * 4 + [0.1, 0.1, 0.9, 1.0] * 4
    albedo.pack()
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = albedo
    links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    normal_img = bpy.data.images.new("bumps", 2, 2)
    normal_img.pixels = [0.5, 0.5, 1.0, 1.0] * 4
    normal_img.filepath_raw = str(OUT / "bumps.png")
    normal_img.file_format = "PNG"
    normal_img.save()
    normal_img.filepath = "//bumps.png"
    ntex = nodes.new("ShaderNodeTexImage")
    ntex.image = normal_img
    nmap = nodes.new("ShaderNodeNormalMap")
    links.new(ntex.outputs["Color"], nmap.inputs["Color"])
    links.new(nmap.outputs["Normal"], bsdf.inputs["Normal"])
    other = mesh("sign", verts=[(0, 1, 0), (1, 1, 0), (1, 1, 1)], faces=[(0, 1, 2)], mats=("outside",))
    other.data.uv_layers.new(name="UVMap")
    far = bpy.data.images.new("far", 2, 2)
    far.filepath_raw = str(OUT.parent / "far.png")
    far.file_format = "PNG"
    far.save()
    omat = bpy.data.materials["outside"]
    ftex = omat.node_tree.nodes.new("ShaderNodeTexImage")
    ftex.image = far
    omat.node_tree.links.new(ftex.outputs["Color"], omat.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    save("textured")


full()
textured()
visibility()
shape_with_modifier()
hostile()
bad_files()
print("fixtures written")
