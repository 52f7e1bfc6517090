// Browser test of the dashboard's sweeper panel: a real headless Chromium (Debian's
// /usr/bin/chromium, driven by playwright-core) against a real daemon (target/release/ftafm
// on a free port, the tip far from the surface for a free tune, stopped at the end).
//
//   cargo build --release && (cd tests/e2e && npm ci) && node --test tests/e2e/sweeper.test.mjs

import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import path from "node:path";
import { launchBrowser } from "./browser.mjs";
import { daemons, startDaemon, stopDaemon } from "./daemon.mjs";

// Waits are generous: on a loaded machine the daemon runs below real time.
const WAIT = 60000;
const TEST = { timeout: 120000 };
const OVERLAY = `# e2e: a free tune
[surface]
distance = 200e-9
`;

let daemon, context, page, work, closeBrowser;
const pageErrors = [];

async function until(fn, arg, what, timeout = WAIT) {
  try {
    return await page.waitForFunction(fn, arg, { timeout, polling: 100 });
  } catch (e) {
    const state = await page.evaluate(() => JSON.stringify({ stats: { ...window.ftafm?.stats, latency: undefined },
      sweep: { ...window.ftafm?.sweep(), csv: undefined, points: window.ftafm?.sweep().points.length } })).catch(() => "?");
    throw new Error(`timed out after ${timeout} ms waiting for ${what}; page state: ${state}`);
  }
}

before(async () => {
  work = mkdtempSync(path.join(tmpdir(), "ftafm-e2e-sweep-"));
  const overlay = path.join(work, "free.toml");
  writeFileSync(overlay, OVERLAY);
  daemon = await startDaemon("127.0.0.1:0", ["--config", overlay]);
  ({ context, page, close: closeBrowser } = await launchBrowser({ acceptDownloads: true }));
  context.setDefaultTimeout(WAIT); // every action (click, fill, scroll) too: a hang guard
  page.on("pageerror", (e) => pageErrors.push(String(e)));
  await page.goto(daemon.url);
  await page.waitForSelector('#conn[data-state="open"]', { timeout: WAIT });
});

after(async () => {
  // A browser that fails to close must not keep the daemon (and the test file) alive.
  await closeBrowser?.().catch((e) => console.warn(`ftafm e2e: closing the browser: ${e}`));
  for (const d of [...daemons]) await stopDaemon({ proc: d });
  if (work) rmSync(work, { recursive: true, force: true });
});

test("a tune run from the panel shows the resonance, its fit, and exports as CSV", TEST, async (t) => {
  await page.locator("#p-sweep").scrollIntoViewIfNeeded();
  await until(() => document.getElementById("sw-start").value !== "", null, "the sweeper set-up read from the daemon");
  assert.equal(await page.inputValue("#sw-parameter"), "/drive/frequency");
  await page.fill("#sw-start", "99500");
  await page.fill("#sw-stop", "100500");
  await page.fill("#sw-points", "41");
  await page.click("#sw-run");
  await until(() => window.ftafm.sweep().final?.outcome === "done", null, "the tune to finish");
  const sweep = await page.evaluate(() => window.ftafm.sweep());
  assert.equal(sweep.points.length, 41);
  assert.equal(sweep.running, false);
  const f0 = sweep.final.tune.f0;
  t.diagnostic(`f0 = ${f0} Hz, Q = ${sweep.final.tune.q}`);
  assert.ok(Math.abs(f0 / 100e3 - 1) < 5e-4, `f0 ${f0}`);
  const result = await page.textContent("#sw-result");
  assert.match(result, /^f0 = 100\.0\d* kHz, Q = (9\d|10\d)\.\d, phase at f0 −?-?9\d\.\d°$/);
  assert.match(await page.textContent("#sw-progress"), /^done: 41 of 41 points, node restored$/);
  // A page behind its messages draws at most twice a second: the plots may follow the text.
  await until(() => window.ftafm.stats.draws.sweep > 0, null, "the plots drawn");
  // the export is the points as CSV
  const [download] = await Promise.all([page.waitForEvent("download"), page.click("#sw-csv")]);
  const csv = readFileSync(await download.path(), "utf8").trim().split("\n");
  assert.match(download.suggestedFilename(), /^ftafm-sweep-\d+\.csv$/);
  assert.equal(csv.length, 2 + 41);
  assert.match(csv[1], /^value,leg,h1_phase_to_drive_rad,mean_deflection_m,max_force_N,max_force_sigma_N,contact_time_ratio,contact_time_ratio_sigma,youngs_modulus_Pa,youngs_modulus_sigma_Pa,r_demod0_h1_m,phase_demod0_h1_rad,/);
  assert.equal(Number(csv[2].split(",")[0]), 99500);
  assert.equal(csv[2].split(",")[1], "up");
});

test("an approach run from the panel can be aborted; a bad range is shown, not run", TEST, async () => {
  await page.selectOption("#sw-parameter", "/surface/distance");
  assert.equal(await page.inputValue("#sw-direction"), "both", "an approach suggests both legs");
  await page.fill("#sw-points", "3000");
  await page.click("#sw-run");
  await until(() => window.ftafm.sweep().points.length >= 3, null, "approach points");
  // The panel updates its controls when it draws, which a busy machine may delay.
  await until(() => !document.getElementById("sw-abort").disabled, null, "the abort button enabled");
  await page.click("#sw-abort");
  await until(() => window.ftafm.sweep().final?.outcome === "aborted", null, "the abort");
  await until(() => document.getElementById("sw-progress").textContent.startsWith("aborted"), null, "the progress to say aborted");
  assert.match(await page.textContent("#sw-progress"), /^aborted: \d+ of 6000 points, node restored$/);
  await page.fill("#sw-start", "-1e-9");
  await page.click("#sw-run");
  await until(() => document.getElementById("sw-result").textContent.includes("/sweeper/start"), null, "the refusal");
  assert.equal(await page.evaluate(() => window.ftafm.sweep().running), false);
  assert.deepEqual(pageErrors, []);
});

test("the sweep's ends and its refusals are in the swept node's units", TEST, async () => {
  // The approach's suggested ends, as a user reads and types them.
  await page.selectOption("#sw-parameter", "/drive/frequency");
  await page.selectOption("#sw-parameter", "/surface/distance");
  assert.equal(await page.inputValue("#sw-start"), "40 nm");
  assert.equal(await page.inputValue("#sw-stop"), "8 nm");
  const refusal = async (start, what) => {
    await page.fill("#sw-start", start);
    await page.click("#sw-run");
    await until(() => document.getElementById("sw-result").textContent.includes("/sweeper/start"), null, what);
    return page.textContent("#sw-result");
  };
  const distance = await refusal("-1 nm", "the distance's refusal");
  assert.match(distance, /^\/sweeper\/start = -1 nm is outside the range of \/sweeper\/parameter = \/surface\/distance now: allowed 0 < value ≤ \d+(\.\d+)? [µm]m$/, distance);
  // A modulus typed with its prefix, refused with prefixes: no raw exponents.
  await page.selectOption("#sw-parameter", "/sample/youngs_modulus");
  await page.fill("#sw-stop", "100 GPa");
  const modulus = await refusal("-5 GPa", "the modulus's refusal");
  assert.match(modulus, /^\/sweeper\/start = -5 GPa is outside the range of \/sweeper\/parameter = \/sample\/youngs_modulus now: allowed 0 < value ≤ 10 TPa$/, modulus);
  assert.doesNotMatch(modulus, /\de[+-]?\d/);
  // What cannot be read is said before anything is sent.
  await page.fill("#sw-start", "5 parsecs");
  await page.click("#sw-run");
  assert.match(await page.textContent("#sw-result"), /cannot read the unit “parsecs”/);
  assert.equal(await page.evaluate(() => window.ftafm.sweep().running), false);
  assert.deepEqual(pageErrors, []);
});
