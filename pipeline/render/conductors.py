"""The conductors in the Cycles scene: every span of build/scene/conductors.json a tube
mesh of its own (one object per span, its subconductors merged) at the frame's
conductor temperature, in a weathered aluminium material.

The spans' polylines are worked out here without bpy (`Wires`), so that the dataset's
labels (datasets/wire_labels.py) rasterize exactly the curves the renderer draws. A
span is drawn at its finest LOD: the build chooses LODs for viewers at the inspection
points, while a dataset's camera may stand anywhere. A tube of the true diameter is
enough for a sub-pixel wire: Cycles samples each pixel's area, so a 30 mm conductor at
100 m (a fifth of a pixel at 640 px over 60 degrees) darkens or brightens its pixels
in proportion to the share it covers, as a camera's photosites would.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..geometry import catenary as cat
from ..geometry.wires import tube
from ..runtime.apply_conductors import span_paths

TUBE_SIDES = 8  # smooth-shaded: round at any size a camera sees it
RENDER_LOD = 0  # the finest
# weathered stranded aluminium: a dull grey, darker and rougher where it has oxidised more
BRIGHT = (0.55, 0.56, 0.56, 1.0)
OXIDISED = (0.34, 0.35, 0.35, 1.0)
METALLIC = 0.75
ROUGHNESS = (0.75, 0.45)  # at noise 0 (oxidised) and 1 (bright)
NOISE_SCALE = 0.8  # per metre: patches of a metre or so along a span


@dataclass
class Wires:
    """conductors.json as the renderer reads it: the spans (sorted by id) and their types."""

    path: Path
    spans: list[dict]
    types: dict[str, dict]
    _paths: dict = field(default_factory=dict, repr=False)  # temperature -> paths (the last one)

    def __post_init__(self):
        self._by_id = {s["id"]: s for s in self.spans}

    def span(self, sid: str) -> dict:
        return self._by_id[sid]

    def radius(self, span: dict) -> float:
        return float(self.types[span["type"]]["diameter_m"]) / 2.0

    def paths(self, temperature_c: float | dict | None = None) -> dict[str, list[np.ndarray]]:
        """span id -> its subconductors' polylines, each (n, 3) float64 ENU, at
        `temperature_c`: one for every span, or per conductor type (a type missing or
        None: as built); None: each span at the temperature conductors.json gives it.
        The last temperature's are kept: a run's frames mostly share one."""
        key = temperature_key(temperature_c)
        if key not in self._paths:
            out = {}
            for s in self.spans:
                temp = _span_temperature(s, key)
                try:
                    rel, _ = span_paths({**s, "lod": RENDER_LOD}, self.types, temp)
                except (cat.CatenaryError, ValueError) as e:
                    raise UserError(self.path, s["id"], f"no shape at {temp:g} deg C: {e}") from None
                p0 = np.asarray(s["from"]["enu"], float)
                out[s["id"]] = [p + p0 for p in rel]
            self._paths = {key: out}
        return self._paths[key]


def temperature_key(temperature_c: float | dict | None):
    """A shot's conductor temperature as a hashable key: None, a float, or sorted
    (type, temperature) pairs."""
    if temperature_c is None:
        return None
    if isinstance(temperature_c, dict):
        return tuple(sorted((k, None if v is None else float(v)) for k, v in temperature_c.items()))
    return float(temperature_c)


def _span_temperature(span: dict, key) -> float:
    if isinstance(key, tuple):
        key = dict(key).get(span["type"])
    return float(span["temperature_c"] if key is None else key)


def load(build: Path) -> Wires | None:
    """The build's conductors (scene/conductors.json), or None when it has no span."""
    path = Path(build) / "scene" / "conductors.json"
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
        spans = sorted(data["spans"], key=lambda s: s["id"])
        types = data["types"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise UserError(path, None, f"not a conductors record ({type(e).__name__}: {e}): rebuild the scene") from None
    if not spans:
        return None
    need = ("id", "type", "from", "to", "tension_n", "weight_n_per_m", "temperature_c", "lods")
    for s in spans:
        missing = [k for k in need if k not in s]
        if missing or s["type"] not in types:
            what = f"missing {', '.join(missing)}" if missing else f"type {s['type']!r} is not in its types"
            raise UserError(path, s.get("id", "a span"), f"{what}: rebuild the scene")
    return Wires(path, spans, types)


# --- bpy ------------------------------------------------------------------------------


class CyclesWires:
    """The spans as Blender objects in `collection`, one per span named
    `conductor:<span id>`, vertices relative to the span's first end."""

    def __init__(self, bpy, collection, wires: Wires):
        self.bpy, self.wires = bpy, wires
        self.temperature = None  # temperature_key of the shape drawn
        self.objects: dict[str, object] = {}
        # Appending a material to a mesh looks through every object in the file (to
        # give each user of the mesh its slot): done once, to the empty mesh each span's
        # mesh is a copy of.
        template = bpy.data.meshes.new("conductor")
        template.materials.append(_material(bpy))
        for sid, paths in wires.paths(None).items():
            span = wires.span(sid)
            origin = np.asarray(span["from"]["enu"], float)
            verts, faces = _tubes(paths, wires.radius(span), origin)
            mesh = template.copy()
            mesh.name = f"conductor:{sid}"
            _fill_triangles(mesh, verts, faces)
            mesh.shade_smooth()
            ob = bpy.data.objects.new(f"conductor:{sid}", mesh)
            ob.location = origin.tolist()
            collection.objects.link(ob)
            self.objects[sid] = ob
        bpy.data.meshes.remove(template)

    def follow(self, temperature_c: float | dict | None) -> None:
        """Every span's shape at `temperature_c` (Wires.paths); the vertex count does
        not change, only the coordinates."""
        key = temperature_key(temperature_c)
        if key == self.temperature:
            return
        for sid, paths in self.wires.paths(temperature_c).items():
            ob = self.objects[sid]
            verts, _ = _tubes(paths, self.wires.radius(self.wires.span(sid)), np.array(ob.location, float))
            ob.data.vertices.foreach_set("co", verts.astype(np.float32).ravel())
            ob.data.update()
        self.temperature = key

    def set_instances(self, ids: dict[str, int]) -> None:
        """Each span's object carries its instance id (Cycles' object index)."""
        for sid, ob in self.objects.items():
            ob.pass_index = ids.get(sid, 0)


def _fill_triangles(mesh, verts: np.ndarray, faces: np.ndarray) -> None:
    """An empty Blender mesh given triangles: the steps of Mesh.from_pydata, fed from
    the arrays without its Python list of every coordinate."""
    mesh.vertices.add(len(verts))
    mesh.loops.add(3 * len(faces))
    mesh.polygons.add(len(faces))
    mesh.vertices.foreach_set("co", np.ascontiguousarray(verts, np.float32).ravel())
    mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * len(faces), 3, dtype=np.int32))
    mesh.polygons.foreach_set("vertices", np.ascontiguousarray(faces, np.int32).ravel())
    mesh.update(calc_edges=True)


def _tubes(paths: list[np.ndarray], radius: float, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) relative to `origin` and faces (m, 3) of the subconductors' tubes."""
    verts, faces, base = [], [], 0
    for p in paths:
        v, f, _ = tube(p - origin, radius, TUBE_SIDES)
        verts.append(v)
        faces.append(f + base)
        base += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def _material(bpy):
    """Weathered aluminium: a Principled BSDF whose shade and roughness wander with a
    noise over object space, between bright and oxidised strands."""
    mat = bpy.data.materials.new("conductor_weathered_aluminium")
    mat["twin_look"] = 1  # weathered already: a dataset's appearance (render/appearance.py) leaves it be
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = next(n for n in nt.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.distribution = "GGX"  # as every imported material (cycles._tune_material)
    bsdf.inputs["Metallic"].default_value = METALLIC
    coords, noise = nt.nodes.new("ShaderNodeTexCoord"), nt.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = NOISE_SCALE
    nt.links.new(coords.outputs["Object"], noise.inputs["Vector"])
    shade = nt.nodes.new("ShaderNodeMix")
    shade.data_type = "RGBA"
    shade.inputs["A"].default_value = OXIDISED
    shade.inputs["B"].default_value = BRIGHT
    nt.links.new(noise.outputs["Fac"], shade.inputs["Factor"])
    nt.links.new(shade.outputs["Result"], bsdf.inputs["Base Color"])
    rough = nt.nodes.new("ShaderNodeMapRange")  # oxidised (low noise) is the rougher
    rough.inputs["To Min"].default_value, rough.inputs["To Max"].default_value = ROUGHNESS
    nt.links.new(noise.outputs["Fac"], rough.inputs["Value"])
    nt.links.new(rough.outputs["Result"], bsdf.inputs["Roughness"])
    return mat
