// Opens twin serve's live page in Debian's Chromium (headless) and times how long a
// change of state takes to show: once the page draws SELECTOR (an element whose
// data-angle the page sets from the twin's messages), prints {"ready": true, ...} on a
// line; then, for each line "watch" on stdin, waits until the element's data-angle
// changes and prints {"changed_at_ms": Date.now() when it did, "angle": ...}; "quit" ends.
//
//   node tools/live_check.mjs --url URL --selector CSS [--timeout 30000]

import readline from "node:readline";
import { chromium } from "playwright-core";

const FLAGS = ["--headless", "--no-sandbox", "--disable-background-networking", "--disable-component-update",
  "--no-first-run", "--disable-sync"];

function options(argv) {
  const o = {timeout: 30000};
  for (let i = 2; i < argv.length; i += 2) o[argv[i].replace(/^--/, "")] = argv[i + 1];
  o.timeout = Number(o.timeout);
  return o;
}

function say(data) { process.stdout.write(JSON.stringify(data) + "\n"); }

async function main() {
  const o = options(process.argv);
  const browser = await chromium.launch({executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
                                         args: FLAGS, headless: true});
  const errors = [];
  try {
    const page = await browser.newPage();
    page.on("pageerror", (e) => errors.push(String(e.stack || e)));
    await page.goto(o.url, {waitUntil: "load", timeout: o.timeout});
    await page.waitForFunction((sel) => {
      const el = document.querySelector(sel);
      return el && el.dataset.angle !== undefined;
    }, o.selector, {timeout: o.timeout, polling: 20});
    // the page's own record of each change, in the browser's wall clock
    await page.evaluate((sel) => {
      const el = document.querySelector(sel);
      window.liveChanges = [];
      new MutationObserver(() => window.liveChanges.push({at: Date.now(), angle: Number(el.dataset.angle)}))
        .observe(el, {attributes: true, attributeFilter: ["data-angle"]});
    }, o.selector);
    say({ready: true, angle: Number(await page.evaluate((s) => document.querySelector(s).dataset.angle, o.selector)),
         errors});
    const lines = readline.createInterface({input: process.stdin});
    for await (const line of lines) {
      if (line.trim() === "quit") break;
      const seen = await page.evaluate(() => window.liveChanges.length);
      try {
        await page.waitForFunction((n) => window.liveChanges.length > n, seen, {timeout: o.timeout, polling: "raf"});
        say(await page.evaluate((n) => window.liveChanges[n], seen));
      } catch (e) {
        say({error: String(e.message || e), errors});
      }
    }
  } catch (e) {
    say({error: String(e.stack || e), errors});
    process.exitCode = 1;
  } finally {
    await browser.close();
  }
}

// stdin keeps the event loop alive: leave once done
main().catch((e) => { say({error: String(e.stack || e)}); process.exitCode = 2; }).finally(() => process.exit());
