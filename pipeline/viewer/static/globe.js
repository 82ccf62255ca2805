// The tileset on the globe in CesiumJS, offline: Natural Earth imagery from Cesium's
// own assets, the WGS84 ellipsoid as terrain (the site's heights are ellipsoidal),
// the screen-space error of the site's LOD tolerance. When the first tiles are
// drawn, twinGlobeStats says where the tiles landed: the tileset's centre, every
// placement's position through the root transform, and points picked on the drawn
// tiles, each as latitude, longitude and height.

import { webglRenderer } from "./renderer.js";

const stats = window.twinGlobeStats;
const $ = (id) => document.getElementById(id);

function cartographic(c) {
  const g = Cesium.Cartographic.fromCartesian(c);
  return [Cesium.Math.toDegrees(g.latitude), Cesium.Math.toDegrees(g.longitude), g.height];
}

function nextFrames(scene, n) {
  return new Promise((resolve) => {
    let left = n;
    const done = scene.postRender.addEventListener(() => {
      if (--left <= 0) { done(); resolve(); }
    });
    scene.requestRender();
  });
}

// Pixels on a grid over the canvas where the tiles were drawn, as geodetic points:
// the depth of a frame drawn without the globe, so every depth is a tile's.
async function pickedPoints(viewer, step) {
  const scene = viewer.scene;
  const canvas = scene.canvas;
  scene.globe.show = false;
  await nextFrames(scene, 1);
  const out = [];
  for (let y = step / 2; y < canvas.clientHeight; y += step) {
    for (let x = step / 2; x < canvas.clientWidth; x += step) {
      const p = scene.pickPosition(new Cesium.Cartesian2(x, y));
      if (Cesium.defined(p)) out.push(cartographic(p));
    }
  }
  scene.globe.show = true;
  await nextFrames(scene, 1);
  return out;
}

async function main() {
  if (typeof Cesium === "undefined") {
    const hint = await fetch("lib/cesium/MISSING.txt").then((r) => (r.ok ? r.text() : "")).catch(() => "");
    throw new Error(hint || "CesiumJS did not load (lib/cesium/Cesium.js)");
  }
  const t0 = performance.now();
  const phases = {};
  const mark = (name) => { phases[name] = Math.round(performance.now() - t0); };
  const twin = await (await fetch("data/twin.json")).json();
  $("title").textContent = `${twin.site} on the globe`;
  const imagery = Cesium.TileMapServiceImageryProvider.fromUrl(Cesium.buildModuleUrl("Assets/Textures/NaturalEarthII"));
  const viewer = new Cesium.Viewer("globe", {
    baseLayer: Cesium.ImageryLayer.fromProviderAsync(imagery), baseLayerPicker: false, geocoder: false,
    timeline: false, animation: false, sceneModePicker: false, navigationHelpButton: false, homeButton: false,
    fullscreenButton: false, infoBox: false, selectionIndicator: false, requestRenderMode: true,
    contextOptions: {webgl: {preserveDrawingBuffer: true}}, msaaSamples: 1,
  });
  viewer.scene.globe.depthTestAgainstTerrain = false;
  const webgl = webglRenderer();
  viewer.scene.fog.enabled = !webgl.software;
  if (twin.built_sun) {  // the built scene's sun: its local time on the site's date
    viewer.clock.currentTime = Cesium.JulianDate.fromIso8601(twin.built_sun.time_utc);
    viewer.clock.shouldAnimate = false;
  }
  mark("globe");
  const tileset = await Cesium.Cesium3DTileset.fromUrl(twin.tiles, {
    maximumScreenSpaceError: twin.lod.screen_tolerance_px,
  });
  viewer.scene.primitives.add(tileset);
  mark("tileset");
  const sphere = tileset.boundingSphere;
  viewer.camera.flyToBoundingSphere(sphere, {duration: 0,
    offset: new Cesium.HeadingPitchRange(Cesium.Math.toRadians(20), Cesium.Math.toRadians(-35), sphere.radius * 2.2)});
  await new Promise((resolve) => {
    const done = tileset.initialTilesLoaded.addEventListener(() => { done(); resolve(); });
    viewer.scene.requestRender();
  });
  mark("initial_tiles");
  await nextFrames(viewer.scene, 2);
  mark("drawn");
  const drawn = performance.now();
  const transform = tileset.root.computedTransform;
  const placements = await (await fetch(twin.placements)).json();
  const placed = placements.placements.map((p) => [p.tag, ...cartographic(
    Cesium.Matrix4.multiplyByPoint(transform, new Cesium.Cartesian3(p.enu[0], p.enu[1], p.enu[2]), new Cesium.Cartesian3()))]);
  const s = tileset.statistics;
  Object.assign(stats, {
    load_ms: drawn - t0, first_frame_ms: drawn, phases_ms: phases, renderer: webgl.name, fog: viewer.scene.fog.enabled,
    centre: cartographic(sphere.center), radius_m: sphere.radius,
    placements: placed, picked: await pickedPoints(viewer, 40),
    tiles_loaded: s.numberOfLoadedTilesTotal, tiles_with_content: s.numberOfTilesWithContentReady,
    commands: s.numberOfCommands, triangles: s.numberOfTrianglesSelected, geometry_bytes: s.geometryByteLength,
  });
  mark("checked");
  $("readout").textContent = `centre ${stats.centre[0].toFixed(6)}, ${stats.centre[1].toFixed(6)}; ` +
    `${stats.tiles_with_content} tiles drawn, ${stats.triangles} triangles`;
  window.twinGlobe = {viewer, tileset};
  if (!stats.commands) stats.errors.push("the tileset drew nothing");
  window.twinGlobeReady = stats.errors.length === 0;
  window.twinGlobeFailed = !window.twinGlobeReady;
}

main().catch((e) => {
  stats.errors.push(String(e && e.stack || e));
  $("status").textContent = String(e && e.message || e);
  window.twinGlobeFailed = true;
});
