"""Reader for mesh files (.stl, .obj with its .mtl, .ply, .glb, .gltf, .dae) through trimesh.

One link "base"; one visual per geometry of the file (a glTF or COLLADA scene's meshes
with their node transforms, an OBJ's material groups), with its material, or a
"default" PBR material.

Units and up axis (ingest.units): asset.toml `units` and `up_axis` where given, else
what the file declares (COLLADA <unit meter> and <up_axis>; glTF is metres and Y up
by its specification), else metres and Z up (STL, OBJ and PLY declare nothing).

What the IR does not carry is said, one warning each in the asset's metadata
(`warning.<what>`, see validate.checks SRC001): animations, glTF skins, COLLADA
controllers. glTF morph targets are kept as shape keys, with the file's default
weights honoured as in ingest.blend: the rest mesh is the weighted mix the file shows,
each key the shape with that target alone at full weight.

Files are untrusted: a COLLADA file that declares a DOCTYPE is refused (no entity is
ever resolved), and a glTF buffer or image, an OBJ material library, or an image an
.mtl names must be a file inside the source's folder (an error otherwise). Every other
file trimesh asks for goes through ingest.images.SourceFiles: read from the asset's
folder only, images capped, each file read recorded (Asset.metadata `opened`). A
glTF's buffers and embedded images reach trimesh under names of that resolver's own,
so that every image, embedded or not, passes the same caps. An image not carried (not
found, refused, over a cap) is a warning naming its material and its path.
"""

from __future__ import annotations

import contextlib
import json
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import ir
from ..errors import UserError
from ..geometry.clean import apply_transform
from .images import SourceFiles, is_image_name
from .size import check_size
from .textures import trimesh_textures, trimesh_uvs, with_textures
from .units import Frame, resolve

SUFFIXES = (".stl", ".obj", ".ply", ".glb", ".gltf", ".dae")
DEFAULT_MATERIAL = ir.Material("default")
COLLADA_UP = {"X_UP": "X", "Y_UP": "Y", "Z_UP": "Z"}


def _safe_name(name: str, fallback: str) -> str:
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name or "")).strip("_")
    return name or fallback


def _material(geom, fallback: str, unset: tuple = (0.8, 0.8, 0.8, 1.0)) -> ir.Material:
    """The trimesh visual's PBR or simple material, as an ir.Material; `unset`: the
    base colour of one that states none (glTF's is white by its specification)."""
    mat = getattr(getattr(geom, "visual", None), "material", None)
    if mat is None:
        return DEFAULT_MATERIAL
    name = _safe_name(getattr(mat, "name", None), fallback)
    try:
        pbr = mat.to_pbr() if hasattr(mat, "to_pbr") else mat
        color = pbr.baseColorFactor
        rgba = tuple(float(c) for c in (np.asarray(color, dtype=np.float64) / (255.0 if np.asarray(color).dtype.kind in "ui" else 1.0))) if color is not None else unset
        emissive = pbr.emissiveFactor
        return ir.Material(
            name,
            base_color=rgba if len(rgba) == 4 else (*rgba[:3], 1.0),
            metallic=float(pbr.metallicFactor if pbr.metallicFactor is not None else 0.0),
            roughness=float(pbr.roughnessFactor if pbr.roughnessFactor is not None else 0.5),
            emission=tuple(float(c) for c in emissive[:3]) if emissive is not None else (0.0, 0.0, 0.0),
        )
    except Exception:  # an exotic material: keep its name, use PBR defaults
        return ir.Material(name)


# --- what a file declares -------------------------------------------------------------


@dataclass
class Morph:
    """A glTF primitive's morph targets, in file coordinates: `rest` (n, 3) the mix the
    file shows, `keys` (name, (n, 3) absolute positions), `weights` the defaults."""

    base: np.ndarray
    rest: np.ndarray
    keys: tuple[tuple[str, np.ndarray], ...]
    weights: tuple[float, ...]


@dataclass
class Facts:
    """What a file says about itself beyond its triangles."""

    metres: float | None = None
    up: str | None = None
    default_up: str = "Z"
    warnings: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    morphs: dict[str, Morph] = field(default_factory=dict)  # trimesh geometry name -> targets
    # a name trimesh asks the resolver for -> (how the file calls it, the materials using it)
    names: dict[str, tuple[str, tuple[str, ...]]] = field(default_factory=dict)
    trimesh_file: bytes | None = None  # what trimesh reads instead of the file (a glTF's JSON)


def collada_facts(path: Path, files: SourceFiles | None = None) -> Facts:
    """<unit meter>, <up_axis>, the animations and controllers trimesh leaves out, and
    the materials each image serves."""
    from .. import safe_xml  # lxml is loaded by the first COLLADA file

    # Refused before the parse and, for a DOCTYPE past the first 64 KiB, after it:
    # trimesh's COLLADA reader (pycollada) would expand its entities.
    if safe_xml.declares_doctype(path) or safe_xml.has_doctype(tree := safe_xml.parse(path, remove_comments=True)):
        raise UserError(path, None, "COLLADA file declares a DOCTYPE (entities are refused, never resolved)")
    root = tree.getroot()
    facts = Facts()
    unit = root.find("{*}asset/{*}unit")
    if unit is not None and unit.get("meter") is not None:
        try:
            metres = float(unit.get("meter"))
        except ValueError:
            raise UserError(path, "asset/unit", f"meter = {unit.get('meter')!r} is not a number") from None
        if not np.isfinite(metres) or metres <= 0:
            raise UserError(path, "asset/unit", f"meter = {unit.get('meter')!r} is not a positive length")
        facts.metres = metres
    up = root.findtext("{*}asset/{*}up_axis")
    if up is not None:
        if up.strip() not in COLLADA_UP:
            raise UserError(path, "asset/up_axis", f"{up.strip()!r}: expected X_UP, Y_UP or Z_UP")
        facts.up = COLLADA_UP[up.strip()]
    animations = root.findall("{*}library_animations//{*}animation")
    if animations:
        facts.warnings["animation"] = f"{len(animations)} COLLADA animations are not carried: the model is read as it stands"
    skins = root.findall("{*}library_controllers/{*}controller/{*}skin")
    morphs = root.findall("{*}library_controllers/{*}controller/{*}morph")
    if skins or morphs:
        kinds = ", ".join(f"{n} {k}" for n, k in ((len(skins), "skin"), (len(morphs), "morph")) if n)
        facts.warnings["controller"] = (f"COLLADA controllers ({kinds}) are not carried: the meshes they deform "
                                        "are left out (export them as plain geometry)")
    facts.names = _collada_images(root)
    return facts


def _collada_images(root) -> dict[str, tuple[str, tuple[str, ...]]]:
    """init_from of each <image> -> (itself, the materials whose effect names the image
    (by its id, or through a <surface> param))."""
    images = {im.get("id"): (im.findtext("{*}init_from") or im.findtext("{*}init_from/{*}ref") or "").strip()
              for im in root.iter("{*}image")}
    effects: dict[str, set[str]] = {}
    for effect in root.iter("{*}effect"):
        named = {el.text.strip() for el in effect.iter("{*}init_from") if el.text}
        named |= {el.get("texture") for el in effect.iter("{*}texture")}
        effects[effect.get("id")] = {i for i in named if i in images}
    users: dict[str, set[str]] = {}
    for mat in root.iter("{*}material"):
        inst = mat.find("{*}instance_effect")
        url = (inst.get("url") or "").lstrip("#") if inst is not None else ""
        for image_id in effects.get(url, ()):
            users.setdefault(images[image_id], set()).add(mat.get("name") or mat.get("id") or "?")
    return {path: (path, tuple(sorted(users.get(path, ())))) for path in images.values() if path}


def _gltf_header(path: Path, files: SourceFiles | None = None):
    from .gltf_file import GltfError, read

    try:
        return read(path, files.read if files is not None else None)
    except GltfError as e:
        raise UserError(path, None, str(e)) from None
    except MemoryError:
        raise
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise UserError(path, None, f"cannot read glTF: {e}") from None


def _check_images(path: Path, header: dict) -> None:
    from .gltf_file import inside

    for i, image in enumerate(header.get("images", [])):
        uri = image.get("uri") if isinstance(image, dict) else None
        if uri and not uri.startswith("data:") and inside(path.parent, uri) is None:
            raise UserError(path, f"images[{i}]", f"uri {uri!r} leaves the file's folder (refused)")


def _primitive_names(header: dict) -> dict[tuple[int, int], str]:
    """(mesh, primitive) -> the name trimesh gives its geometry (trimesh.exchange.gltf
    names each primitive after its mesh, made unique in file order)."""
    from trimesh.util import unique_name

    names: dict[tuple[int, int], str] = {}
    taken: dict[str, int] = {}
    counts: dict = {}
    for mi, mesh in enumerate(header.get("meshes", [])):
        for pi, prim in enumerate(mesh.get("primitives", [])):
            name = unique_name(mesh.get("name", "GLTF"), taken, counts=counts)
            if prim.get("mode", 4) in (0, 1, 4, 5):
                taken[name] = 1
                names[(mi, pi)] = name
    return names


def _default_weights(header: dict, mi: int, n: int, facts: Facts) -> tuple[float, ...]:
    """A mesh's default morph weights: its nodes' own when they agree, else the mesh's."""
    mesh = header["meshes"][mi]
    own = {tuple(node["weights"]) for node in header.get("nodes", []) if node.get("mesh") == mi and "weights" in node}
    if len(own) > 1:
        facts.warnings["morph_weights"] = (f"mesh {mesh.get('name', mi)!r}: its instances set different morph "
                                           "weights; the mesh's defaults are used for all")
    weights = next(iter(own)) if len(own) == 1 else tuple(mesh.get("weights", ()))
    if len(weights) != n:
        weights = (0.0,) * n
    return tuple(float(w) for w in weights)


def _morphs(path: Path, gltf, facts: Facts) -> None:
    header = gltf.header
    names = _primitive_names(header)
    for (mi, pi), geom_name in names.items():
        mesh = header["meshes"][mi]
        prim = mesh["primitives"][pi]
        targets = [t for t in prim.get("targets", []) if isinstance(t, dict)]
        if not targets or not all("POSITION" in t for t in targets):
            continue
        label = mesh.get("name") or f"mesh{mi}"
        given = (mesh.get("extras") or {}).get("targetNames") if isinstance(mesh.get("extras"), dict) else None
        key_names = [str(n) for n in given] if isinstance(given, list) and len(given) == len(targets) else \
            [f"{label}_target{k}" for k in range(len(targets))]
        base = gltf.accessor(prim["attributes"]["POSITION"])
        deltas = [gltf.accessor(t["POSITION"]) for t in targets]
        if any(d.shape != base.shape for d in deltas):
            raise UserError(path, label, "a morph target's POSITION count differs from the mesh's")
        weights = _default_weights(header, mi, len(targets), facts)
        rest = base + sum((w * d for w, d in zip(weights, deltas)), np.zeros_like(base))
        keys = tuple((_unique(key_names[k], key_names[:k]), base + d) for k, d in enumerate(deltas))
        facts.morphs[geom_name] = Morph(base, rest, keys, weights)
        if any(weights):
            facts.notes.append(f"{label}: morph weights {list(weights)} make its rest mesh")


def _unique(name: str, before: list[str]) -> str:
    while name in before:
        name += "_"
    return name


def _decodable(path: Path, header: dict) -> None:
    """Refuses meshes compressed only in a way trimesh cannot decode here: it would
    read their placeholder zeros as the geometry."""
    import importlib.util

    lacking = {"EXT_meshopt_compression"}
    if importlib.util.find_spec("DracoPy") is None:
        lacking.add("KHR_draco_mesh_compression")
    needed = sorted(lacking & set(header.get("extensionsRequired", [])))
    if needed:
        raise UserError(path, None, f"its meshes need {', '.join(needed)} to be decoded, which this reader "
                                    "lacks: export the file without mesh compression")


def _image_users(header: dict) -> dict[int, list[str]]:
    """image index -> the names of the materials sampling it."""
    users: dict[int, list[str]] = {}
    textures = header.get("textures", [])

    def walk(node, material: str) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                if key.endswith("Texture") and isinstance(value, dict) and isinstance(value.get("index"), int) \
                        and 0 <= value["index"] < len(textures) and isinstance(textures[value["index"]], dict):
                    texture = textures[value["index"]]
                    sources = [texture.get("source")] + [e.get("source") for e in texture.get("extensions", {}).values()
                                                         if isinstance(e, dict)]
                    for source in sources:
                        if isinstance(source, int) and material not in users.setdefault(source, []):
                            users[source].append(material)
                walk(value, material)
        elif isinstance(node, list):
            for value in node:
                walk(value, material)

    for i, mat in enumerate(header.get("materials", [])):
        walk(mat, str(mat.get("name") or f"materials[{i}]") if isinstance(mat, dict) else f"materials[{i}]")
    return users


def _for_trimesh(gltf, files: SourceFiles, facts: Facts) -> None:
    """The glTF as trimesh reads it: its buffers and embedded images served by `files`
    under names of their own (so each image passes its caps there), its external
    images by the names they have."""
    import copy

    header = copy.deepcopy(gltf.header)
    for i, buffer in enumerate(header.get("buffers", [])):
        files.served[f"buffer-{i}.bin"] = gltf.buffers[i]
        buffer["uri"] = f"buffer-{i}.bin"
    users = _image_users(header)
    for i, image in enumerate(header.get("images", [])):
        if not isinstance(image, dict):
            continue
        label = image.get("name") or f"images[{i}]"
        uri = image.get("uri")
        if isinstance(uri, str) and not uri.startswith("data:"):
            facts.names[uri] = (f"{label} ({uri})" if image.get("name") else uri, tuple(users.get(i, ())))
            continue
        name = f"image-{i}.img"
        try:
            if "bufferView" in image:
                view = header["bufferViews"][image.pop("bufferView")]
                start = int(view.get("byteOffset", 0))
                files.served[name] = gltf.buffers[view["buffer"]][start: start + int(view["byteLength"])]
            elif isinstance(uri, str):
                from .gltf_file import _data_uri

                files.served[name] = _data_uri(uri)
        except (KeyError, IndexError, TypeError, ValueError):
            continue  # trimesh finds nothing under the name: said below as not found
        image["uri"] = name
        facts.names[name] = (f"{label} ({'data: URI' if uri else 'in the binary buffer'})", tuple(users.get(i, ())))
    facts.trimesh_file = json.dumps(header).encode()


def gltf_facts(path: Path, files: SourceFiles | None = None) -> Facts:
    """Metres, Y up; the morph targets; the animations and skins trimesh leaves out."""
    gltf = _gltf_header(path, files)
    header = gltf.header
    _decodable(path, header)
    _check_images(path, header)
    facts = Facts(metres=None, up=None, default_up="Y")
    if files is not None:
        _for_trimesh(gltf, files, facts)
    _morphs(path, gltf, facts)
    animations = header.get("animations", [])
    if animations:
        facts.warnings["animation"] = (f"{len(animations)} glTF animations are not carried: the model is read "
                                       "as it stands (morph targets at their default weights)")
    skins = header.get("skins", [])
    if skins:
        facts.warnings["armature"] = (f"{len(skins)} glTF skins are not carried: skinned meshes are read in "
                                      "their bind pose")
    return facts


def obj_facts(path: Path, files: SourceFiles | None = None) -> Facts:
    """Refuses material libraries (and the images they name) outside the folder; the
    materials each image serves."""
    from .gltf_file import inside

    folder = path.parent
    facts = Facts()
    with open(path, "rb") as fh:
        for line in fh:
            if line.startswith(b"mtllib"):
                for name in line[6:].decode("utf-8", "replace").split():
                    lib = inside(folder, name)
                    if lib is None:
                        raise UserError(path, "mtllib", f"{name!r} leaves the file's folder (refused)")
                    facts.names[name] = (f"material library {name}", ())
                    if lib.is_file():
                        _check_mtl(lib, folder, facts)
    return facts


def _check_mtl(mtl: Path, folder: Path, facts: Facts) -> None:
    from .gltf_file import inside

    material = "?"
    for line in mtl.read_bytes().decode("utf-8", "replace").splitlines():
        words = line.split()
        if words and words[0].lower() == "newmtl":
            material = " ".join(words[1:])
        if words and (words[0].lower().startswith("map_") or words[0].lower() in ("bump", "disp", "decal", "refl")):
            name = words[-1]
            if inside(folder, name) is None:
                raise UserError(mtl, words[0], f"{name!r} leaves the file's folder (refused)")
            # trimesh asks for the rest of the line after map_Kd
            asked = line[line.lower().index(words[0].lower()) + len(words[0]):].strip()
            label, users = facts.names.get(asked, (asked, ()))
            facts.names[asked] = (label, tuple(sorted({*users, material})))


FACTS = {".dae": collada_facts, ".gltf": gltf_facts, ".glb": gltf_facts, ".obj": obj_facts}


# --- trimesh's scene to ir ---------------------------------------------------------------


def _geometries(loaded) -> list[tuple[str, str, object, np.ndarray]]:
    """(node name, geometry name, Trimesh in its own coordinates, (4, 4) node
    transform) for every triangle geometry of the scene, sorted by node."""
    import trimesh

    if isinstance(loaded, trimesh.Trimesh):
        return [("mesh", "mesh", loaded, np.eye(4))]
    if isinstance(loaded, trimesh.Scene):
        out = []
        for node in sorted(loaded.graph.nodes_geometry):
            transform, geom_name = loaded.graph[node]
            geom = loaded.geometry[geom_name]
            if isinstance(geom, trimesh.Trimesh):
                out.append((str(node), str(geom_name), geom, np.asarray(transform, dtype=np.float64)))
        return out
    return []


def _mesh(path: Path, name: str, geom, matrix: np.ndarray, morph: Morph | None) -> ir.Mesh:
    faces = np.asarray(geom.faces, dtype=np.int64)
    vertices = np.asarray(geom.vertices, dtype=np.float64)
    keys: tuple[ir.ShapeKey, ...] = ()
    if morph is not None and morph.base.shape == vertices.shape and np.allclose(morph.base, vertices, atol=1e-6):
        vertices = morph.rest
        keys = tuple(ir.ShapeKey(k, apply_transform(p, faces, matrix)[0]) for k, p in morph.keys)
    if not np.isfinite(vertices).all() or any(not np.isfinite(k.vertices).all() for k in keys):
        raise UserError(path, name, "non-finite (NaN or infinite) vertex coordinates")
    with np.errstate(over="ignore", invalid="ignore"):
        v, f = apply_transform(vertices, faces, matrix)  # mirrored nodes keep outward faces
    if not np.isfinite(v).all() or any(not np.isfinite(k.vertices).all() for k in keys):
        raise UserError(path, name, "coordinates overflow once the units, scale and node transforms apply")
    return ir.Mesh(v, f, uvs=trimesh_uvs(geom), shape_keys=keys)


def asset_from_trimesh(loaded, cfg, path: Path, frame: Frame, metadata: tuple[tuple[str, str], ...] = (),
                       facts: Facts | None = None) -> ir.Asset:
    """An ir.Asset from a trimesh Trimesh/Scene (shared with the CAD reader): each
    geometry through its node transform, then `frame` (file -> model metres, Z up)."""
    facts = facts or Facts()
    visuals, materials, seen, carried = [], {}, set(), set()
    for node, geom_name, geom, transform in _geometries(loaded):
        vis_name = _safe_name(node, "mesh")
        if vis_name[0].isdigit():  # OpenCASCADE numbers unnamed STEP solids
            vis_name = f"part_{vis_name}"
        while vis_name in seen:
            vis_name += "_"
        seen.add(vis_name)
        if len(geom.faces) == 0:
            continue
        morph = facts.morphs.get(geom_name)
        mesh = _mesh(path, vis_name, geom, frame.matrix() @ transform, morph)
        if mesh.shape_keys:
            carried.add(geom_name)
        mat = _material(geom, f"{vis_name}_material", (1.0,) * 4 if path.suffix.lower() in (".gltf", ".glb")
                        else (0.8, 0.8, 0.8, 1.0))
        if mat.name not in materials:
            textures = trimesh_textures(getattr(getattr(geom, "visual", None), "material", None),
                                        _TEXTURE_SLOTS.get(path.suffix.lower(), ir.TEXTURE_SLOTS))
            if textures and mesh.uvs is None:
                facts.warnings["textures"] = f"{vis_name}: a texture without texture coordinates is not carried"
                textures = {}
            materials[mat.name] = with_textures(mat, textures)
        visuals.append(ir.Visual(vis_name, mat.name, (mesh,)))
    if not visuals:
        left = facts.warnings.get("controller")
        raise UserError(path, None, "no triangles in the file" + (f" ({left})" if left else ""))
    lost = sorted(set(facts.morphs) - carried)
    if lost:
        facts.warnings["morph_targets"] = f"morph targets of {', '.join(lost)} are not carried (their mesh was not read as stored)"
    notes = (("notes", "; ".join(sorted(facts.notes))),) if facts.notes else ()
    warnings = tuple((f"warning.{k}", facts.warnings[k]) for k in sorted(facts.warnings))
    return ir.Asset(
        id=cfg.id, category=cfg.category, description=getattr(cfg, "description", ""),
        links=(ir.Link("base", visuals=tuple(visuals)),),
        materials=tuple(materials[k] for k in sorted(materials)),
        source=str(path), metadata=(*metadata, *notes, *warnings),
    )


@contextlib.contextmanager
def _quiet_trimesh():
    """trimesh logs a traceback for each texture it cannot find; the readers report
    what they cannot carry themselves."""
    import warnings

    logger = logging.getLogger("trimesh")  # its modules log through children of it
    before = logger.level
    logger.setLevel(logging.CRITICAL + 1)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logger.setLevel(before)


def _load(path: Path, file_type: str | None = None, files: SourceFiles | None = None, text: bytes | None = None):
    """trimesh's reading of `path` (or of `text` in its stead), every other file through
    `files` (default: the file's folder)."""
    import io

    import trimesh

    files = files if files is not None else SourceFiles(path)
    try:
        with _quiet_trimesh():
            # process=False: no silent merging; cleaning is the geometry step's job
            if text is not None:
                return trimesh.load(io.BytesIO(text), file_type=file_type, process=False, resolver=files)
            return trimesh.load(str(path), file_type=file_type, process=False, resolver=files)
    except (UserError, MemoryError):
        raise
    except Exception as e:  # trimesh raises many types for corrupt files
        raise UserError(path, None, f"cannot read mesh file: {type(e).__name__}: {e}") from None


# COLLADA has no normal, metallic-roughness or occlusion map of its own: what trimesh
# (through pycollada's bump-map search) offers as a normal map can be an exporter's
# specular level (3ds Max's <extra>), so only the diffuse and emission images are taken.
_TEXTURE_SLOTS = {".dae": ("base_color", "emissive")}


def read_mesh(cfg) -> ir.Asset:
    """Read cfg.source (.stl/.obj/.ply/.glb/.gltf/.dae) into an ir.Asset in metres, Z up."""
    path = Path(cfg.source)
    check_size(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise UserError(path, None, f"unsupported mesh format {suffix!r}")
    files = SourceFiles(path)
    facts = FACTS.get(suffix, lambda p, f: Facts())(path, files)
    loaded = _load(path, "gltf" if facts.trimesh_file is not None else suffix[1:], files, facts.trimesh_file)
    _not_read(path, files, facts)
    frame = resolve(cfg, facts.metres, facts.up, facts.default_up)
    opened = (("opened", json.dumps(files.opened, sort_keys=True)),) if files.opened else ()
    return asset_from_trimesh(loaded, cfg, path, frame, (*frame.metadata(), *opened), facts)


def _not_read(path: Path, files: SourceFiles, facts: Facts) -> None:
    """A warning for each file the source names that was not read (not found, refused,
    over a cap), naming the materials that use it and its path as written."""
    for name, why in sorted(files.problems.items()):
        label, users = facts.names.get(name, (name, ()))
        who = f"material {', '.join(map(repr, users))}: " if users else ""
        if label.startswith("material library"):
            facts.warnings[f"not_read.{label}"] = f"{path.name}: {label}: {why}; its materials are not carried"
            continue
        what = "image" if is_image_name(name) else "file"
        facts.warnings[f"not_read.{label}"] = f"{path.name}: {who}{what} {label!r}: {why}; not carried"
