// Browser test of the dashboard's PID panel: a real headless Chromium (Debian's
// /usr/bin/chromium, driven by playwright-core) against a real daemon (target/release/ftafm
// on a free port, stopped at the end). A unit enabled from the panel holds harmonic 1's
// amplitude at a set-point the physics reaches (the amplitude the daemon reads 2 nm closer
// to the surface), its updates arrive in the table with the new epoch and its output moves;
// a gain of the wrong sign shows the daemon's refusal under the field and changes nothing.
//
//   cargo build --release && (cd tests/e2e && npm ci) && node --test tests/e2e/pids.test.mjs

import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import { launchBrowser } from "./browser.mjs";
import { daemons, startDaemon, stopDaemon } from "./daemon.mjs";

// Hang guards, not margins: the test waits on replies and on the units' update counts.
const WAIT = 60000;
const TEST = { timeout: 180000 };

let daemon, context, page, closeBrowser;
const pageErrors = [];

async function until(fn, arg, what, timeout = WAIT) {
  try {
    return await page.waitForFunction(fn, arg, { timeout, polling: 100 });
  } catch (e) {
    const state = await page.evaluate(() => JSON.stringify(window.ftafm?.pids())).catch(() => "?");
    throw new Error(`timed out after ${timeout} ms waiting for ${what}; PID panel state: ${state}`);
  }
}

/** A request on the page's own connection (what a script beside the dashboard does). */
const request = (op, fields) => page.evaluate(([op, fields]) => window.ftafm.app.conn.request(op, fields), [op, fields]);

before(async () => {
  daemon = await startDaemon("127.0.0.1:0");
  ({ context, page, close: closeBrowser } = await launchBrowser());
  context.setDefaultTimeout(WAIT);
  page.on("pageerror", (e) => pageErrors.push(String(e)));
  await page.goto(daemon.url);
  await page.waitForSelector('#conn[data-state="open"]', { timeout: WAIT });
});

after(async () => {
  await closeBrowser?.().catch((e) => console.warn(`ftafm e2e: closing the browser: ${e}`));
  for (const d of [...daemons]) await stopDaemon({ proc: d });
});

/** Types `text` into the PID control of node `key` and presses Enter. */
async function type(key, text) {
  const field = page.locator(`#pid-controls input[data-path="/pids/0/${key}"]`);
  await field.fill(text);
  await field.press("Enter");
}

test("a unit enabled from the panel runs, shows its updates, and a bad gain is refused", TEST, async (t) => {
  await page.locator("#p-pids").scrollIntoViewIfNeeded();
  await until(() => document.querySelector('#pid-controls input[data-path="/pids/0/setpoint"]')?.value, null, "the PID controls built from list");
  await until(() => window.ftafm.pids().pids?.length === 4, null, "the four units from status");
  assert.equal(await page.textContent('#pids-table tr[data-unit="0"] td[data-key="enable"]'), "off");
  assert.equal(await page.textContent('#pids-table tr[data-unit="0"] td[data-key="updates"]'), "–");

  // The set-point: harmonic 1's amplitude with the surface at 18 nm, read from the lock-in.
  const near = await request("set", { path: "/surface/distance", value: 18e-9 });
  await until((t) => window.ftafm.app.history.tNow >= t + 0.3, near.t, "0.3 s of data at 18 nm");
  const setpoint = await page.evaluate(() => window.ftafm.amplitude(1));
  const far = await request("set", { path: "/surface/distance", value: 20e-9 });
  await until((t) => window.ftafm.app.history.tNow >= t + 0.3, far.t, "0.3 s of data at 20 nm");
  assert.ok(setpoint > 5e-9 && setpoint < (await page.evaluate(() => window.ftafm.amplitude(1))), `set-point ${setpoint}`);

  await type("setpoint", `${setpoint}`);
  await until((v) => window.ftafm.app.nodes.get("/pids/0/setpoint")?.value === v, setpoint, "the set-point's reply");
  await page.locator('#pid-controls input[type="checkbox"][data-path="/pids/0/enable"]').check();
  await until(() => window.ftafm.app.nodes.get("/pids/0/enable")?.value === true && window.ftafm.app.lastSet?.path === "/pids/0/enable", null, "the enable's reply");
  assert.equal((await request("get", { path: "/pids/0/enable" })).value, true);

  // Updates arrive: the first under the settings that enabled it, then later ones.
  const first = await until(() => {
    const u = window.ftafm.pids().pids?.[0];
    return u?.enable && u.latest ? u.latest : null;
  }, null, "the unit's first update").then((h) => h.jsonValue());
  const later = await until((n) => {
    const l = window.ftafm.pids().pids?.[0]?.latest;
    return l && l.updates >= n + 2000 ? l : null;
  }, first.updates, "2000 more updates (20 ms at 100 kHz)").then((h) => h.jsonValue());
  t.diagnostic(`first ${JSON.stringify(first)}, later ${JSON.stringify(later)}`);
  // Made under the settings the panel's changes started (after the last change before them).
  assert.ok(first.epoch > far.epoch, `first update's epoch ${first.epoch}, before the panel's sets ${far.epoch}`);
  assert.ok(later.epoch >= first.epoch);
  assert.notEqual(later.output, 20e-9, "the output moved");
  assert.ok(Math.abs(later.output - 18e-9) < 0.5e-9, `holds ${later.output} m, the physics says 18 nm`);
  assert.ok(Math.abs(later.error) < 0.01 * setpoint, `error ${later.error}`);
  // The table shows it.
  await until((n) => Number(document.querySelector('#pids-table tr[data-unit="0"] td[data-key="updates"]')?.textContent) >= n, later.updates, "the table's row drawn");
  assert.equal(await page.textContent('#pids-table tr[data-unit="0"] td[data-key="enable"]'), "on");
  assert.match(await page.textContent('#pids-table tr[data-unit="0"] td[data-key="output"]'), /^1[78]\.\d+ nm$/);
  assert.match(await page.textContent('#pids-table tr[data-unit="0"] td[data-key="epoch"]'), /^\d+$/);
  // The strip chart has the unit's updates from two status messages or more.
  await until(() => window.ftafm.pids().trace >= 2 && window.ftafm.stats.draws.pids > 0, null, "two points of the strip chart drawn");

  // A proportional gain of the other sign than I (1200/s): refused, the message under the
  // field, the node unchanged.
  const rejects = await page.evaluate(() => window.ftafm.stats.rejects);
  await type("p", "-0.5");
  await until((n) => window.ftafm.stats.rejects > n, rejects, "the refusal");
  const error = await page.textContent('#pid-controls .error[data-for="/pids/0/p"]');
  t.diagnostic(error);
  assert.match(error, /\/pids\/0\/p/);
  assert.equal((await request("get", { path: "/pids/0/p" })).value, 0);
  assert.equal(await page.inputValue('#pid-controls input[data-path="/pids/0/p"]'), "0");

  // Disabled from the panel: the updates stop (the count holds over a later status).
  await page.locator('#pid-controls input[type="checkbox"][data-path="/pids/0/enable"]').uncheck();
  const off = await until(() => {
    const s = window.ftafm.pids();
    return s.pids?.[0] && !s.pids[0].enable ? { t: s.t, updates: s.pids[0].latest.updates } : null;
  }, null, "the unit reported off").then((h) => h.jsonValue());
  await until((t0) => window.ftafm.pids().t > t0, off.t, "a later status");
  assert.equal(await page.evaluate(() => window.ftafm.pids().pids[0].latest.updates), off.updates);
  assert.deepEqual(pageErrors, []);
});
