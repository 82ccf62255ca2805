"""Parametric parts shared by helper A's authoring scripts: revolved solids, boxes,
insulator shed profiles, pipes, dial gauges and the asset.toml writer.

Detail comes from modifiers (Screw, Array, Bevel) that the pipeline evaluates, so the
stored meshes stay small. Every function is deterministic. The leading underscore keeps
make_all.py from running this module as an authoring script.
"""

from __future__ import annotations

import math
from pathlib import Path

import bpy
from mathutils import Vector

import kit

TAU = kit.TAU


# --- raw meshes ------------------------------------------------------------------------


def _link(name: str, me, mat: str | None, location, rotation, scale=(1.0, 1.0, 1.0)):
    if mat is not None:
        me.materials.append(kit.material(mat))
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    ob.rotation_euler = rotation
    ob.scale = scale
    bpy.context.scene.collection.objects.link(ob)
    return ob


def mesh(name: str, verts, faces, mat: str, location=(0, 0, 0), rotation=(0, 0, 0), scale=(1, 1, 1)):
    """A mesh object from vertex and face lists (faces counter-clockwise from outside)."""
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, v)) for v in verts], [], [tuple(f) for f in faces])
    me.validate(clean_customdata=False)
    return _link(name, me, mat, location, rotation, scale)


BOX_FACES = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]


def box_verts(size, offset=(0.0, 0.0, 0.0)):
    """The 8 corners of a box of `size` centred on `offset` (faces: BOX_FACES)."""
    (sx, sy, sz), (ox, oy, oz) = (tuple(s / 2.0 for s in size)), offset
    return [(ox + x * sx, oy + y * sy, oz + z * sz) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)]


def box(name: str, size, center, mat: str, rotation=(0, 0, 0), bevel: float = 0.0):
    """A box of `size` (x, y, z) centred on `center`, optionally bevelled."""
    ob = mesh(name, box_verts(size), BOX_FACES, mat, center, rotation)
    if bevel > 0.0:
        add_bevel(ob, bevel, 2)
    return ob


def prism_x(name: str, radius: float, x0: float, x1: float, mat: str, location, scale=(1, 1, 1),
            segments: int = 16):
    """A closed round bar along local +X from x0 to x1, stored as plain mesh data (so a
    negative scale on the object mirrors it)."""
    ring = [(radius * math.cos(TAU * i / segments), radius * math.sin(TAU * i / segments))
            for i in range(segments)]
    verts = [(x, y, z) for x in (x0, x1) for y, z in ring]
    faces = [(i, (i + 1) % segments, segments + (i + 1) % segments, segments + i) for i in range(segments)]
    faces += [tuple(range(segments - 1, -1, -1)), tuple(range(segments, 2 * segments))]
    return mesh(name, verts, faces, mat, location, (0, 0, 0), scale)


def revolve(name: str, profile, mat: str, segments: int = 48, location=(0, 0, 0), rotation=(0, 0, 0)):
    """A solid of revolution about the local Z axis (Screw modifier).

    profile: [(r, z), ...] a polyline in the XZ half-plane, ordered bottom to top; when it
    starts and ends on the axis (r = 0) the result is closed.
    """
    me = bpy.data.meshes.new(name)
    verts = [(float(r), 0.0, float(z)) for r, z in profile]
    edges = [(i, i + 1) for i in range(len(verts) - 1)]
    me.from_pydata(verts, edges, [])
    ob = _link(name, me, mat, location, rotation)
    screw = ob.modifiers.new("revolve", "SCREW")
    screw.axis = "Z"
    screw.angle = TAU
    screw.steps = segments
    screw.render_steps = segments
    screw.screw_offset = 0.0
    screw.use_merge_vertices = True
    screw.merge_threshold = 1e-5
    # A bottom-to-top profile revolved this way faces inwards; flip it to face out (the
    # automatic normal calculation guesses differently for wavy profiles such as sheds).
    screw.use_normal_calculate = False
    screw.use_normal_flip = True
    return ob


def cylinder(name: str, radius: float, length: float, center, mat: str, axis: str = "Z", segments: int = 32):
    """A closed cylinder along the model X, Y or Z axis, centred on `center`."""
    h = length / 2.0
    profile = [(0.0, -h), (radius, -h), (radius, h), (0.0, h)]
    rotation = {"Z": (0, 0, 0), "X": (0, math.pi / 2, 0), "Y": (math.pi / 2, 0, 0)}[axis]
    return revolve(name, profile, mat, segments, center, rotation)


def rod(name: str, start, end, radius: float, mat: str, segments: int = 16):
    """A closed cylinder from point `start` to point `end` (pipes, braces)."""
    a, b = Vector(start), Vector(end)
    d = b - a
    profile = [(0.0, 0.0), (radius, 0.0), (radius, d.length), (0.0, d.length)]
    rotation = d.to_track_quat("Z", "Y").to_euler()
    return revolve(name, profile, mat, segments, a, tuple(rotation))


def add_array(ob, count: int, offset, name: str = "array"):
    """Repeat `ob` `count` times at a constant offset (x, y, z) in its local frame."""
    mod = ob.modifiers.new(name, "ARRAY")
    mod.count = count
    mod.use_relative_offset = False
    mod.use_constant_offset = True
    mod.constant_offset_displace = offset
    return mod


def add_bevel(ob, width: float, segments: int):
    mod = ob.modifiers.new("bevel", "BEVEL")
    mod.width = width
    mod.segments = segments
    mod.limit_method = "ANGLE"
    return mod


def parent_keep(children, parent) -> None:
    """Parent every object of `children` to `parent`, keeping world transforms."""
    for child in children:
        kit.set_parent_keep(child, parent)


def collision_box(name: str, size, center, count: int = 1, offset=(0.0, 0.0, 0.0)):
    """A box (optionally arrayed) marked as authored collision geometry."""
    ob = box(name, size, center, "galvanised_steel")
    if count > 1:
        add_array(ob, count, offset)
    ob["collision"] = True
    ob.display_type = "WIRE"
    return ob


# --- radiators -------------------------------------------------------------------------


def radiator_fin(name: str, x0: float, depth: float, z0: float, height: float, y0: float,
                 channels: int = 12, sections: int = 10):
    """One pressed-steel radiator panel in the XZ plane, `depth` long in +X from x0: a wavy
    cross-section (vertical oil channels) extruded upwards in welded sections."""
    section = []
    for i in range(2 * channels + 1):
        half = 0.012 if i % 2 else 0.005
        section.append((depth * i / (2 * channels), half))
    loop = [(x, -t) for x, t in section] + [(x, t) for x, t in reversed(section)]
    n = len(loop)
    verts = [(x0 + x, y, z0 + height * k / sections) for k in range(sections + 1) for x, y in loop]
    faces = []
    for k in range(sections):
        a, b = k * n, (k + 1) * n
        faces += [(a + i, a + (i + 1) % n, b + (i + 1) % n, b + i) for i in range(n)]
    faces.append(tuple(reversed(range(n))))
    faces.append(tuple(range(sections * n, (sections + 1) * n)))
    return mesh(name, verts, faces, "painted_tank", (0.0, y0, 0.0))


def radiator_bank(prefix: str, sign: float, x_near: float, *, depth: float, pitch: float, count: int,
                  z0: float, height: float, feeds_y, mat: str = "painted_tank"):
    """A bank of `count` panels along Y on the +X (sign +1) or -X end of a tank whose end
    face is at |x| = x_near - 0.15, with top and bottom headers and feed pipes."""
    y0 = -pitch * (count - 1) / 2
    x0 = x_near if sign > 0 else -x_near - depth
    fins = radiator_fin(f"{prefix}_fins", x0, depth, z0, height, y0)
    add_array(fins, count, (0.0, pitch, 0.0))
    x_mid = sign * (x_near + depth / 2)
    tank_x = sign * (x_near - 0.15)
    for level, z in (("top", z0 + height + 0.1), ("bottom", z0 - 0.1)):
        cylinder(f"{prefix}_header_{level}", 0.09, pitch * count + 0.1, (x_mid, 0.0, z), mat, "Y", 24)
        for k, y in enumerate(feeds_y):
            rod(f"{prefix}_feed_{level}_{k}", (tank_x, y, z), (x_mid, y, z), 0.07, mat, 24)
    return fins


# --- insulators ------------------------------------------------------------------------


def shed_profile(r_core: float, r_big: float, r_small: float, z0: float, z1: float, pitch: float):
    """(r, z) profile of an insulator between z0 and z1: a core with alternating big and
    small sheds (drip edge below, sloped top), closed at both ends on the axis."""
    pts = [(0.0, z0), (r_core, z0)]
    n = int((z1 - z0 - pitch * 0.5) / pitch)
    for i in range(n):
        base = z0 + pitch * (i + 0.5)
        r = r_big if i % 2 == 0 else r_small
        pts += [
            (r_core, base),
            (r - 0.008, base - 0.012),  # drip lip underneath
            (r, base - 0.004),
            (r, base + 0.006),
            (r_core + 0.25 * (r - r_core), base + 0.045 * (r - r_core) / 0.1 + 0.01),
            (r_core, base + 0.05 * (r - r_core) / 0.1 + 0.015),
        ]
    pts += [(r_core, z1), (0.0, z1)]
    # A big shed's top can meet the core exactly where the next shed starts: a
    # repeated point would revolve into a ring of zero-area faces.
    return [p for i, p in enumerate(pts) if i == 0 or math.dist(p, pts[i - 1]) > 1e-9]


def insulator(name: str, base_center, height: float, r_core: float, r_big: float, mat: str,
              pitch: float = 0.09, segments: int = 48):
    """An insulator column standing on `base_center` (sheds from bottom to top)."""
    x, y, z = base_center
    profile = shed_profile(r_core, r_big, r_core + 0.6 * (r_big - r_core), 0.0, height, pitch)
    return revolve(name, profile, mat, segments, (x, y, z))


def flange(name: str, center, radius: float, thickness: float, mat: str = "galvanised_steel", segments: int = 32):
    """A flat disc flange (axis Z) centred on `center`."""
    return cylinder(name, radius, thickness, center, mat, "Z", segments)


# --- gauges ----------------------------------------------------------------------------

# Pointer sweep: 0 % at -135 deg, 100 % at +135 deg about the dial normal (local Z),
# measured counter-clockwise from the dial's local +Y (up).
DIAL_SWEEP = (-2.356, 2.356)
DIAL_ROTATION = (math.pi / 2, 0.0, 0.0)  # local Z -> model -Y (out of a front face)


def _polar(angle: float, r: float, z: float):
    return (-r * math.sin(angle), r * math.cos(angle), z)


def annular_sector(name: str, r_in: float, r_out: float, a0: float, a1: float, z: float, mat: str,
                   location, steps: int = 24):
    """A flat ring sector in the local XY plane (angles from +Y, counter-clockwise);
    with r_in = 0 a fan of triangles around one centre vertex."""
    if r_in == 0.0:
        verts = [(0.0, 0.0, z)] + [_polar(a0 + (a1 - a0) * i / steps, r_out, z) for i in range(steps + 1)]
        faces = [(0, i + 1, i + 2) for i in range(steps)]
        return mesh(name, verts, faces, mat, location, DIAL_ROTATION)
    verts, faces = [], []
    for i in range(steps + 1):
        a = a0 + (a1 - a0) * i / steps
        verts += [_polar(a, r_in, z), _polar(a, r_out, z)]
    for i in range(steps):
        k = 2 * i
        faces.append((k, k + 1, k + 3, k + 2))
    return mesh(name, verts, faces, mat, location, DIAL_ROTATION)


def dial_gauge(prefix: str, center, radius: float, state: str, red_until: float = 25.0):
    """A mechanical dial gauge on a front (-Y) face, dial centre `center`.

    Objects: <prefix>_dial_white, <prefix>_dial_red (the low sector), <prefix>_glass,
    <prefix>_bezel, <prefix>_pointer (origin on the dial centre, rotating about its local Z
    which points out of the dial). The pointer carries the rotate binding.
    """
    cx, cy, cz = center
    lo, hi = DIAL_SWEEP
    red_end = lo + (hi - lo) * red_until / 100.0
    face_z = -0.008  # the dial face sits just behind the pointer
    annular_sector(f"{prefix}_dial_red", 0.55 * radius, 0.95 * radius, lo, red_end, face_z,
                   "dial_red", center, 12)
    # The white face: full inner disc plus the outer ring outside the red sector.
    white = annular_sector(f"{prefix}_dial_white", 0.0, 0.55 * radius, 0.0, TAU, face_z,
                           "dial_white", center, 48)
    _append_ring(white, 0.55 * radius, 0.95 * radius, red_end, lo + TAU, face_z, 36)
    _append_ring(white, 0.95 * radius, radius, 0.0, TAU, face_z, 48)
    revolve(f"{prefix}_glass", [(0.0, 0.008), (radius, 0.008), (radius, 0.014), (0.0, 0.024)],
            "gauge_glass", 48, center, DIAL_ROTATION)
    bezel_profile = [(0.0, -0.09), (radius * 1.05, -0.09), (radius * 1.12, -0.02),
                     (radius * 1.08, 0.016), (radius * 0.98, 0.018)]
    revolve(f"{prefix}_bezel", bezel_profile, "painted_grey", 48, center, DIAL_ROTATION)
    pointer = pointer_mesh(f"{prefix}_pointer", 0.85 * radius, center)
    kit.bind_state(pointer, state, "rotate", (0.0, 100.0), DIAL_SWEEP)
    return pointer


def _append_ring(ob, r_in: float, r_out: float, a0: float, a1: float, z: float, steps: int) -> None:
    """Add a ring sector to mesh object `ob` (same frame) as separate faces."""
    import bmesh

    bm = bmesh.new()
    bm.from_mesh(ob.data)
    ring = []
    for i in range(steps + 1):
        a = a0 + (a1 - a0) * i / steps
        ring.append((bm.verts.new(_polar(a, r_in, z)), bm.verts.new(_polar(a, r_out, z))))
    for (a_in, a_out), (b_in, b_out) in zip(ring, ring[1:]):
        bm.faces.new((a_in, a_out, b_out, b_in))
    bm.to_mesh(ob.data)
    bm.free()


def pointer_mesh(name: str, length: float, center):
    """A tapered pointer along local +Y with a hub, origin on the dial centre."""
    w, t = 0.012, 0.004
    verts = [(-w, -0.03, 0), (w, -0.03, 0), (0.002, length, 0), (-0.002, length, 0),
             (-w, -0.03, t), (w, -0.03, t), (0.002, length, t), (-0.002, length, t)]
    faces = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    ob = mesh(name, verts, faces, "pointer_black", center, DIAL_ROTATION)
    return ob


def oil_column(name: str, bottom_center, radius: float, full_height: float, mat: str = "oil_amber",
               segments: int = 16):
    """A vertical oil column with shape keys `Basis` (empty, ~1 mm) and `full`."""
    empty_h = 0.001
    verts = [(0.0, 0.0, 0.0), (0.0, 0.0, empty_h)]
    for z in (0.0, empty_h):
        for i in range(segments):
            a = TAU * i / segments
            verts.append((radius * math.cos(a), radius * math.sin(a), z))
    faces = []
    bottom, top = 2, 2 + segments
    for i in range(segments):
        j = (i + 1) % segments
        faces.append((bottom + i, bottom + j, top + j, top + i))
        faces.append((0, bottom + j, bottom + i))
        faces.append((1, top + i, top + j))
    ob = mesh(name, verts, faces, mat, bottom_center)
    ob.shape_key_add(name="Basis", from_mix=False)
    full = ob.shape_key_add(name="full", from_mix=False)
    full.value = 0.0  # authored empty; the runtime sets the weight
    for i, v in enumerate(ob.data.vertices):
        if v.co.z > empty_h / 2.0:
            full.data[i].co.z = full_height
    return ob


def sight_glass(prefix: str, bottom_center, state: str, height: float = 0.3):
    """A direct-view oil indicator: glass tube, caps and an oil column bound to `state`."""
    x, y, z = bottom_center
    cylinder(f"{prefix}_tube", 0.03, height, (x, y, z + height / 2.0), "gauge_glass", "Z", 24)
    cylinder(f"{prefix}_cap_bottom", 0.042, 0.03, (x, y, z - 0.015), "galvanised_steel", "Z", 24)
    cylinder(f"{prefix}_cap_top", 0.042, 0.03, (x, y, z + height + 0.015), "galvanised_steel", "Z", 24)
    oil = oil_column(f"{prefix}_oil", (x, y, z + 0.01), 0.024, height - 0.04)
    kit.bind_state(oil, state, "shape", (0.0, 100.0), (0.0, 1.0))
    return oil


def keep_material(name: str) -> None:
    """Keep a library material in the file although no object uses it yet (a material
    binding switches to it at run time)."""
    kit.material(name).use_fake_user = True


# --- asset.toml ------------------------------------------------------------------------


def write_asset_toml(out: Path, asset_id: str, category: str, description: str, *, budgets,
                     collision: str = "hull_per_link", triangle_budget: int = 400000,
                     mass_kg: float = 100.0, terminals=()) -> Path:
    """<out>/<asset_id>/asset.toml in the schema of schemas/asset.schema.json;
    `terminals`: (name, (x, y, z)) conductor attachment points in the model frame."""
    lines = [
        f'category = "{category}"',
        f'description = "{description}"',
        f'source = "{asset_id}.blend"',
        f"triangle_budget = {int(triangle_budget)}",
        f"mass_kg = {float(mass_kg)!r}",
        "",
        "[lod]",
        "budgets_m = [" + ", ".join(repr(float(b)) for b in budgets) + "]",
        "",
        "[collision]",
        f'mode = "{collision}"',
        "",
        *terminal_lines(terminals),
    ]
    path = out / asset_id / "asset.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))
    return path


def terminal_lines(terminals) -> list[str]:
    """asset.toml [[terminals]] tables, positions to the micrometre."""
    lines = []
    for name, xyz in terminals:
        lines += ["[[terminals]]", f'name = "{name}"',
                  "position = [" + ", ".join(repr(round(float(v), 6) + 0.0) for v in xyz) + "]", ""]
    return lines


def terminal_empties(terminals) -> None:
    """An Empty `terminal.<name>` (plain axes, 0.2 m) at each conductor attachment
    point, model frame: what the pipeline reads as the asset's terminals."""
    for name, xyz in terminals:
        ob = bpy.data.objects.new(f"terminal.{name}", None)
        ob.empty_display_type = "PLAIN_AXES"
        ob.empty_display_size = 0.2
        ob.location = tuple(float(v) for v in xyz)
        bpy.context.scene.collection.objects.link(ob)


def finish(asset_id: str, out: Path, terminals=()) -> Path:
    """Save the .blend (after a depsgraph update so parenting matrices are final), with
    the conductor terminals as `terminal.<name>` empties."""
    terminal_empties(terminals)
    bpy.context.view_layer.update()
    return kit.save(asset_id, out)
