"""The Cycles scene (bpy): built packages imported through Blender's glTF importer,
the sky, sun, moon and floodlights, and the camera; one frame at a time.

bpy is imported only when a scene is made: the rest of the renderer runs without it.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .. import glb as glb_file, sun as sun_model
from ..perception.gauge import POINTER
from ..geometry import rays
from ..geometry.pinhole import look_at, project
from .sensor import PhoneCamera
from . import conductors
from ..runtime.site import Shot, BuiltSite

# a see-through object's part code in the label pass: SEE_THROUGH x its part + the part behind it
SEE_THROUGH = 256


class CyclesScene:
    """One Cycles scene: imported packages, lights, camera. Packages are imported once
    per asset; more placements of it share its meshes (linked copies), except meshes with
    shape keys, which are per instance (their weights are)."""

    SKY_SCALE = 7.0  # Blender's sky texture -> W/m2/sr (clear-sky DHI ~120 W/m2 at 60 deg)
    NIGHT_AMBIENT = 2e-4  # W/m2/sr: airglow and light pollution
    MOON = {"elevation": math.radians(50.0), "azimuth": math.radians(80.0), "irradiance": 2.5e-3}
    LAMP_W = 5000.0  # W (radiant) per floodlight head, spot 70 degrees
    THREADS = 2

    def __init__(self, site: BuiltSite, cam: PhoneCamera, seed: int):
        import bpy

        self.bpy, self.site, self.cam = bpy, site, cam
        self.lamps: list = []
        bpy.ops.wm.read_factory_settings(use_empty=True)
        s = self.scene = bpy.context.scene
        s.render.engine = "CYCLES"
        s.cycles.device = "CPU"
        s.cycles.samples = cam.samples
        s.cycles.seed = int(seed) % (2**31)
        s.cycles.use_animated_seed = False
        s.cycles.use_adaptive_sampling = False
        s.cycles.use_denoising = bool(cam.render_denoise)
        if cam.render_denoise:
            s.cycles.denoiser = "OPENIMAGEDENOISE"
            s.cycles.denoising_quality = cam.render_denoise
            s.cycles.denoising_prefilter = "FAST"  # guides from the first hit: clean enough here
            s.cycles.denoising_input_passes = "RGB_ALBEDO_NORMAL"
            s.cycles.denoising_use_gpu = False  # same pixels on every machine
        # Blender's factory light paths (12 bounces, caustics, light tree) stay: fewer
        # bounces without caustics render a close-up darker than a converged render and
        # save little time. The floodlights are off while the sun is up (set_shot).
        s.render.threads_mode = "FIXED"
        s.render.threads = self.THREADS
        s.render.resolution_x, s.render.resolution_y = cam.width, cam.height
        s.render.resolution_percentage = 100
        # Cycles' persistent data would keep the BVH between frames, but with it a night
        # frame (lamps on, sun off) rendered after a day frame has other pixels than the
        # same frame rendered first: a frame must not depend on its history.
        s.render.use_persistent_data = False
        s.view_settings.view_transform = "Standard"
        s.render.image_settings.file_format = "OPEN_EXR"
        s.render.image_settings.color_depth = "32"
        self.roots: dict[str, object] = {}  # tag -> root object
        self.objects: dict[str, dict[str, object]] = {}  # tag -> visual name -> object
        self.prototypes: dict[str, str] = {}  # asset -> tag imported first
        self._rest: dict[str, dict[str, object]] = {}  # tag -> link -> rest matrix_basis (set_joints)
        # tag -> the collection of its objects, excluded from the view layer while the
        # placement is hidden (show_only)
        self._collections: dict[str, object] = {}
        self._placements = bpy.data.collections.new("placements")  # the placements' collections
        s.collection.children.link(self._placements)
        self._hierarchy: dict[str, list] = {}  # an imported root's name -> it and its descendants, in order
        self.wires: conductors.CyclesWires | None = None  # the spans (load_terrain), always shown
        self._frame_image = None  # the rendered file as Blender reads it (render)
        self._world()
        self._camera()
        self.tmp = Path(tempfile.mkdtemp(prefix="twin_render_"))

    def close(self):
        shutil.rmtree(self.tmp, ignore_errors=True)

    def _world(self):
        bpy = self.bpy
        w = bpy.data.worlds.new("sky")
        self.scene.world = w
        w.use_nodes = True
        w.cycles.sampling_method = "MANUAL"  # the automatic map (1024) is slow to build for each sky
        w.cycles.sample_map_resolution = 64
        nt = w.node_tree
        self.sky = nt.nodes.new("ShaderNodeTexSky")
        self.sky.sky_type = "MULTIPLE_SCATTERING"
        self.sky.sun_disc = False  # the sun lamp lights; the disc would only add noise
        amb = nt.nodes.new("ShaderNodeBackground")
        amb.inputs["Strength"].default_value = self.NIGHT_AMBIENT
        amb.inputs["Color"].default_value = (0.6, 0.7, 1.0, 1.0)
        bg = nt.nodes["Background"]
        nt.links.new(self.sky.outputs["Color"], bg.inputs["Color"])
        add = nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(bg.outputs[0], add.inputs[0])
        nt.links.new(amb.outputs[0], add.inputs[1])
        nt.links.new(add.outputs[0], nt.nodes["World Output"].inputs["Surface"])
        self.sky_bg = bg
        self.sun = self._sun_lamp("sun", 0.0093)  # the sun's angular diameter, rad
        self.moon = self._sun_lamp("moon", 0.009)

    def _sun_lamp(self, name: str, angle: float):
        bpy = self.bpy
        ob = bpy.data.objects.new(name, bpy.data.lights.new(name, "SUN"))
        ob.data.angle = angle
        self.scene.collection.objects.link(ob)
        return ob

    def _camera(self):
        bpy = self.bpy
        self.camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
        self.camera.data.sensor_fit = "HORIZONTAL"
        self.scene.collection.objects.link(self.camera)
        self.scene.camera = self.camera

    # -- content
    def load_many(self, tags) -> None:
        """`load` each tag, the view layer updated once at the end: an update costs time
        in proportion to the scene, so one per placement grows with the square of a
        site's size (imports make none: _operator).

        The first placement of each asset not loaded yet comes first: the imports, then
        the copies of what they made. The glTF importer makes and deletes a temporary
        object for each mesh, and Blender's deletion of an object looks through the whole
        file's data, so an import costs in proportion to what is already loaded.

        A placement's children have stale world matrices until the update: nothing
        reads them before it."""
        tags = list(tags)
        assets = set(self.prototypes)
        imports = []
        for tag in tags:
            asset = self.site.placement(tag)["asset"]
            if asset not in assets:
                assets.add(asset)
                imports.append(tag)
        first = set(imports)
        for tag in imports + [t for t in tags if t not in first]:
            self._load(tag)
        self.bpy.context.view_layer.update()

    def load(self, tag: str) -> None:
        """One placement (load_many)."""
        self.load_many([tag])

    def _placements_layer(self):
        return self.bpy.context.view_layer.layer_collection.children[self._placements.name]

    def _load(self, tag: str) -> None:
        """Import a placement's built package (glTF), or copy the asset's first
        placement, and put it at its ENU pose."""
        if tag in self.roots:
            return
        p = self.site.placement(tag)
        glb = self.site.build / "models" / p["asset"] / f"{p['asset']}.glb"
        collection = self.bpy.data.collections.new(tag)
        self._placements.children.link(collection)
        if p["asset"] in self.prototypes:
            root, objs = self._copy(self.roots[self.prototypes[p["asset"]]], collection)
        else:
            root, objs = self._import(glb, collection)
            self.prototypes[p["asset"]] = tag
        self._collections[tag] = collection
        root.matrix_world = _matrix(self.bpy, self.site.pose(p))
        self.roots[tag], self.objects[tag] = root, objs

    def load_terrain(self) -> None:
        """The site's fixed furniture: the ground and the conductors strung over it."""
        if self.site.terrain and "__terrain__" not in self.roots:
            root, objs = self._import(self.site.build / "models" / self.site.terrain / f"{self.site.terrain}.glb",
                                      self.scene.collection)
            self.roots["__terrain__"], self.objects["__terrain__"] = root, objs
        if self.wires is None:
            wires = conductors.load(self.site.build)
            self.wires = None if wires is None else conductors.CyclesWires(self.bpy, self.scene.collection, wires)

    def _import(self, glb: Path, collection):
        """A package's objects, in `collection` (the glTF importer links them to the
        scene's own collection), and its root."""
        bpy = self.bpy
        before = set(bpy.data.objects)
        # Close-ups draw LOD 0. Blender imports MSFT_lod's out-of-scene nodes as extra
        # roots at the origin, and building their meshes is most of an import: the
        # importer reads a copy without them.
        doc, binary = glb_file.read(glb)
        scene_only = glb_file.scene_nodes_only(doc)
        if scene_only is not doc:
            glb = self.tmp / glb.name
            glb_file.write(glb, scene_only, binary)
        # Selecting what it made deselects every object of the scene first, through an
        # operator and its view-layer updates: a cost that grows with the scene, for a
        # selection nothing here reads.
        _operator("import_scene.gltf", filepath=str(glb), import_select_created_objects=False)
        new = [o for o in self.scene.collection.objects if o not in before]  # in the order linked
        if collection != self.scene.collection:
            for o in new:
                collection.objects.link(o)
                self.scene.collection.objects.unlink(o)
        glass = {m.name for m in {sl.material for o in new for sl in o.material_slots if sl.material is not None}
                 if _tune_material(m)}
        for o in new:
            # A thin pane passes ~92 % of the light: shadow rays ignore it, so the dial
            # behind gets direct light (through a transparent shader they would be
            # sampled less well: noisier and darker).
            if any(sl.material is not None and sl.material.name in glass for sl in o.material_slots):
                o.visible_shadow = False
        root = next(o for o in new if o.parent is None)
        objs = {_base_name(o.name): o for o in new}
        # children_recursive walks every object of the scene: once per asset, not per copy
        self._hierarchy[root.name] = [root, *root.children_recursive]
        return root, objs

    def _copy(self, root, collection):
        """Linked duplicate of an imported hierarchy, in `collection`; shape-keyed meshes
        get own data."""
        mapping = {}
        for o in self._hierarchy[root.name]:
            c = o.copy()
            if o.type == "MESH" and o.data.shape_keys is not None:
                c.data = o.data.copy()
            collection.objects.link(c)
            mapping[o] = c
        for o, c in mapping.items():
            if o.parent is not None:
                c.parent = mapping[o.parent]
                c.matrix_parent_inverse = o.matrix_parent_inverse.copy()
        return mapping[root], {_base_name(o.name): c for o, c in mapping.items()}

    def add_lamps(self, tags: list[str]) -> None:
        """Floodlights of the lighting poles as spot lights (the poles' meshes are loaded
        only if the camera sees them): one per emissive lens, shining out of its face."""
        bpy = self.bpy
        for tag in tags:
            p = self.site.placement(tag)
            m = self.site.manifests[p["asset"]]
            for link in m["links"]:
                for v in link["visuals"]:
                    if v["material"] != "lamp_white":
                        continue
                    pose = self.site.pose(p) @ np.array(link["pose"]).reshape(4, 4) @ np.array(v["pose"]).reshape(4, 4)
                    beam = pose[:3, :3] @ np.array([0.0, -1.0, 0.0])
                    light = bpy.data.lights.new(f"{tag}_{v['name']}", "SPOT")
                    light.energy = self.LAMP_W
                    light.spot_size = math.radians(70.0)
                    light.color = (1.0, 0.95, 0.85)
                    ob = bpy.data.objects.new(light.name, light)
                    ob.matrix_world = _matrix(bpy, look_at(pose[:3, 3] + beam * 0.05, pose[:3, 3] + beam))
                    self.scene.collection.objects.link(ob)
                    self.lamps.append(ob)

    # -- per frame
    def set_shot(self, shot: Shot) -> None:
        bpy = self.bpy
        cam = self.camera
        cam.matrix_world = _matrix(bpy, shot.cam_pose)
        cam.data.angle = shot.lens.hfov
        cam.data.clip_start, cam.data.clip_end = shot.lens.near, shot.lens.far
        self._set_sky(shot)
        if self.wires is not None:
            self.wires.follow(shot.conductor_temperature_c)
        for vs in shot.visual_states:
            objs = self.objects.get(vs.tag)
            if objs is None or vs.visual not in objs:
                continue
            ob = objs[vs.visual]
            link = self._link_pose(vs.tag, vs.link)
            ob.matrix_world = _matrix(bpy, self.site.pose(self.site.placement(vs.tag)) @ link @ vs.transform)
            for key, weight in vs.shape_weights.items():
                if ob.data.shape_keys is not None and key in ob.data.shape_keys.key_blocks:
                    ob.data.shape_keys.key_blocks[key].value = weight
            if vs.material is not None and vs.material in bpy.data.materials and ob.material_slots:
                ob.material_slots[0].material = bpy.data.materials[vs.material]

    def _link_pose(self, tag: str, link: str) -> np.ndarray:
        m = self.site.manifests[self.site.placement(tag)["asset"]]
        for rec in m["links"]:
            if rec["name"] == link:
                return np.array(rec["pose"]).reshape(4, 4)
        return np.eye(4)

    def _set_sky(self, shot: Shot) -> None:
        bpy = self.bpy
        self.sky.sun_elevation = shot.sun_elevation
        # Blender's sky rotation is counter-clockwise from +Y about +Z; azimuth is clockwise.
        self.sky.sun_rotation = -shot.sun_azimuth
        self.sky_bg.inputs["Strength"].default_value = self.SKY_SCALE
        up = shot.sun_elevation > 0
        self.sun.hide_render = not up
        self.sun.data.energy = shot.dni  # W/m2 normal to the rays: Cycles' sun unit
        self.sun.matrix_world = _matrix(bpy, look_at(shot.sun_dir, (0.0, 0.0, 0.0)))
        moon = self.MOON
        self.moon.hide_render = up
        for lamp in self.lamps:  # photocell floodlights: on from sunset to sunrise
            lamp.hide_render = up
        self.moon.data.energy = moon["irradiance"]
        mdir = sun_model.direction_enu(moon["elevation"], moon["azimuth"])
        self.moon.matrix_world = _matrix(bpy, look_at(mdir, (0.0, 0.0, 0.0)))

    def pointer_rows(self, tag: str, cam_pose: np.ndarray, k: dict) -> float | None:
        """Row extent (px) of the pointer's projected vertices: the true H numerator."""
        ob = self.objects.get(tag, {}).get(POINTER)
        if ob is None:
            return None
        self.bpy.context.view_layer.update()
        m = np.array(ob.matrix_world)
        v = np.array([tuple(x.co) for x in ob.data.vertices], float)
        uv = project(v @ m[:3, :3].T + m[:3, 3], cam_pose, k)
        return float(np.nanmax(uv[:, 1]) - np.nanmin(uv[:, 1]))

    def sun_visible(self, eye: np.ndarray, sun_dir: np.ndarray) -> bool:
        """Is the sun unobstructed from the lens (for the veiling glare)? Only what the
        render shows can hide it: a placement show_only hid is not in the frame. The
        ray meets the boxes of all objects at once; the shown meshes whose box it
        enters are ray cast, nearest first (Blender's scene.ray_cast sees every
        object of the view layer, hidden from renders or not)."""
        from mathutils import Vector

        dg = self.bpy.context.evaluated_depsgraph_get()
        objs = dg.objects
        n = len(objs)
        matrices, corners = np.empty(n * 16, np.float32), np.empty(n * 24, np.float32)
        objs.foreach_get("matrix_world", matrices)  # column-major
        objs.foreach_get("bound_box", corners)
        matrices = matrices.reshape(n, 4, 4).transpose(0, 2, 1).astype(float)
        origin = np.asarray(eye, float) + np.asarray(sun_dir, float) * 0.01
        entry = rays.ray_box_entry(origin, sun_dir, *rays.world_boxes(matrices, corners.reshape(n, 8, 3)))
        for i in np.argsort(entry, kind="stable")[: int(np.isfinite(entry).sum())]:
            ob = objs[int(i)]
            if ob.type != "MESH" or ob.hide_render:
                continue
            local = np.linalg.inv(matrices[i])
            start, direction = local[:3, :3] @ origin + local[:3, 3], local[:3, :3] @ sun_dir
            if ob.original.ray_cast(Vector(start), Vector(direction), depsgraph=dg)[0]:
                return False
        return True

    def render(self, width: int | None = None, height: int | None = None, samples: int | None = None) -> np.ndarray:
        """(h, w, 3) float32 linear radiance, top row first."""
        bpy, s = self.bpy, self.scene
        s.render.resolution_x = width or self.cam.width
        s.render.resolution_y = height or self.cam.height
        s.cycles.samples = samples or self.cam.samples
        path = self.tmp / "frame.exr"
        s.render.filepath = str(path)
        bpy.ops.render.render(write_still=True)
        # One image datablock, read again from the file each frame: adding and removing
        # an ID rebuilds the depsgraph's relations, and the next evaluation of the scene
        # (the sun's ray cast, the label pass) then evaluates every object again.
        if self._frame_image is None:
            self._frame_image = bpy.data.images.load(str(path))
        else:
            self._frame_image.reload()
        img = self._frame_image
        px = np.empty(len(img.pixels), dtype=np.float32)
        img.pixels.foreach_get(px)
        w, h = img.size
        return px.reshape(h, w, 4)[::-1, :, :3].copy()


    # -- datasets: what each pixel shows
    def set_instances(self, ids: dict[str, int]) -> None:
        """Each loaded placement's objects carry its instance id (Cycles' object index);
        the terrain and anything unlisted carry 0, the background's."""
        for tag, objs in self.objects.items():
            for ob in objs.values():
                ob.pass_index = ids.get(tag, 0)

    def show_only(self, tags) -> None:
        """Render just these placements (and the terrain): a frame's content is its own
        culled set, whatever else the scene holds. A hidden placement's collection is
        excluded from the view layer rather than its objects hidden from renders: an
        object hidden from renders is still in every dependency graph Blender builds,
        and a render builds two (the picture and the label pass), so a scene holding
        many placements a frame does not see would cost each frame in proportion to all
        of them. Only placements whose visibility changes are touched."""
        keep = set(tags)
        layers = self._placements_layer().children
        for tag, collection in self._collections.items():
            layer, hide = layers[collection.name], tag not in keep
            if layer.exclude != hide:
                layer.exclude = hide

    def set_joints(self, tag: str, manifest: dict, values: dict[str, float]) -> None:
        """Revolute joints of a placement at `values` (rad): each child link's node
        turns about the joint's axis from its rest pose (the link frames of a package
        sit on their joints, parented along the kinematic tree)."""
        from mathutils import Matrix, Vector

        objs = self.objects.get(tag, {})
        rest = self._rest.setdefault(tag, {})
        for j in manifest.get("joints", []):
            ob = objs.get(j["child"])
            if ob is None or j["name"] not in values:
                continue
            basis = rest.setdefault(j["child"], ob.matrix_basis.copy())
            ob.matrix_basis = basis @ Matrix.Rotation(float(values[j["name"]]), 4, Vector(j["axis"]))

    def set_sky(self, aerosol: float) -> None:
        self.sky.aerosol_density = float(aerosol)

    def set_parts(self, parts: dict[str, dict[str, int]], see_through=()) -> None:
        """Each object's part id (tag -> object name -> id, 0 for none), which the label
        pass renders beside the instance ids; objects of the parts `see_through` (glass)
        let the label pass see what is behind them too."""
        for tag, objs in self.objects.items():
            for name, ob in objs.items():
                ob["twin_part"] = float(parts.get(tag, {}).get(name, 0))
                ob["twin_glass"] = float(ob["twin_part"] in see_through)

    def render_labels(self, as_lights: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(instance ids uint16, planar depth float32 in metres, inf where no surface,
        part code uint16 (set_parts)) of the current frame, from Cycles itself: every
        surface replaced by an emission of (object index, view Z depth, part id), one
        sample through each pixel's centre, so the ids are whole numbers and never blend
        across an edge. A see-through object (a glass) also lets the ray go on: its part
        code is SEE_THROUGH x its part id plus the part id of what the ray meets behind
        it, whose index and depth add nothing (the glass's own stay in the first two).

        The emission is seen by camera rays only (nothing else shades), so Cycles is told
        not to sample it as light: otherwise it builds a light tree over every triangle
        of the frame, half of the pass's time, for the same bytes. `as_lights`: the
        pass as it was before (the bench's "before")."""
        bpy, s = self.bpy, self.scene
        layer = bpy.context.view_layer
        saved = (s.cycles.samples, s.cycles.use_denoising, s.cycles.filter_width, s.world, layer.material_override)
        try:
            s.cycles.samples, s.cycles.use_denoising, s.cycles.filter_width = 1, False, 0.01
            s.world = self._label_world()
            layer.material_override = self._label_material()
            layer.material_override.cycles.emission_sampling = "AUTO" if as_lights else "NONE"
            px = self.render()
        finally:
            (s.cycles.samples, s.cycles.use_denoising, s.cycles.filter_width, s.world,
             layer.material_override) = saved
        ids = np.rint(px[..., 0]).astype(np.uint16)
        depth = px[..., 1].astype(np.float32)
        depth[depth <= 0.0] = np.inf  # the background emits nothing; every surface lies beyond the near plane
        return ids, depth, np.rint(px[..., 2]).astype(np.uint16)

    def _label_material(self):
        bpy = self.bpy
        mat = bpy.data.materials.get("__labels__")
        if mat is not None:
            return mat
        mat = bpy.data.materials.new("__labels__")
        mat.use_nodes = True
        nt = mat.node_tree
        for n in list(nt.nodes):
            nt.nodes.remove(n)
        info, cam = nt.nodes.new("ShaderNodeObjectInfo"), nt.nodes.new("ShaderNodeCameraData")
        rgb, emit = nt.nodes.new("ShaderNodeCombineColor"), nt.nodes.new("ShaderNodeEmission")
        out = nt.nodes.new("ShaderNodeOutputMaterial")
        nt.links.new(info.outputs["Object Index"], rgb.inputs[0])
        nt.links.new(cam.outputs["View Z Depth"], rgb.inputs[1])
        part, glass = (nt.nodes.new("ShaderNodeAttribute") for _ in range(2))
        part.attribute_type, part.attribute_name = "OBJECT", "twin_part"
        glass.attribute_type, glass.attribute_name = "OBJECT", "twin_glass"
        # first: 1 on the ray's first surface, 0 behind a glass (whose R and G are the pixel's)
        first = self._math(nt, "LESS_THAN", nt.nodes.new("ShaderNodeLightPath").outputs["Transparent Depth"], 0.5)
        code = self._math(nt, "MULTIPLY", part.outputs["Factor"],
                          self._math(nt, "MULTIPLY_ADD", glass.outputs["Factor"], float(SEE_THROUGH - 1), 1.0))
        behind = self._math(nt, "MULTIPLY", part.outputs["Factor"],
                            self._math(nt, "SUBTRACT", 1.0, glass.outputs["Factor"]))
        nt.links.new(self._math(nt, "MULTIPLY", info.outputs["Object Index"], first), rgb.inputs[0])
        nt.links.new(self._math(nt, "MULTIPLY", cam.outputs["View Z Depth"], first), rgb.inputs[1])
        nt.links.new(self._math(nt, "MULTIPLY_ADD", first, self._math(nt, "SUBTRACT", code, behind), behind),
                     rgb.inputs[2])
        nt.links.new(rgb.outputs[0], emit.inputs["Color"])
        emit.inputs["Strength"].default_value = 1.0
        # a glass: its emission, and the ray goes on through it (a transparent closure, weight 1)
        see = nt.nodes.new("ShaderNodeMixShader")
        nt.links.new(glass.outputs["Factor"], see.inputs["Fac"])
        nt.links.new(nt.nodes.new("ShaderNodeBsdfTransparent").outputs[0], see.inputs[2])
        both = nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(emit.outputs[0], both.inputs[0])
        nt.links.new(see.outputs[0], both.inputs[1])
        nt.links.new(both.outputs[0], out.inputs["Surface"])
        return mat

    @staticmethod
    def _math(nt, op: str, *inputs):
        """A Math node of `inputs` (sockets or numbers); its output socket."""
        node = nt.nodes.new("ShaderNodeMath")
        node.operation = op
        for slot, value in zip(node.inputs, inputs):
            if isinstance(value, (int, float)):
                slot.default_value = float(value)
            else:
                nt.links.new(value, slot)
        return node.outputs[0]

    def _label_world(self):
        bpy = self.bpy
        w = bpy.data.worlds.get("__labels__")
        if w is None:
            w = bpy.data.worlds.new("__labels__")
            w.use_nodes = True
            w.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
        return w


GLASS_ALPHA_MAX = 0.5  # glTF alpha at or below which a material is a window, not a tint


def _operator(name: str, **properties) -> set[str]:
    """Blender's operator `name` (as bpy.ops names it: "import_scene.gltf") called
    without bpy.ops' view-layer updates before and after it, through the module
    bpy.ops wraps (_bpy.ops, an internal of bpy). Each update evaluates the whole
    view layer; the scene is updated once it is loaded (load_many) and before each
    render, and nothing an import does reads evaluated data."""
    from _bpy import ops

    return ops.call(name, properties)


def _tune_material(mat) -> bool:
    """Imported glTF materials for Cycles: window glass as clear glass (below); every
    Principled BSDF with single-scatter GGX (multiscatter is much slower to render;
    bench_render's reference makes the same choice, so its error leaves this out)."""
    if not mat.node_tree:
        return False
    for n in mat.node_tree.nodes:
        if n.type == "BSDF_PRINCIPLED":
            n.distribution = "GGX"
    return _clear_glass(mat)


def _clear_glass(mat) -> bool:
    """A window material (glTF alpha <= GLASS_ALPHA_MAX, as the gauge glass's 0.25) as a
    thin clear pane of IOR 1.5, roughness 0: Fresnel-weighted specular reflection (4 %
    head-on, more at grazing angles) over full transmission without refraction offset
    (thin-walled). The glTF alpha blend keeps a 75 % diffuse share that greys the dial
    and pointer out; a refracting solid would need caustics to let the sun through.
    Transparent shadows let the sun reach the dial, as through real glass. Tinted
    see-through materials (the oil column, alpha 0.9) stay as imported."""
    if not mat.node_tree:
        return False
    bsdf = next((n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is None or bsdf.inputs["Alpha"].is_linked or bsdf.inputs["Alpha"].default_value > GLASS_ALPHA_MAX:
        return False
    nt = mat.node_tree
    rough = bsdf.inputs["Roughness"].default_value
    for n in list(nt.nodes):
        if n.type != "OUTPUT_MATERIAL":
            nt.nodes.remove(n)
    out = next(n for n in nt.nodes if n.type == "OUTPUT_MATERIAL")
    fresnel, mix = nt.nodes.new("ShaderNodeFresnel"), nt.nodes.new("ShaderNodeMixShader")
    fresnel.inputs["IOR"].default_value = 1.5
    clear, gloss = nt.nodes.new("ShaderNodeBsdfTransparent"), nt.nodes.new("ShaderNodeBsdfGlossy")
    gloss.inputs["Roughness"].default_value = 0.0 if rough <= 0.1 else rough
    nt.links.new(fresnel.outputs[0], mix.inputs[0])
    nt.links.new(clear.outputs[0], mix.inputs[1])
    nt.links.new(gloss.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    return True


def _base_name(name: str) -> str:
    """Blender appends .001 to repeated names; the package's names are without it."""
    head, dot, tail = name.rpartition(".")
    return head if dot and tail.isdigit() else name


def _matrix(bpy, m: np.ndarray):
    from mathutils import Matrix

    return Matrix([list(map(float, row)) for row in np.asarray(m)])
