// The twin in three.js: the built scene .glb with its instances, the inspection
// cameras, the sun from the runtime's ephemeris (a table the build samples), LOD by
// distance with the builder's rule, state variants and scenario runs.
//
// Frames: twin.json and placements.json speak ENU (x east, y north, z up); the scene
// glTF is Y up (x east, y up, z south). A state binding moves a visual in its own
// Z-up frame: the drawn matrix is its rest matrix times C D C^-1, D the binding's
// change and C the Z-up -> Y-up turn the exporter applied.

import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { webglRenderer } from "./renderer.js";

const stats = window.twinViewerStats;
const $ = (id) => document.getElementById(id);
const C = new THREE.Matrix4().set(1, 0, 0, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 1);
const C_INV = C.clone().invert();
const DEG = 180 / Math.PI;

const enuToY = (v) => new THREE.Vector3(v[0], v[2], -v[1]);
const yToEnu = (v) => [v.x, -v.z, v.y];

async function fetchJSON(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
  return r.json();
}

// --- the site's clock and the sun -------------------------------------------------

// Wall time (seconds as if UTC) -> the UTC instants showing it: none in a gap, two in a fold.
export function wallToUtc(clock, wall) {
  const out = [];
  const offs = clock.offsets;
  for (let i = 0; i < offs.length; i++) {
    const u = wall - offs[i][1];
    const end = i + 1 < offs.length ? offs[i + 1][0] : Infinity;
    if (u >= offs[i][0] && u < end) out.push({utc: u, offset: offs[i][1], abbr: offs[i][2]});
  }
  return out;
}

export function utcToWall(clock, utc) {
  let o = clock.offsets[0];
  for (const p of clock.offsets) if (p[0] <= utc) o = p;
  return {wall: utc + o[1], offset: o[1], abbr: o[2]};
}

function isoOffset(seconds) {
  const s = seconds < 0 ? "-" : "+";
  const a = Math.abs(seconds);
  return `${s}${String(Math.floor(a / 3600)).padStart(2, "0")}:${String(Math.floor((a % 3600) / 60)).padStart(2, "0")}`;
}

function wallText(clock, utc) {
  const w = utcToWall(clock, utc);
  return new Date(w.wall * 1000).toISOString().slice(0, 19) + isoOffset(w.offset);
}

// The sun towards the site at a UTC instant: the table's cubic through the four
// nearest samples, normalised. Returns ENU direction, elevation and azimuth (deg).
export function sunAt(sun, table, utc) {
  const x = (utc - sun.start_utc_s) / sun.step_s;
  if (!(x >= 1 && x <= sun.count - 3)) return null;  // outside the table's year
  const k = Math.floor(x);
  const t = x - k;
  // Lagrange weights of samples k-1, k, k+1, k+2 at k + t
  const w = [-t * (t - 1) * (t - 2) / 6, (t + 1) * (t - 1) * (t - 2) / 2,
             -(t + 1) * t * (t - 2) / 2, (t + 1) * t * (t - 1) / 6];
  const d = [0, 0, 0];
  for (let j = 0; j < 4; j++) for (let c = 0; c < 3; c++) d[c] += w[j] * table[3 * (k - 1 + j) + c];
  const n = Math.hypot(d[0], d[1], d[2]);
  const dir = d.map((v) => v / n);
  const elevation = Math.asin(Math.max(-1, Math.min(1, dir[2]))) * DEG;
  const azimuth = ((Math.atan2(dir[0], dir[1]) * DEG) + 360) % 360;
  return {dir, elevation_deg: elevation, azimuth_deg: azimuth};
}

// runtime.sun.irradiance: direct horizontal irradiance, 0 at and below the horizon
export function irradiance(sun, elevationRad) {
  const s = Math.sin(elevationRad);
  return s > 0 ? sun.g0_w_m2 * Math.exp(-sun.tau_atm / s) * s : 0;
}

// --- the runtime's mapping M_k of a state value (ir.StateBinding.output) ----------

export function bindingOutput(b, value) {
  if (b.effect === "material") {
    let i = 0;
    for (const t of b.thresholds || []) if (t <= value) i++;
    return i;
  }
  const [d0, d1] = b.domain;
  const [r0, r1] = b.range || [0, 1];
  let t = d1 === d0 ? 0 : (value - d0) / (d1 - d0);
  t = Math.min(1, Math.max(0, t));
  return r0 + t * (r1 - r0);
}

function unitAxis(axis) {
  const a = axis || [0, 0, 1];
  const n = Math.hypot(a[0], a[1], a[2]);
  return n > 0 ? a.map((v) => v / n) : [0, 0, 1];
}

// runtime.nodes.delta_matrix: a rotate / translate / scale output as a Z-up matrix
export function deltaMatrix(effect, axis, y) {
  const [x0, x1, x2] = unitAxis(axis);
  const m = new THREE.Matrix4();
  if (effect === "rotate") {
    // Rodrigues: I + sin(y) K + (1 - cos y) K^2, K the cross-product matrix of the axis
    const s = Math.sin(y), c1 = 1 - Math.cos(y);
    const K = [[0, -x2, x1], [x2, 0, -x0], [-x1, x0, 0]];
    const r = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
    for (let i = 0; i < 3; i++) for (let j = 0; j < 3; j++) {
      let kk = 0;
      for (let l = 0; l < 3; l++) kk += K[i][l] * K[l][j];
      r[i][j] += s * K[i][j] + c1 * kk;
    }
    m.set(r[0][0], r[0][1], r[0][2], 0, r[1][0], r[1][1], r[1][2], 0, r[2][0], r[2][1], r[2][2], 0, 0, 0, 0, 1);
  } else if (effect === "translate") {
    m.makeTranslation(x0 * y, x1 * y, x2 * y);
  } else if (effect === "scale") {
    const a = [x0, x1, x2];
    const e = (i, j) => (i === j ? 1 : 0) + (y - 1) * a[i] * a[j];
    m.set(e(0, 0), e(0, 1), e(0, 2), 0, e(1, 0), e(1, 1), e(1, 2), 0, e(2, 0), e(2, 1), e(2, 2), 0, 0, 0, 0, 1);
  }
  return m;
}

// One bound visual at one set of fed values (runtime.nodes._map_visual): the change
// D (Z up, visual frame), the link-frame transform rest @ D, material, shape weights.
export function mapVisual(bindings, fed) {
  const recs = bindings.filter((b) => b.variable in fed);
  if (!recs.length) return null;
  const delta = new THREE.Matrix4();
  let material = null;
  let variant = null;
  const weights = {};
  const outputs = [];
  for (const b of recs) {
    const y = bindingOutput(b, fed[b.variable]);
    outputs.push({variable: b.variable, effect: b.effect, value: fed[b.variable], output: y});
    if (b.effect === "material") {
      material = b.materials && b.materials.length ? b.materials[y] : null;
      variant = material === null ? null : `${b.variable}:${material}`;
    }
    else if (b.effect === "shape") weights[b.shape_key || ""] = y;
    else delta.multiply(deltaMatrix(b.effect, b.axis, y));
  }
  return {delta, material, variant, weights, outputs};
}

// --- the viewer ---------------------------------------------------------------

class Viewer {
  constructor(twin, record, sunTable) {
    this.twin = twin;
    this.record = record;
    this.sunTable = sunTable;
    this.placements = new Map(record.placements.map((p) => [p.tag, p]));
    this.entries = [];          // every drawn visual: {asset, lod, visual, tags, instanced, chain, node}
    this.byTag = new Map();     // tag -> {record, refs: [{entry, index}], level, bound: Map(visual -> BoundVisual)}
    this.lodMode = "auto";
    this.runs = new Map();
    this.fed = new Map();       // STATE -> {variable: value} the user or a run set
    this.pickables = [];
    this.renderQueued = false;
    this.lastLodCamera = null;
  }

  async load(mark = () => {}) {
    this.setupRenderer();
    const loader = new GLTFLoader();
    const gltf = await loader.loadAsync(this.twin.scene);
    mark("scene");
    this.gltf = gltf;
    this.parser = gltf.parser;
    this.json = gltf.parser.json;
    const lights = [];
    gltf.scene.traverse((o) => { if (o.isLight) lights.push(o); });
    lights.forEach((l) => l.parent.remove(l));  // the page lights the scene by its own clock
    this.scene.add(gltf.scene);
    this.coarser = new THREE.Group();           // MSFT_lod's coarser nodes (not in the glTF scene)
    this.split = new THREE.Group();             // state-bound visuals of stateful placements
    this.scene.add(this.coarser, this.split);
    await this.index();
    mark("indexed");
    this.bindStates();
    this.updateLod(true);
    this.checkPlacements();
  }

  setupRenderer() {
    const el = $("view");
    this.webgl = webglRenderer();
    this.renderer = new THREE.WebGLRenderer({antialias: !this.webgl.software});
    this.renderer.setPixelRatio(window.devicePixelRatio || 1);
    this.renderer.setSize(el.clientWidth, el.clientHeight);
    el.appendChild(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(50, el.clientWidth / el.clientHeight, 0.05, 20000);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener("change", () => this.requestRender());
    this.sunLight = new THREE.DirectionalLight(0xfff4e5, 2.5);
    this.sky = new THREE.HemisphereLight(0xbfd8ff, 0x5a5040, 1.0);
    this.scene.add(this.sunLight, this.sunLight.target, this.sky);
    window.addEventListener("resize", () => {
      this.camera.aspect = el.clientWidth / el.clientHeight;
      this.camera.updateProjectionMatrix();
      this.renderer.setSize(el.clientWidth, el.clientHeight);
      this.requestRender();
    });
  }

  drawables(obj) {
    return obj.isMesh ? [obj] : obj.children.filter((c) => c.isMesh);
  }

  // Every root node of the scene: terrain, the instanced visuals (one per model visual
  // and builder level, their placements in extras.tags) and the per-placement ones
  // (meshes with morph targets), each with its MSFT_lod chain.
  async index() {
    const json = this.json;
    for (const ni of json.scenes[json.scene || 0].nodes) {
      const def = json.nodes[ni];
      const tags = (def.extras && def.extras.tags) || null;
      if (def.mesh === undefined || !tags) {
        if (def.mesh !== undefined) (await this.parser.getDependency("node", ni)).traverse((o) => {
          if (o.isMesh) { o.userData.twin = {terrain: true}; this.pickables.push(o); }
        });
        continue;
      }
      const [asset, lodPart, visual] = def.name.split("/");
      const lod = parseInt(lodPart.slice(3), 10);
      const instanced = !!(def.extensions && def.extensions.EXT_mesh_gpu_instancing);
      const ids = (def.extensions && def.extensions.MSFT_lod && def.extensions.MSFT_lod.ids) || [];
      const nodes = [ni, ...ids];
      const chain = [];
      for (const [k, id] of nodes.entries()) {
        const obj = await this.parser.getDependency("node", id);
        if (k > 0) this.coarser.add(obj);
        chain.push({obj, node: id, meshes: this.drawables(obj)});
      }
      const entry = {asset, lod, visual, tags, instanced, chain};
      for (const member of chain) {
        for (const d of member.meshes) {
          d.userData.twin = {entry};
          this.pickables.push(d);
          if (instanced) {
            d.userData.rest = Float32Array.from(d.instanceMatrix.array);
            d.userData.shown = new Uint8Array(d.count);
            d.userData.slots = [];  // drawn slot -> instance index (what a pick's instanceId names)
            d.instanceMatrix.setUsage(THREE.DynamicDrawUsage);
          }
        }
      }
      this.entries.push(entry);
      tags.forEach((tag, index) => {
        if (!this.byTag.has(tag)) this.byTag.set(tag, {record: this.placements.get(tag), refs: [], level: -1, bound: new Map()});
        this.byTag.get(tag).refs.push({entry, index});
      });
    }
  }

  // The bound visuals of every placement with a STATE and bindings, taken out of
  // their instanced nodes into meshes of their own (a placement's state is its own).
  bindStates() {
    for (const [tag, p] of this.byTag) {
      const rec = p.record;
      const asset = rec && this.twin.assets[rec.asset];
      if (!rec || !rec.state || !asset || !asset.bindings.length) continue;
      const targets = new Set(asset.bindings.map((b) => b.target));
      for (const ref of p.refs) {
        const {entry, index} = ref;
        if (!targets.has(entry.visual)) continue;
        const members = entry.chain.map((member) => {
          if (!entry.instanced) {
            return {obj: member.obj, rest: member.obj.matrix.clone(), meshes: member.meshes, node: member.node};
          }
          const holder = new THREE.Group();
          holder.matrixAutoUpdate = false;
          const rest = new THREE.Matrix4().fromArray(member.meshes[0].userData.rest, 16 * index);
          const meshes = member.meshes.map((d) => {
            const m = new THREE.Mesh(d.geometry, d.material);
            m.userData.twin = {tag};
            this.pickables.push(m);
            holder.add(m);
            return m;
          });
          this.split.add(holder);
          return {obj: holder, rest, meshes, node: member.node};
        });
        ref.split = true;
        for (const member of members) {
          member.obj.matrixAutoUpdate = false;
          member.obj.matrix.copy(member.rest);
          member.baseMaterials = member.meshes.map((m) => m.material);
          member.baseWeights = member.meshes.map((m) => (m.morphTargetInfluences ? [...m.morphTargetInfluences] : null));
        }
        p.bound.set(entry.visual, {entry, members, bindings: asset.bindings.filter((b) => b.target === entry.visual)});
      }
    }
  }

  // --- LOD --------------------------------------------------------------------

  // scene.placements.choose_lods from the viewer's camera: the coarsest level whose
  // measured error, seen from the eye at the nearest point of the model's bounds,
  // stays within the site's screen tolerance.
  ruleLevel(rec, eyeEnu, hfov, widthPx) {
    const asset = this.twin.assets[rec.asset];
    const c = Math.cos(rec.yaw_rad), s = Math.sin(rec.yaw_rad);
    const dx = eyeEnu[0] - rec.enu[0], dy = eyeEnu[1] - rec.enu[1], dz = eyeEnu[2] - rec.enu[2];
    const local = [c * dx + s * dy, -s * dx + c * dy, dz];
    const [lo, hi] = asset.bounds;
    const k = rec.scale || 1;  // placements.json's scale (insert_scale = "apply"), else 1
    let d2 = 0;
    for (let i = 0; i < 3; i++) {
      const q = Math.min(Math.max(local[i], k * lo[i]), k * hi[i]);
      d2 += (local[i] - q) ** 2;
    }
    const d = Math.sqrt(d2);
    let level = 0;
    asset.errors_m.forEach((e, k) => {
      const px = d > 0 ? k * e / (2 * d * Math.tan(hfov / 2)) * widthPx : (e > 0 ? Infinity : 0);
      if (px <= this.twin.lod.screen_tolerance_px) level = k;
    });
    return level;
  }

  levelFor(p) {
    const built = p.record.lod;
    if (this.lodMode === "built") return built;
    if (this.lodMode !== "auto") return parseInt(this.lodMode, 10);
    const eye = yToEnu(this.camera.position);
    const hfov = 2 * Math.atan(Math.tan(THREE.MathUtils.degToRad(this.camera.fov) / 2) * this.camera.aspect);
    return this.ruleLevel(p.record, eye, hfov, this.renderer.domElement.width);
  }

  // Show each placement's visuals at its level: the scene holds the levels from the
  // builder's choice down, so a placement never shows finer than that.
  updateLod(force = false) {
    const touched = new Set();
    const counts = {};
    for (const [, p] of this.byTag) {
      if (!p.record) continue;
      const level = Math.max(this.levelFor(p), p.record.lod);
      counts[level] = (counts[level] || 0) + 1;
      if (level === p.level && !force) continue;
      p.level = level;
      for (const ref of p.refs) {
        const {entry, index} = ref;
        const shown = Math.min(level - entry.lod, entry.chain.length - 1);
        entry.chain.forEach((member, k) => {
          if (entry.instanced) {
            // a split instance stays hidden: its own mesh draws it
            for (const d of member.meshes) {
              d.userData.shown[index] = k === shown && !ref.split ? 1 : 0;
              touched.add(d);
            }
          } else if (!ref.split) {
            member.obj.visible = k === shown;
          }
        });
        const bound = p.bound.get(entry.visual);
        if (bound) bound.members.forEach((member, k) => { member.obj.visible = k === shown; });
      }
    }
    for (const d of touched) this.compact(d);
    this.lodCounts = counts;
    $("lod-readout").textContent = "placements per level: " +
      Object.keys(counts).sort().map((k) => `${k}: ${counts[k]}`).join(", ");
  }

  // An instanced mesh draws its shown instances only: they are moved to the front
  // and the count cut (an instance scaled to nothing would still cost its vertices).
  compact(d) {
    const {rest, shown} = d.userData;
    const slots = [];
    for (let j = 0; j < shown.length; j++) if (shown[j]) slots.push(j);
    const m = d.instanceMatrix.array;
    slots.forEach((j, slot) => { for (let c = 0; c < 16; c++) m[16 * slot + c] = rest[16 * j + c]; });
    d.userData.slots = slots;
    d.count = slots.length;
    d.visible = slots.length > 0;
    d.instanceMatrix.needsUpdate = true;
    if (slots.length) d.computeBoundingSphere();
  }

  checkPlacements() {
    const missing = [...this.placements.keys()].filter((t) => !this.byTag.has(t));
    if (missing.length) stats.errors.push(`${missing.length} placements not in the scene: ${missing.slice(0, 5).join(", ")}`);
    stats.instances = [...this.byTag.values()].filter((p) => p.record && p.level >= 0).length;
  }

  // --- states -----------------------------------------------------------------

  // The values `fed` (variable -> value) on the placement `tag`'s bound visuals;
  // returns what each became (for the panel and the tests).
  applyState(tag, fed) {
    const p = this.byTag.get(tag);
    if (!p) throw new Error(`no placement ${tag}`);
    const out = {};
    for (const [visual, bound] of p.bound) {
      const mapped = mapVisual(bound.bindings, fed);
      bound.members.forEach((member) => this.showMapped(bound.entry, member, mapped));
      if (mapped) {
        const rest = new THREE.Matrix4().fromArray(bound.bindings[0].rest_pose || new THREE.Matrix4().elements).transpose();
        out[visual] = {material: mapped.material, weights: mapped.weights, outputs: mapped.outputs,
                       transform: rest.clone().multiply(mapped.delta).transpose().toArray()};
      }
    }
    this.requestRender();
    return out;
  }

  showMapped(entry, member, mapped) {
    const delta = mapped ? mapped.delta : new THREE.Matrix4();
    member.obj.matrix.copy(member.rest).multiply(C).multiply(delta).multiply(C_INV);
    member.obj.matrixWorldNeedsUpdate = true;
    const meshDef = this.json.meshes[this.json.nodes[member.node].mesh];
    member.meshes.forEach((m, i) => {
      m.material = member.baseMaterials[i];
      if (mapped && mapped.variant) this.variantMaterial(meshDef.primitives[i], mapped.variant, m);
      if (m.morphTargetInfluences) {
        const base = member.baseWeights[i];
        for (let k = 0; k < base.length; k++) m.morphTargetInfluences[k] = base[k];
        if (mapped) for (const [key, w] of Object.entries(mapped.weights)) {
          const k = m.morphTargetDictionary ? m.morphTargetDictionary[key] : undefined;
          if (k !== undefined) m.morphTargetInfluences[k] = w;
        }
      }
    });
  }

  // KHR_materials_variants: the primitive's material for the variant `name` (the
  // exporter names a material binding's variants "<variable>:<material>").
  variantMaterial(prim, name, mesh) {
    const mappings = prim.extensions && prim.extensions.KHR_materials_variants && prim.extensions.KHR_materials_variants.mappings;
    if (!mappings) return;
    const variants = this.json.extensions.KHR_materials_variants.variants;
    for (const m of mappings) {
      if (m.variants.some((v) => variants[v].name === name)) {
        this.parser.getDependency("material", m.material).then((mat) => {
          mesh.material = mat;
          this.requestRender();
        });
        return;
      }
    }
  }

  // The user's values and a run's: STATE -> variable -> value, on every placement with that STATE.
  applyFed() {
    for (const [tag, p] of this.byTag) {
      if (p.record && p.record.state && p.bound.size) this.applyState(tag, this.fed.get(p.record.state) || {});
    }
  }

  // --- sun --------------------------------------------------------------------

  setSun(dir, irr) {
    const v = enuToY(dir).normalize();
    const up = Math.max(dir[2], 0);
    this.sunLight.position.copy(v.multiplyScalar(500));
    this.sunLight.intensity = 3.0 * irr / 1000;
    const day = Math.min(1, Math.max(0, up * 4 + 0.15));
    this.sky.intensity = 0.15 + 0.85 * day;
    this.scene.background = new THREE.Color(0x0b1020).lerp(new THREE.Color(0x9cc4e8), day);
    this.requestRender();
  }

  // Date (YYYY-MM-DD) and local time (HH:MM) on the site's clock -> the sun.
  setLocalTime(date, time) {
    const [y, mo, d] = date.split("-").map(Number);
    const [h, mi] = time.split(":").map(Number);
    const wall = Date.UTC(y, mo - 1, d, h, mi) / 1000;
    const instants = wallToUtc(this.twin.clock, wall);
    if (!instants.length) {
      $("sun-readout").textContent = `${date} ${time} does not exist in ${this.twin.clock.zone} (the clocks skip it)`;
      return {error: "gap"};
    }
    const utc = instants[0].utc;
    const sun = sunAt(this.twin.sun, this.sunTable, utc);
    if (!sun) {
      $("sun-readout").textContent = `the sun table covers ${this.twin.sun.year} only`;
      return {error: "outside"};
    }
    const irr = irradiance(this.twin.sun, sun.elevation_deg / DEG);
    this.setSun(sun.dir, irr);
    const twice = instants.length > 1 ? ` (happens twice: ${instants.map((i) => isoOffset(i.offset)).join(" or ")}; the first)` : "";
    $("sun-readout").textContent = `${wallText(this.twin.clock, utc)} ${instants[0].abbr}${twice}: ` +
      `elevation ${sun.elevation_deg.toFixed(2)}°, azimuth ${sun.azimuth_deg.toFixed(2)}°, ${irr.toFixed(0)} W/m²`;
    return {utc, offsets: instants.map((i) => i.offset), ...sun, irradiance_w_m2: irr};
  }

  // --- cameras ----------------------------------------------------------------

  // The whole site from above its south-east, around the placements' extent.
  overview() {
    const box = new THREE.Box3();
    for (const p of this.record.placements) box.expandByPoint(enuToY(p.enu));
    box.expandByScalar(10);
    const centre = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3()).length();
    this.camera.fov = 50;
    this.camera.near = Math.max(0.05, size / 5000);
    this.camera.far = size * 10;
    this.camera.updateProjectionMatrix();
    this.camera.position.copy(centre).add(new THREE.Vector3(0.35, 0.45, 0.55).multiplyScalar(size * 0.8));
    this.controls.target.copy(centre);
    this.controls.update();
    this.afterMove();
  }

  goToInspection(name) {
    const point = this.twin.inspection_points.find((p) => p.name === name);
    if (!point) return this.overview();
    const hfov = this.twin.lod.reference_hfov_rad;
    this.camera.fov = 2 * Math.atan(Math.tan(hfov / 2) / this.camera.aspect) * DEG;
    this.camera.near = 0.05;
    this.camera.updateProjectionMatrix();
    this.camera.position.copy(enuToY(point.eye));
    this.controls.target.copy(enuToY(point.look_at));
    this.controls.update();
    this.afterMove();
  }

  afterMove() {
    this.updateLod();
    this.requestRender();
  }

  // --- picking ----------------------------------------------------------------

  pickAt(x, y) {
    const rect = this.renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((x - rect.left) / rect.width) * 2 - 1, -((y - rect.top) / rect.height) * 2 + 1);
    const ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, this.camera);
    const hits = ray.intersectObjects(this.pickables, false).filter((h) => h.object.visible);
    for (const h of hits) {
      const t = h.object.userData.twin;
      if (!t) continue;
      if (t.terrain) return {terrain: true};
      if (t.tag) return {tag: t.tag};
      if (t.entry) {
        const tag = t.entry.instanced ? t.entry.tags[h.object.userData.slots[h.instanceId]] : t.entry.tags[0];
        const p = this.byTag.get(tag);
        const ref = p && p.refs.find((r) => r.entry === t.entry);
        if (ref && ref.split) continue;  // a hidden instance: the split mesh is the one drawn
        return {tag};
      }
    }
    return null;
  }

  select(tag) {
    const el = $("picked");
    const p = this.byTag.get(tag);
    if (!p || !p.record) {
      el.innerHTML = "<h2>Selection</h2><p class='small'>Click a piece of equipment.</p>";
      return;
    }
    const r = p.record;
    const asset = this.twin.assets[r.asset] || {};
    const rows = [["tag", r.tag], ["asset", r.asset], ["category", asset.category], ["state", r.state || "-"],
                  ["level", r.level], ["LOD shown", p.level], ["LOD as built", r.lod],
                  ["ENU (m)", r.enu.map((v) => v.toFixed(3)).join(", ")], ["heading", `${r.heading_deg}°`]];
    el.innerHTML = "<h2>Selection</h2>";
    const table = document.createElement("table");
    table.className = "kv";
    for (const [k, v] of rows) {
      const tr = table.insertRow();
      tr.insertCell().textContent = k;
      tr.insertCell().textContent = v === undefined ? "" : String(v);
    }
    el.appendChild(table);
    if (asset.description) {
      const d = document.createElement("p");
      d.className = "small";
      d.textContent = asset.description;
      el.appendChild(d);
    }
    if (r.state && p.bound.size) this.stateControls(el, r, asset);
    this.highlight(r, asset);
  }

  // One slider per state variable of the placement's bindings (its domain), the
  // mapping's result beside it; "rest" clears what was set.
  stateControls(el, r, asset) {
    const variables = new Map();
    for (const b of asset.bindings) if (!variables.has(b.variable)) variables.set(b.variable, b);
    const h = document.createElement("h2");
    h.textContent = `State ${r.state}`;
    el.appendChild(h);
    const fed = this.fed.get(r.state) || {};
    for (const [variable, b] of variables) {
      const label = document.createElement("label");
      const input = document.createElement("input");
      input.type = "range";
      input.min = b.domain[0];
      input.max = b.domain[1];
      input.step = (b.domain[1] - b.domain[0]) / 200 || 1;
      input.value = variable in fed ? fed[variable] : b.domain[0];
      const out = document.createElement("output");
      const show = () => { out.textContent = ` ${variable} = ${Number(input.value).toFixed(2)}`; };
      input.addEventListener("input", () => {
        const now = {...(this.fed.get(r.state) || {}), [variable]: Number(input.value)};
        this.fed.set(r.state, now);
        show();
        this.applyFed();
      });
      show();
      label.append(input, out);
      el.appendChild(label);
    }
    const reset = document.createElement("button");
    reset.textContent = "rest";
    reset.addEventListener("click", () => { this.fed.delete(r.state); this.applyFed(); this.select(r.tag); });
    el.appendChild(reset);
  }

  highlight(r, asset) {
    if (this.box) this.scene.remove(this.box);
    const [lo, hi] = asset.bounds;
    const geometry = new THREE.BoxGeometry(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
    geometry.translate((hi[0] + lo[0]) / 2, (hi[1] + lo[1]) / 2, (hi[2] + lo[2]) / 2);
    this.box = new THREE.LineSegments(new THREE.EdgesGeometry(geometry), new THREE.LineBasicMaterial({color: 0xffc000}));
    const k = r.scale || 1;
    const pose = new THREE.Matrix4().makeRotationZ(r.yaw_rad).setPosition(r.enu[0], r.enu[1], r.enu[2])
      .multiply(new THREE.Matrix4().makeScale(k, k, k));
    this.box.matrixAutoUpdate = false;
    this.box.matrix.copy(C).multiply(pose);
    this.scene.add(this.box);
    this.requestRender();
  }

  // --- runs -------------------------------------------------------------------

  async findRuns() {
    for (const s of this.twin.scenarios) {
      if (!s.name) continue;
      const r = await fetch(s.states).catch(() => null);
      if (!r || !r.ok) continue;
      const steps = (await r.text()).split("\n").filter((l) => l.trim()).map((l) => JSON.parse(l));
      this.runs.set(s.name, {scenario: s, steps});
      const o = document.createElement("option");
      o.value = s.name;
      o.textContent = `${s.name} (${steps.length} steps)`;
      $("run").appendChild(o);
    }
    if (!this.runs.size) $("run-readout").textContent = "no run yet: twin run SCENARIO";
  }

  // Step k of a run: the render node's inputs (each fed by a node output) on the
  // placements with those STATEs, and the run's own sun.
  showRunStep(name, k) {
    const run = this.runs.get(name);
    const step = run.steps[k];
    const s = run.scenario;
    this.fed.clear();
    for (const [state, variables] of Object.entries(s.inputs)) {
      const values = {};
      for (const [variable, src] of Object.entries(variables)) if (src in step.outputs) values[variable] = step.outputs[src];
      this.fed.set(state, values);
    }
    this.applyFed();
    const utc = s.start_utc_s + step.t;
    let sunText = "";
    if (s.sun && `${s.sun}.elevation` in step.outputs) {
      const e = step.outputs[`${s.sun}.elevation`], a = step.outputs[`${s.sun}.azimuth`];
      this.setSun([Math.cos(e) * Math.sin(a), Math.cos(e) * Math.cos(a), Math.sin(e)], step.outputs[`${s.sun}.irradiance`] || 0);
      sunText = `, sun ${(e * DEG).toFixed(2)}° / ${(a * DEG).toFixed(2)}°`;
    }
    $("run-readout").textContent = `t = ${step.t} s, ${wallText(this.twin.clock, utc)}${sunText}`;
    return {t: step.t, utc, fed: Object.fromEntries(this.fed)};
  }

  // --- rendering --------------------------------------------------------------

  requestRender() {
    if (this.renderQueued) return;
    this.renderQueued = true;
    requestAnimationFrame(() => {
      this.renderQueued = false;
      this.render();
    });
  }

  render() {
    const eye = this.camera.position;
    if (!this.lastLodCamera || this.lastLodCamera.distanceTo(eye) > 0.05) {
      this.lastLodCamera = eye.clone();
      if (this.lodMode === "auto") this.updateLod();
    }
    this.renderer.render(this.scene, this.camera);
  }
}

// --- the page ------------------------------------------------------------------

function bindControls(app) {
  const twin = app.twin;
  for (const p of twin.inspection_points) {
    const o = document.createElement("option");
    o.value = p.name;
    o.textContent = p.target ? `${p.name} (${p.target})` : p.name;
    $("camera").appendChild(o);
  }
  $("camera").addEventListener("change", (e) => app.goToInspection(e.target.value));
  $("lod").addEventListener("change", (e) => { app.lodMode = e.target.value; app.updateLod(true); app.requestRender(); });
  const date = $("date"), time = $("time");
  date.min = `${twin.sun.year}-01-01`;
  date.max = `${twin.sun.year}-12-31`;
  date.value = twin.date;
  time.value = 13 * 60;
  const setSun = () => {
    const m = Number(time.value);
    const hhmm = `${String(Math.floor(m / 60)).padStart(2, "0")}:${String(m % 60).padStart(2, "0")}`;
    $("time-out").textContent = hhmm;
    app.setLocalTime(date.value, hhmm);
  };
  date.addEventListener("change", setSun);
  time.addEventListener("input", setSun);
  setSun();
  let down = null;
  app.renderer.domElement.addEventListener("pointerdown", (e) => { down = [e.clientX, e.clientY]; });
  app.renderer.domElement.addEventListener("pointerup", (e) => {
    if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4) return;
    const hit = app.pickAt(e.clientX, e.clientY);
    app.select(hit && hit.tag);
  });
  let timer = null;
  const stepInput = $("step");
  $("run").addEventListener("change", (e) => {
    const run = app.runs.get(e.target.value);
    clearInterval(timer);
    $("play").disabled = stepInput.disabled = !run;
    if (!run) { app.fed.clear(); app.applyFed(); setSun(); $("run-readout").textContent = ""; return; }
    stepInput.max = run.steps.length - 1;
    stepInput.value = 0;
    app.showRunStep(e.target.value, 0);
  });
  stepInput.addEventListener("input", () => app.showRunStep($("run").value, Number(stepInput.value)));
  $("play").addEventListener("click", () => {
    if (timer) { clearInterval(timer); timer = null; $("play").textContent = "play"; return; }
    $("play").textContent = "pause";
    const run = app.runs.get($("run").value);
    timer = setInterval(() => {
      const k = (Number(stepInput.value) + 1) % run.steps.length;
      stepInput.value = k;
      app.showRunStep($("run").value, k);
    }, 1000 * Math.min(run.scenario.step_s, 1) / 4);  // four steps a second at most
  });
}

async function main() {
  const t0 = performance.now();
  const phases = {};
  const mark = (name) => { phases[name] = Math.round(performance.now() - t0); };
  const twin = await fetchJSON("data/twin.json");
  const [record, table] = await Promise.all([
    fetchJSON(twin.placements),
    fetch(`data/${twin.sun.file}`).then((r) => r.arrayBuffer()).then((b) => new Float32Array(b)),
  ]);
  $("title").textContent = twin.site;
  $("subtitle").textContent = `${twin.description} (${twin.timezone})`;
  const app = new Viewer(twin, record, table);
  window.twinViewer = {app, wallToUtc, utcToWall, sunAt, irradiance, bindingOutput, mapVisual};
  mark("data");
  await app.load(mark);
  bindControls(app);
  app.overview();
  await app.findRuns();
  mark("runs");
  // ready once a frame with the scene in it has been drawn
  app.render();
  await new Promise((resolve) => requestAnimationFrame(() => requestAnimationFrame(resolve)));
  mark("drawn");
  const info = app.renderer.info.render;
  Object.assign(stats, {first_frame_ms: performance.now(), load_ms: performance.now() - t0,
                        draw_calls: info.calls, triangles: info.triangles, lod: app.lodCounts,
                        placements: record.placements.length, runs: [...app.runs.keys()], phases_ms: phases,
                        renderer: app.webgl.name, antialias: app.renderer.getContext().getContextAttributes().antialias});
  if (!info.calls || !info.triangles) stats.errors.push("the first frame drew nothing");
  window.twinViewerReady = stats.errors.length === 0;
  window.twinViewerFailed = !window.twinViewerReady;
}

main().catch((e) => {
  stats.errors.push(String(e && e.stack || e));
  $("status").textContent = String(e && e.message || e);
  window.twinViewerFailed = true;
});
