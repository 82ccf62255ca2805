// Opens a viewer page (index.html or globe.html of a served build/viewer/) in Debian's
// Chromium, headless, WebGL through SwiftShader; waits until the page says it is
// ready (or failed); prints one JSON document: the page's stats, page errors,
// the time from navigation to ready, memory, and the result of --eval. A globe page's
// render loop stops once it is ready (see below).
//
//   node tools/viewer_check.mjs --url URL [--mode viewer|globe] [--screenshot PNG]
//        [--width 1280] [--height 800] [--timeout 240000] [--eval FILE]
//
// --eval FILE: a JavaScript expression (an async function body is fine when wrapped
// as `(async () => {...})()`) evaluated in the page once ready; its JSON value is
// "eval" in the output. Exit status 0 when the page was ready, 1 otherwise.
// CHROMIUM (environment) names another browser binary; nothing is downloaded.

import fs from "node:fs";
import { chromium } from "playwright-core";

const FLAGS = ["--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
  "--disable-background-networking", "--disable-component-update", "--no-first-run", "--disable-sync"];

function options(argv) {
  const o = {mode: "viewer", width: 1280, height: 800, timeout: 240000};
  for (let i = 2; i < argv.length; i += 2) o[argv[i].replace(/^--/, "")] = argv[i + 1];
  o.width = Number(o.width);
  o.height = Number(o.height);
  o.timeout = Number(o.timeout);
  if (!o.url) throw new Error("--url is required");
  return o;
}

// Proportional set size of this process's descendants (the browser's processes), bytes.
function browserMemory() {
  const parent = new Map();
  for (const name of fs.readdirSync("/proc")) {
    if (!/^\d+$/.test(name)) continue;
    try {
      const stat = fs.readFileSync(`/proc/${name}/stat`, "utf8");
      parent.set(Number(name), Number(stat.slice(stat.lastIndexOf(")") + 2).split(" ")[1]));
    } catch { /* gone */ }
  }
  const mine = new Set([process.pid]);
  let grew = true;
  while (grew) {
    grew = false;
    for (const [pid, ppid] of parent) if (!mine.has(pid) && mine.has(ppid)) { mine.add(pid); grew = true; }
  }
  mine.delete(process.pid);
  let pss = 0, rss = 0;
  for (const pid of mine) {
    try {
      const rollup = fs.readFileSync(`/proc/${pid}/smaps_rollup`, "utf8");
      pss += 1024 * Number((rollup.match(/^Pss:\s+(\d+)/m) || [0, 0])[1]);
      rss += 1024 * Number((rollup.match(/^Rss:\s+(\d+)/m) || [0, 0])[1]);
    } catch { /* gone, or not ours to read */ }
  }
  return {processes: mine.size, pss_bytes: pss, rss_bytes: rss};
}

async function main() {
  const o = options(process.argv);
  const flag = o.mode === "globe" ? "twinGlobe" : "twinViewer";
  const out = {url: o.url, mode: o.mode, page_errors: [], console_errors: []};
  const browser = await chromium.launch({executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
                                         args: FLAGS, headless: true});
  let status = 1;
  try {
    const page = await browser.newPage({viewport: {width: o.width, height: o.height}});
    page.on("pageerror", (e) => out.page_errors.push(String(e.stack || e)));
    page.on("console", (m) => { if (m.type() === "error") out.console_errors.push(m.text()); });
    page.on("requestfailed", (r) => out.console_errors.push(`request failed: ${r.url()} ${r.failure() && r.failure().errorText}`));
    const cdp = await page.context().newCDPSession(page);
    await cdp.send("Performance.enable");
    const t0 = Date.now();
    await page.goto(o.url, {waitUntil: "load", timeout: o.timeout});
    try {
      await page.waitForFunction(`window.${flag}Ready || window.${flag}Failed`, null, {timeout: o.timeout, polling: 100});
    } catch (e) {
      out.timeout = String(e.message || e);
    }
    out.ready_ms = Date.now() - t0;
    out.ready = await page.evaluate(`window.${flag}Ready === true`);
    // Cesium's render loop keeps SwiftShader's GPU process busy even in
    // requestRenderMode with nothing to draw, and every later step (the screenshot
    // most) waits behind it. Once ready, the loop stops and the page is drawn once,
    // on request, before the screenshot.
    if (o.mode === "globe") await page.evaluate(() => { if (window.twinGlobe) window.twinGlobe.viewer.useDefaultRenderLoop = false; });
    out.stats = await page.evaluate(`window.${flag}Stats`);
    const metrics = Object.fromEntries((await cdp.send("Performance.getMetrics")).metrics.map((m) => [m.name, m.value]));
    out.memory = {js_heap_used_bytes: metrics.JSHeapUsedSize, js_heap_total_bytes: metrics.JSHeapTotalSize,
                  ...browserMemory()};
    out.webgl = await page.evaluate(() => {
      const gl = document.createElement("canvas").getContext("webgl2");
      const ext = gl && gl.getExtension("WEBGL_debug_renderer_info");
      return gl ? (ext ? gl.getParameter(ext.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER)) : null;
    });
    if (o.eval && out.ready) out.eval = await page.evaluate(fs.readFileSync(o.eval, "utf8"));
    if (o.screenshot) {
      if (o.mode === "globe") await page.evaluate(() => { if (window.twinGlobe) window.twinGlobe.viewer.render(); });
      await page.screenshot({path: o.screenshot, timeout: o.timeout});
    }
    status = out.ready ? 0 : 1;
  } catch (e) {
    out.error = String(e.stack || e);
  } finally {
    await browser.close();
  }
  process.stdout.write(JSON.stringify(out) + "\n");
  process.exitCode = status;
}

main().catch((e) => {
  process.stdout.write(JSON.stringify({error: String(e.stack || e)}) + "\n");
  process.exitCode = 2;
});
