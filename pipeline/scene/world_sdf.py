"""The Gazebo world: SDF 1.9 with spherical coordinates, a sun, the terrain and every
placement, each drawing the meshes of its model package (never one scene mesh).

sdformat 12 (Gazebo Fortress) copies the whole description of an element's kind into
every <model>, <link>, <visual> and <collision> it parses, whatever they hold, a model
costing most and an <include> parsing the model's file again: its memory grows with
the count of those elements, and a world of one model per placement does not open on
a laptop. So the world keeps a model per placement only where the placement needs one,
and groups the rest:

- an <include> of the placement's LOD variant for an asset a state binding drives
  (the runtime swaps the include's URI);
- a placement drawn scaled ([floorplan] insert_scale = "apply") cannot be an include
  (SDF has no scale on one): it is a grouped model of its own, named by its TAG;
- every other placement of a package variant goes into one static model named after
  the variant, with one link: the placement is a <frame> named by its TAG at its pose
  (the same pose an include would have) and draws, posed relative to it, one <visual>
  `<TAG>__whole` of the package's whole model at its LOD (every visual of every link at
  rest, one submesh per material) and one <collision> `<TAG>__collision` of all its
  collision meshes: sdformat spends about 160 kB on each <visual> or <collision>
  (tools/gzprobe), and a site's thousands of placements fit only with one of each.
  A package without whole meshes (written before them) gets a copy of each of the
  variant's visuals and collisions, named `<TAG>__<name>` (`<TAG>__<link>__<name>`
  for a model of several links). A scaled placement's elements are posed at the
  scaled offsets and their geometry scaled (mesh <scale>, box, cylinder, sphere);
- a placement of a variant with movable joints (a disconnect switch) is grouped so
  too, but its grouped model draws its fixed links only, one <visual> `<TAG>__<link>`
  each (names.whole_link_mesh_file); its moving links hang on their joints in a
  non-static model of the variant's moving parts, with a JointPositionController per
  movable joint listening on the topic the live twin publishes on (world_joints).
  Under site.toml [gazebo] moving_parts = "none" (or a list of tag patterns its tag does
  not match) it is grouped as any other placement (its whole model at rest) and the
  world holds no joint for it; "auto" (the default) writes every switch moving unless
  the world would then cost sdformat more than its 1.5 GB parse budget, as at 5,000
  placements (write_within_budget);
- in the world, the grouped placements' collisions are not theirs but merged into a
  few cells of ground (world_collisions: `collision_cells`, one mesh shape a cell),
  and a placement that repeats another exactly (the same asset, scale and LOD at the
  same pose: devices piled on one insertion point) is its frame alone, the first
  drawing and colliding for both: at 5,000 placements one shape and one <collision>
  each neither stepped in real time nor parsed within the budget. A switch collides
  as it rests (its blade closed) wherever its joints are; a repeated switch keeps
  moving parts of its own, as each is commanded on its own.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path

import numpy as np
from lxml import etree

from .. import safe_xml
from ..findings import Finding, finding
from ..export.names import WHOLE_COLLISION_FILE, fmt, lod_model_name, whole_mesh_file
from .placements import Placed
from . import world_joints
from .world_joints import pose_of as _pose_of, scale_element, scale_geometry as _scale_geometry
from .world_collisions import CollisionCells, placement_key

# A placement's own elements in a grouped model: `<TAG>__<visual or collision name>`.
GROUPED_SEPARATOR = "__"
GROUPED_LINK = "placements"


def _text(parent, tag: str, text) -> etree._Element:
    el = etree.SubElement(parent, tag)
    el.text = str(text)
    return el


# sdformat's peak memory parsing a world that gz-sim loads on a laptop (validate's GZ008)
PARSE_BUDGET_MB = 1536.0
# sdformat 12's peak parse memory of a world written here, from the <visual>s and <joint>s
# of its file (parse_estimate_mb); the fit's data are in the commit that set them
PARSE_MB_BASE, PARSE_MB_PER_VISUAL, PARSE_MB_PER_JOINT = 189.0, 0.266, 1.432


def sun_direction(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit vector the sunlight travels along, in ENU (azimuth clockwise from north)."""
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    to_sun = np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])
    return -to_sun


def write(path: Path, **world_args) -> None:
    """The world (world_element's arguments) in the file `path`, its collision cells'
    meshes beside it."""
    _save(path, *world_element(**world_args))


def write_within_budget(path: Path, **world_args) -> tuple[str, float]:
    """site.toml [gazebo] moving_parts = "auto": the world in `path` with every switch's
    moving parts when sdformat would parse it within PARSE_BUDGET_MB
    (parse_estimate_mb), else with none. Returns ("all" or "none", the estimate of the
    world with every switch moving, MB)."""
    root, cells = world_element(moves=lambda tag: True, **world_args)
    estimate = parse_estimate_mb(root)
    if estimate > PARSE_BUDGET_MB:
        root, cells = world_element(moves=lambda tag: False, **world_args)
    _save(path, root, cells)
    return ("all" if estimate <= PARSE_BUDGET_MB else "none"), estimate


def at_rest_finding(world_name: str, estimate_mb: float) -> Finding:
    """GZ012: moving_parts = "auto" drew every switch at rest, and why."""
    return finding("GZ012", world_name, f"every switch is drawn at rest, without joints: with its moving parts the "
                   f"world would cost sdformat about {estimate_mb:.0f} MB to parse (budget {PARSE_BUDGET_MB:.0f} MB); "
                   'site.toml [gazebo] moving_parts = ["<tag pattern>", ...] moves the switches that must move')


def parse_estimate_mb(root: etree._Element) -> float:
    """The peak memory (MB) of sdformat 12 parsing a world written here, from the
    <visual>s and <joint>s of its file: a line fitted to tools/gzprobe's peaks of the
    sample and of the 5,000-placement plan (bench.plans.at_scale) with none, some and
    all of its switches moving. The file's own counts, not the parsed world's: those
    are what the scene has when it chooses."""
    visuals = sum(1 for _ in root.iter("visual"))
    joints = sum(1 for _ in root.iter("joint"))
    return PARSE_MB_BASE + PARSE_MB_PER_VISUAL * visuals + PARSE_MB_PER_JOINT * joints


def moving_parts_mb(joints: int) -> float:
    """What `joints` of switches' moving parts add to parse_estimate_mb: each joint's
    moving link draws one visual (world_joints)."""
    return joints * (PARSE_MB_PER_JOINT + PARSE_MB_PER_VISUAL)


def _save(path: Path, root: etree._Element, cells: CollisionCells) -> None:
    cells.write_meshes(Path(path).parent)
    Path(path).write_bytes(etree.tostring(root, pretty_print=True, xml_declaration=True, encoding="UTF-8"))


def world_element(*, site_name: str, origin_llh, placed: list[Placed], terrain_model: str,
          sun: dict, models: Path, own_model: frozenset[str] = frozenset(), extra_models=(),
          moves: Callable[[str], bool] = lambda tag: True) -> tuple[etree._Element, CollisionCells]:
    """The world's <sdf> element, and its collision cells, whose meshes the world names
    beside it (CollisionCells.write_meshes).
    models: the folder of the built packages (variants are read from it);
    own_model: asset ids whose placements stay one <include> each; extra_models:
    lxml <model> elements appended to the world (the conductors); moves: whether a
    placement's moving links (by tag) hang on joints (False: drawn whole at rest, no
    joint; config.moves_in_gazebo)."""
    sdf = etree.Element("sdf", version="1.9")
    world = etree.SubElement(sdf, "world", name=site_name)
    sph = etree.SubElement(world, "spherical_coordinates")
    _text(sph, "surface_model", "EARTH_WGS84")
    _text(sph, "world_frame_orientation", "ENU")
    _text(sph, "latitude_deg", fmt(origin_llh[0]))
    _text(sph, "longitude_deg", fmt(origin_llh[1]))
    _text(sph, "elevation", fmt(origin_llh[2]))
    _text(sph, "heading_deg", "0")

    # gz-sim hands <dart><collision_detector> to dartsim (SdfEntityCreator, Physics).
    # dartsim's default (ODE) updates every static shape each step; bullet's broadphase
    # keeps a site of static equipment above real time (tools/gzprobe --physics).
    physics = etree.SubElement(world, "physics", name="dart_bullet", type="dart", default="true")
    _text(physics, "max_step_size", "0.001")
    _text(physics, "real_time_factor", "1")
    _text(etree.SubElement(physics, "dart"), "collision_detector", "bullet")

    light = etree.SubElement(world, "light", type="directional", name="sun")
    _text(light, "cast_shadows", "true")
    _text(light, "pose", "0 0 100 0 0 0")
    _text(light, "diffuse", "1 0.96 0.9 1")
    _text(light, "specular", "0.3 0.3 0.3 1")
    _text(light, "intensity", fmt(round(sun["intensity"], 6)))
    d = sun_direction(sun["elevation_deg"], sun["azimuth_deg"])
    _text(light, "direction", " ".join(fmt(round(v, 12)) for v in d))

    inc = etree.SubElement(world, "include")
    _text(inc, "uri", f"model://{terrain_model}")
    _text(inc, "name", "terrain")
    _text(inc, "pose", "0 0 0 0 0 0")
    _text(inc, "static", "true")

    groups: dict[str, list[Placed]] = {}
    cells, drawn = CollisionCells(Path(models)), set()
    for pl in sorted(placed, key=lambda p: p.placement.tag):
        variant = lod_model_name(pl.placement.asset_id, pl.lod)
        if pl.placement.scale != 1.0:
            world.append(grouped_model(variant, Path(models) / variant / "model.sdf", [pl], name=pl.placement.tag,
                                       cells=cells, drawn=drawn, moves=moves))
            if moves(pl.placement.tag):
                _append_moving(world, Path(models), variant, [pl], pl.placement.tag + world_joints.MODEL_SUFFIX)
        elif pl.placement.asset_id in own_model:
            inc = etree.SubElement(world, "include")
            _text(inc, "uri", f"model://{variant}")
            _text(inc, "name", pl.placement.tag)
            x, y, z = pl.pose[:3, 3]
            _text(inc, "pose", " ".join(fmt(v) for v in (x, y, z, 0.0, 0.0, pl.yaw)))
            _text(inc, "static", "true")
        else:
            groups.setdefault(variant, []).append(pl)
    for variant, members in sorted(groups.items()):
        world.append(grouped_model(variant, Path(models) / variant / "model.sdf", members, cells=cells, drawn=drawn,
                                   moves=moves))
        moving = [pl for pl in members if moves(pl.placement.tag)]
        if moving:
            _append_moving(world, Path(models), variant, moving, variant + world_joints.MODEL_SUFFIX)
    merged = cells.model()
    if merged is not None:
        world.append(merged)
    for model in extra_models:
        world.append(copy.deepcopy(model))  # a world made twice (write_within_budget) holds its own
    return sdf, cells


def _append_moving(world: etree._Element, models: Path, variant: str, members: list[Placed], name: str) -> None:
    """The members' models of moving parts (world_joints), when the variant has movable
    joints: `name`, or `<name><k>` for the k-th run of world_joints.PER_MODEL members."""
    art = world_joints.read_articulation(models / variant / "model.sdf")
    if art is None:
        return
    runs = [members[k:k + world_joints.PER_MODEL] for k in range(0, len(members), world_joints.PER_MODEL)]
    for k, run in enumerate(runs):
        world.append(world_joints.moving_model(name if len(runs) == 1 else f"{name}{k}", models, run, art))


def grouped_model(variant: str, model_sdf: Path, members: list[Placed], name: str | None = None,
                  cells: CollisionCells | None = None, drawn: set | None = None,
                  moves: Callable[[str], bool] = lambda tag: True) -> etree._Element:
    """One static model (named `name`, default the variant) with one link: per member
    placement a frame named by its TAG at its pose, and what it draws posed relative to
    that frame, at the placement's scale: the package's whole model at the variant's
    LOD and all its collision meshes, one <visual> and one <collision> (`<TAG>__whole`,
    `<TAG>__collision`), when the package has them (export.collada._write_whole); else
    a copy of each of the variant's visuals and collisions. A variant with movable
    joints draws its fixed links only, one <visual> `<TAG>__<link>` each (or copies of
    their visuals): its moving links are in its model of moving parts
    (world_joints.moving_model); a member that `moves` says stays still is drawn
    whole, as a placement of any other variant. `cells`: the world's merged collisions, which take
    each member's collision instead when its package has the whole collision mesh.
    `drawn`: the placements already in the world (world_collisions.placement_key),
    shared by every call for one world: a member that repeats one exactly (devices
    piled on one insertion point) is its frame alone, the first one's visual and
    collision standing for both."""
    source = safe_xml.parse(model_sdf, remove_blank_text=True).getroot().find("model")
    articulated = world_joints.articulation(source)
    source_links = source.findall("link")
    model = etree.Element("model", name=name or variant)
    _text(model, "static", "true")
    link = etree.SubElement(model, "link", name=GROUPED_LINK)
    models = Path(model_sdf).parent.parent
    for pl in members:
        tag = pl.placement.tag
        art = articulated if moves(tag) else None
        x, y, z = pl.pose[:3, 3]
        frame = etree.Element("frame", name=tag, attached_to=GROUPED_LINK)
        _text(frame, "pose", " ".join(fmt(v) for v in (x, y, z, 0.0, 0.0, pl.yaw)))
        model.append(frame)
        if drawn is not None:
            key = placement_key(pl)
            if key in drawn:
                continue
            drawn.add(key)
        collides = any(sl.find("collision") is not None for sl in source_links)
        if collides and cells is not None and cells.add(pl):
            collides = False
        whole = _whole_elements(models, pl, collides) if art is None else None
        if whole is not None:
            for item in whole:
                link.append(item)
            continue
        if art is not None:
            for fixed in art.fixed:
                for item in world_joints.link_visuals(models, pl, art, fixed, tag + GROUPED_SEPARATOR + fixed):
                    link.append(scale_element(item, _pose_of(art.links[fixed]), pl.placement.scale, tag))
        for source_link in source_links:
            if art is not None and (source_link.get("name") in art.moving or not collides):
                continue  # drawn above; a moving link collides nowhere
            # names are unique within a link: with several links, the link's name too
            prefix = tag + GROUPED_SEPARATOR
            if len(source_links) > 1:
                prefix += source_link.get("name") + GROUPED_SEPARATOR
            kinds = ("collision",) if art is not None else ("visual", "collision") if collides else ("visual",)
            for kind in kinds:
                for el in source_link.findall(kind):
                    item = copy.deepcopy(el)
                    item.set("name", prefix + el.get("name"))
                    link.append(scale_element(item, _pose_of(source_link), pl.placement.scale, tag))
    return model


def _whole_elements(models: Path, pl: Placed, collides: bool) -> list[etree._Element] | None:
    """A placement's <visual> of its package's whole model at its LOD and <collision> of
    all its collision meshes (when the variant has any), or None when the package has
    no whole model at that LOD. Their materials are the meshes' own (COLLADA Phong)."""
    asset = pl.placement.asset_id
    visual_file = whole_mesh_file(pl.lod)
    if not (models / asset / visual_file).is_file():
        return None
    items = [("visual", f"{pl.placement.tag}{GROUPED_SEPARATOR}whole", visual_file)]
    if collides:
        if not (models / asset / WHOLE_COLLISION_FILE).is_file():
            return None
        items.append(("collision", f"{pl.placement.tag}{GROUPED_SEPARATOR}collision", WHOLE_COLLISION_FILE))
    out = []
    for kind, name, rel in items:
        item = etree.Element(kind, name=name)
        _text(item, "pose", "0 0 0 0 0 0").set("relative_to", pl.placement.tag)
        _text(etree.SubElement(etree.SubElement(item, "geometry"), "mesh"), "uri", f"model://{asset}/{rel}")
        if pl.placement.scale != 1.0:
            _scale_geometry(item, pl.placement.scale)
        out.append(item)
    return out
