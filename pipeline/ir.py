"""The neutral asset model every reader produces and every writer consumes.

Plain frozen dataclasses and numpy arrays, nothing else. Conventions (DESIGN.md s.3):
metres, radians, right-handed, Z up, float64. Poses are 4x4 float64 homogeneous
matrices. Frames:

- model frame: the asset's origin (foundation centre at ground level);
- link frame: `Link.pose` in the model frame; a child link's frame is its joint's pivot;
- visual/collision frame: `Visual.pose` in its link's frame; mesh vertices live there.

Nothing here does I/O; arrays are never mutated after construction.
"""

from __future__ import annotations

import hashlib

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Literal

import numpy as np

JointType = Literal["revolute", "prismatic", "continuous", "fixed"]
StateEffect = Literal["rotate", "translate", "scale", "shape", "material"]

IDENTITY = np.eye(4)


def _frozen_array(a, dtype, shape_tail: tuple[int, ...] | None = None) -> np.ndarray:
    arr = np.array(a, dtype=dtype, copy=True)
    if shape_tail is not None and (arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail):
        if not (arr.size == 0):
            raise ValueError(f"expected shape (n, {', '.join(map(str, shape_tail))}), got {arr.shape}")
        arr = arr.reshape((0, *shape_tail))
    arr.setflags(write=False)
    return arr


def pose(matrix=None) -> np.ndarray:
    """A read-only 4x4 float64 copy of `matrix` (identity when None)."""
    m = np.eye(4) if matrix is None else np.array(matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise ValueError(f"a pose is a 4x4 matrix, got {m.shape}")
    m.setflags(write=False)
    return m


@dataclass(frozen=True, eq=False)
class ShapeKey:
    """A mesh variant: absolute vertex positions of the same topology.

    vertices: (n, 3) float64, same n as the base mesh.
    """

    name: str
    vertices: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "vertices", _frozen_array(self.vertices, np.float64, (3,)))


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh in its owner's frame.

    vertices: (n, 3) float64
    faces:    (m, 3) int32, counter-clockwise seen from outside
    normals:  (n, 3) float64 unit vectors, or None (writers compute smooth normals)
    uvs:      (n, 2) float64, or None
    shape_keys: mesh variants with the same topology (morph targets / blend shapes)
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None
    shape_keys: tuple[ShapeKey, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "vertices", _frozen_array(self.vertices, np.float64, (3,)))
        object.__setattr__(self, "faces", _frozen_array(self.faces, np.int32, (3,)))
        if self.normals is not None:
            object.__setattr__(self, "normals", _frozen_array(self.normals, np.float64, (3,)))
        if self.uvs is not None:
            object.__setattr__(self, "uvs", _frozen_array(self.uvs, np.float64, (2,)))
        object.__setattr__(self, "shape_keys", tuple(self.shape_keys))

    @property
    def triangle_count(self) -> int:
        return int(len(self.faces))

    @cached_property
    def digest(self) -> str:
        """sha256 of everything the mesh holds (its arrays never change), shape keys'
        names included: the one key by which the memos know a mesh (checks' findings,
        COLLADA documents)."""
        from .digest import sha256_arrays

        names = np.array([k.name for k in self.shape_keys], dtype=str)
        return sha256_arrays(self.vertices, self.faces, self.normals, self.uvs, names,
                             *(k.vertices for k in self.shape_keys))

    def bounds(self) -> np.ndarray:
        """(2, 3) float64: min and max corner; zeros for an empty mesh."""
        if len(self.vertices) == 0:
            return np.zeros((2, 3))
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])


@dataclass(frozen=True)
class Phong:
    """Classic fixed-function parameters (SDF <ambient>/<diffuse>/..., COLLADA <phong>)."""

    ambient: tuple[float, float, float, float]
    diffuse: tuple[float, float, float, float]
    specular: tuple[float, float, float, float]
    emissive: tuple[float, float, float, float]
    shininess: float


TEXTURE_SLOTS = ("base_color", "normal", "metallic_roughness", "occlusion", "emissive")
_IMAGE_MIME = {b"\x89PNG\r\n\x1a\n": ("image/png", ".png"), b"\xff\xd8\xff": ("image/jpeg", ".jpg")}


@dataclass(frozen=True)
class Texture:
    """An image a material samples with its mesh's UVs (set 0, origin bottom-left as in
    Blender and COLLADA; the glTF writer flips V).

    name: a file-name stem, unique within the asset; data: the PNG or JPEG bytes as
    found in the source (never re-encoded, so every output carries the same image).
    metallic_roughness follows glTF: roughness in G, metalness in B.
    """

    name: str
    data: bytes

    @property
    def mime(self) -> str:
        return self._kind()[0]

    @property
    def suffix(self) -> str:
        return self._kind()[1]

    @cached_property
    def digest(self) -> str:
        return hashlib.sha256(self.data).hexdigest()

    def _kind(self) -> tuple[str, str]:
        for magic, kind in _IMAGE_MIME.items():
            if self.data.startswith(magic):
                return kind
        raise ValueError(f"texture {self.name!r} is neither PNG nor JPEG")

    def __repr__(self) -> str:
        return f"Texture({self.name!r}, {len(self.data)} bytes, sha256 {self.digest[:12]})"


@dataclass(frozen=True)
class Material:
    """A Principled-BSDF / glTF metallic-roughness material. Colours are linear RGB.

    base_color: (r, g, b, a) in 0..1, a is the opacity
    emission:   (r, g, b) radiance colour already multiplied by its strength
    """

    name: str
    base_color: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0)
    metallic: float = 0.0
    roughness: float = 0.5
    emission: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # image maps (TEXTURE_SLOTS), each multiplied by the factor above as in glTF
    base_color_texture: Texture | None = None
    normal_texture: Texture | None = None
    metallic_roughness_texture: Texture | None = None
    occlusion_texture: Texture | None = None
    emissive_texture: Texture | None = None

    def textures(self) -> dict[str, Texture]:
        """slot -> texture, for the slots this material fills."""
        return {slot: t for slot in TEXTURE_SLOTS if (t := getattr(self, f"{slot}_texture")) is not None}

    def key(self) -> dict:
        """Everything the material is, as JSON-able data (textures by name and hash)."""
        data = {k: getattr(self, k) for k in ("name", "base_color", "metallic", "roughness", "emission")}
        data["textures"] = {slot: [t.name, t.digest] for slot, t in self.textures().items()}
        return data

    @property
    def alpha(self) -> float:
        return float(self.base_color[3])

    def phong(self) -> Phong:
        """The COLLADA <phong> effect: what Gazebo 11 (OGRE 1, fixed function) lights a
        mesh with when the SDF visual says nothing, and gz-sim copies (metalness 0).
        As sdf_phong, but a metal's highlight takes its base colour (classic Phong has
        no Fresnel to tint it). Opacity is the writer's <transparency>, not an alpha."""
        return self._gazebo(tinted_specular=True)

    def sdf_phong(self) -> Phong:
        """The SDF <material> colours, which both Gazebo generations read beside
        <pbr><metal> (metalness, roughness):

        - diffuse = base colour, alpha 1. gz-rendering's Ogre2Material::SetDiffuse is the
          PBS albedo, and Ogre's metallic workflow takes F0 = lerp(0.03, albedo,
          metalness): a black diffuse renders a metal black. Opacity comes from the
          visual's <transparency> alone (Ogre2Material multiplies it by diffuse alpha:
          an alpha here too would square it).
        - specular = lerp(0.5 (1 - roughness)^2, 1, metallic), grey. Ogre2 multiplies
          every reflection by it (kS): 1 for metals keeps their reflections whole; less
          for rough dielectrics. Gazebo 11 adds it as a Phong highlight of exponent
          `shininess` (its COLLADA effect's, the SDF has none), untinted.
        - ambient = base colour (Gazebo 11 multiplies it by the scene's ambient light;
          ogre2 ignores it); emissive = the emission, clipped to 0..1.
        """
        return self._gazebo(tinted_specular=False)

    def _gazebo(self, tinted_specular: bool) -> Phong:
        r, g, b, a = self.base_color
        m = float(np.clip(self.metallic, 0.0, 1.0))
        rough = float(np.clip(self.roughness, 0.02, 1.0))
        # a dielectric's highlight fades as it roughens; shininess is the Blinn-Phong
        # exponent that matches GGX at alpha = roughness^2
        dielectric = 0.5 * (1.0 - rough) ** 2
        top = (r, g, b) if tinted_specular else (1.0, 1.0, 1.0)
        spec = tuple(float(dielectric * (1.0 - m) + c * m) for c in top)
        shininess = float(np.clip(2.0 / rough**4 - 2.0, 1.0, 128.0))
        e = tuple(float(np.clip(c, 0.0, 1.0)) for c in self.emission)
        colour = tuple(float(c) for c in (r, g, b))
        return Phong(
            ambient=(*colour, float(a)),
            diffuse=(*colour, 1.0),
            specular=(*spec, 1.0),
            emissive=(*e, 1.0),
            shininess=shininess,
        )


@dataclass(frozen=True, eq=False)
class Visual:
    """A visual object of a link: one mesh, one material, its LOD chain.

    pose: (4, 4) float64 in the link frame; vertices are in this visual's frame.
    lods: lods[0] is the authored mesh; further entries are simplified versions with
          the same material. A visual with shape keys or a state binding keeps one LOD.
    """

    name: str
    material: str
    lods: tuple[Mesh, ...]
    pose: np.ndarray = field(default_factory=lambda: pose())

    def __post_init__(self):
        object.__setattr__(self, "pose", pose(self.pose))
        object.__setattr__(self, "lods", tuple(self.lods))
        if not self.lods:
            raise ValueError(f"visual {self.name!r} has no mesh")

    @property
    def mesh(self) -> Mesh:
        return self.lods[0]

    def lod(self, level: int) -> Mesh:
        """The mesh of LOD `level`, or the coarsest one this visual has."""
        return self.lods[min(level, len(self.lods) - 1)]


@dataclass(frozen=True, eq=False)
class Collision:
    """Collision geometry of a link. pose: (4, 4) float64 in the link frame."""

    name: str
    mesh: Mesh
    pose: np.ndarray = field(default_factory=lambda: pose())

    def __post_init__(self):
        object.__setattr__(self, "pose", pose(self.pose))


@dataclass(frozen=True, eq=False)
class Link:
    """A rigid body. pose: (4, 4) float64 of the link frame in the model frame."""

    name: str
    pose: np.ndarray = field(default_factory=lambda: pose())
    visuals: tuple[Visual, ...] = ()
    collisions: tuple[Collision, ...] = ()
    mass: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "pose", pose(self.pose))
        object.__setattr__(self, "visuals", tuple(self.visuals))
        object.__setattr__(self, "collisions", tuple(self.collisions))


@dataclass(frozen=True, eq=False)
class Joint:
    """A joint between two links.

    pose: (4, 4) float64, the pivot frame in the model frame (equals the child link's
          frame as authored).
    axis: (3,) float64 unit vector expressed in the joint (pivot) frame.
    lower, upper: limits in rad (revolute) or m (prismatic); None for continuous/fixed.
    """

    name: str
    type: JointType
    parent: str
    child: str
    pose: np.ndarray = field(default_factory=lambda: pose())
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    lower: float | None = None
    upper: float | None = None
    effort: float | None = None
    velocity: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "pose", pose(self.pose))
        ax = np.array(self.axis, dtype=np.float64).reshape(3)
        ax.setflags(write=False)
        object.__setattr__(self, "axis", ax)


@dataclass(frozen=True)
class StateBinding:
    """A runtime variable driving one visual (DESIGN.md s.2).

    target: the visual's name. axis: (3,) in the visual's frame (rotate/translate).
    domain -> range is a clamped linear map; `material` picks materials[i] where i is
    the number of thresholds <= value (thresholds ascending, len = len(materials) - 1).
    """

    variable: str
    effect: StateEffect
    target: str
    domain: tuple[float, float]
    range: tuple[float, float] = (0.0, 1.0)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    shape_key: str | None = None
    materials: tuple[str, ...] = ()
    thresholds: tuple[float, ...] = ()

    def output(self, value: float) -> float | int:
        """The binding's mapping M_k of a state value: angle, distance, factor,
        shape-key weight, or (for `material`) an index into `materials`."""
        if self.effect == "material":
            return int(np.searchsorted(np.asarray(self.thresholds, dtype=np.float64), value, side="right"))
        d0, d1 = self.domain
        r0, r1 = self.range
        t = 0.0 if d1 == d0 else (float(value) - d0) / (d1 - d0)
        t = min(1.0, max(0.0, t))
        return r0 + t * (r1 - r0)


@dataclass(frozen=True)
class LodInfo:
    """One level of an asset's LOD chain: budget and measured two-sided Hausdorff error."""

    level: int
    budget_m: float
    error_m: float
    triangles: int


@dataclass(frozen=True, eq=False)
class Asset:
    """One piece of equipment: links, joints, materials, state bindings, LODs."""

    id: str
    category: str
    links: tuple[Link, ...]
    joints: tuple[Joint, ...] = ()
    materials: tuple[Material, ...] = ()
    bindings: tuple[StateBinding, ...] = ()
    lods: tuple[LodInfo, ...] = ()
    description: str = ""
    source: str = ""
    metadata: tuple[tuple[str, str], ...] = ()
    # conductor attachment points the source declares (a .blend's `terminal.<name>`
    # empties): (name, (x, y, z) model-frame metres), sorted by name
    terminals: tuple[tuple[str, tuple[float, float, float]], ...] = ()

    def __post_init__(self):
        for name in ("links", "joints", "materials", "bindings", "lods", "metadata"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        object.__setattr__(self, "terminals", tuple((str(n), tuple(float(v) for v in p)) for n, p in self.terminals))

    def material(self, name: str) -> Material:
        for m in self.materials:
            if m.name == name:
                return m
        raise KeyError(name)

    def link(self, name: str) -> Link:
        for link in self.links:
            if link.name == name:
                return link
        raise KeyError(name)

    @property
    def root_link(self) -> Link:
        children = {j.child for j in self.joints}
        roots = [link for link in self.links if link.name not in children]
        if len(roots) != 1:
            raise ValueError(f"asset {self.id!r} has {len(roots)} root links")
        return roots[0]

    def visuals(self):
        """(link, visual) pairs in link order."""
        for link in self.links:
            for v in link.visuals:
                yield link, v

    def textures(self) -> dict[str, Texture]:
        """name -> texture over every material, by name (a reader gives one name one image)."""
        out: dict[str, Texture] = {}
        for m in self.materials:
            for t in m.textures().values():
                if out.setdefault(t.name, t).digest != t.digest:
                    raise ValueError(f"two different images named {t.name!r}")
        return dict(sorted(out.items()))

    def triangle_count(self, lod: int = 0) -> int:
        return sum(v.lod(lod).triangle_count for _, v in self.visuals())

    @property
    def lod_count(self) -> int:
        return max((len(v.lods) for _, v in self.visuals()), default=1)

    def with_(self, **changes) -> "Asset":
        return replace(self, **changes)


@dataclass(frozen=True)
class Placement:
    """One placed INSERT of the floor plan (at the end of a chain of nested INSERTs).

    position: (x, y) drawing metres in the plant grid, where the INSERT chain takes the
    block's origin; z: height above its level, metres (the drawing's unit only:
    grid_scale is the projection's horizontal factor and applies to x and y in georef).
    heading_deg: direction of the block's x axis, counter-clockwise in the plant grid.
    handle: the placed INSERT's; dxf_handles: the chain from the modelspace INSERT to it.
    scale: the model's scale factor (1 unless [floorplan] insert_scale = "apply").
    """

    tag: str
    asset_id: str
    level: str
    x: float
    y: float
    z: float = 0.0
    heading_deg: float = 0.0
    state: str | None = None
    handle: str = ""
    dxf_handles: tuple[str, ...] = ()
    scale: float = 1.0


@dataclass(frozen=True, eq=False)
class Platform:
    """A terrace outline. outline: (k, 2) float64 plant-grid metres, not closed."""

    level: str
    outline: np.ndarray
    handle: str = ""

    def __post_init__(self):
        object.__setattr__(self, "outline", _frozen_array(self.outline, np.float64, (2,)))


@dataclass(frozen=True)
class FloorPlan:
    """What a floor plan holds: placements, platforms, and what was ignored.

    inserts: (block name, count) of every INSERT met, nested ones included;
    warnings: what the reader has to say about the drawing (blocks left out, no
    platforms, no placements, scaled INSERTs placed at scale 1), one message each;
    absorbed: (mapped block name, count) of the INSERTs nested, at any depth, in the
    placed INSERTs of each mapped block (its model stands for them).
    """

    path: str
    units: str
    placements: tuple[Placement, ...]
    platforms: tuple[Platform, ...]
    ignored: tuple[tuple[str, int], ...] = ()
    inserts: tuple[tuple[str, int], ...] = ()
    warnings: tuple[str, ...] = ()
    # LINEs and LWPOLYLINEs of the conductor layers: (handle, layer upper case,
    # plan vertices in metres ((x, y), ...)), in drawing order
    conductor_lines: tuple[tuple[str, str, tuple[tuple[float, float], ...]], ...] = ()
    absorbed: tuple[tuple[str, int], ...] = ()
