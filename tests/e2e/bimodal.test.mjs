// Browser test of the dashboard's bimodal controls: a real headless Chromium (Debian's
// /usr/bin/chromium, driven by playwright-core) against a real daemon (target/release/ftafm
// on a free port, stopped at the end). The second excitation is switched on, its frequency
// and amplitude typed in their units, and a demodulator put on it from the demodulator
// controls: the daemon holds each value, the harmonics chips and table name the demodulator
// a harmonic of drive2 ("f₂×4", "4 of drive2"), also when a script beside the page changes
// another's oscillator. A frequency above Nyquist while drive2 runs, and the paper engine
// (which drive2 does not run on), are refused with the daemon's message under the field.
//
//   cargo build --release && (cd tests/e2e && npm ci) && node --test tests/e2e/bimodal.test.mjs
//
// FTAFM_E2E_WEB=<dir> (e.g. ../../web) serves the page's modules and style from that
// directory instead of the daemon's embedded copies (index.html stays the daemon's).

import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import { launchBrowser, serveWebFrom } from "./browser.mjs";
import { daemons, startDaemon, stopDaemon } from "./daemon.mjs";

// Hang guards, not margins: the test waits on replies and on the page's redraws.
const WAIT = 60000;
const TEST = { timeout: 180000 };

let daemon, context, page, closeBrowser;
const pageErrors = [];

async function until(fn, arg, what, timeout = WAIT) {
  try {
    return await page.waitForFunction(fn, arg, { timeout, polling: 100 });
  } catch (e) {
    const state = await page.evaluate(() => JSON.stringify({ state: window.ftafm?.stats.state, oscillators: window.ftafm?.app.history.oscillator })).catch(() => "?");
    throw new Error(`timed out after ${timeout} ms waiting for ${what}; page: ${state}`);
  }
}

/** A request on the page's own connection (what a script beside the dashboard does). */
const request = (op, fields) => page.evaluate(([op, fields]) => window.ftafm.app.conn.request(op, fields), [op, fields]);
const get = async (p) => (await request("get", { path: p })).value;

before(async () => {
  daemon = await startDaemon("127.0.0.1:0");
  ({ context, page, close: closeBrowser } = await launchBrowser());
  context.setDefaultTimeout(WAIT);
  page.on("pageerror", (e) => pageErrors.push(String(e)));
  await serveWebFrom(page, daemon.url);
  await page.goto(daemon.url);
  await page.waitForSelector('#conn[data-state="open"]', { timeout: WAIT });
});

after(async () => {
  await closeBrowser?.().catch((e) => console.warn(`ftafm e2e: closing the browser: ${e}`));
  for (const d of [...daemons]) await stopDaemon({ proc: d });
});

/** Types `text` into the control of node `p`, presses Enter and waits for the reply (the
 * node list holding `value`, to a part in 1e9). */
async function typeAndWait(p, text, value) {
  const field = page.locator(`#controls input[data-path="${p}"]`);
  await field.fill(text);
  await field.press("Enter");
  await until(([p, v]) => {
    const x = window.ftafm.app.nodes.get(p)?.value;
    return typeof x === "number" && Math.abs(x - v) <= 1e-9 * Math.abs(v);
  }, [p, value], `the reply to ${p} = ${text}`);
}

/** Types a refused `text` into node `p`'s control; the message shown under it. */
async function refused(p, text) {
  const rejects = await page.evaluate(() => window.ftafm.stats.rejects);
  const field = page.locator(`#controls [data-path="${p}"]:is(input, select)`);
  if (await field.evaluate((el) => el.tagName === "SELECT")) await field.selectOption(text);
  else {
    await field.fill(text);
    await field.press("Enter");
  }
  await until((n) => window.ftafm.stats.rejects > n, rejects, `the refusal of ${p} = ${text}`);
  await until((p) => document.querySelector(`#controls .error[data-for="${p}"]`)?.textContent.length > 0, p, "the message under the field");
  return page.textContent(`#controls .error[data-for="${p}"]`);
}

test("the second drive and a demodulator on it, set from the page", TEST, async (t) => {
  // The controls, built from list: off, at the lever's second resonance, 1 nm.
  const freq = page.locator('#controls input[data-path="/drive2/frequency"]');
  await freq.waitFor();
  assert.match(await freq.inputValue(), /^626\.6\d* kHz$/);
  assert.equal(await page.inputValue('#controls input[data-path="/drive2/free_amplitude"]'), "1 nm");
  assert.equal(await page.isChecked('#controls input[type="checkbox"][data-path="/drive2/enable"]'), false);
  const range = await page.textContent('#controls .ctl[data-path="/drive2/frequency"] .range');
  assert.match(range, /f₂/, `the range names the symbol: ${range}`);

  // Switched on, its frequency and amplitude typed in their units: the daemon holds them.
  await page.locator('#controls input[type="checkbox"][data-path="/drive2/enable"]').check();
  await until(() => window.ftafm.app.nodes.get("/drive2/enable")?.value === true, null, "the enable's reply");
  await typeAndWait("/drive2/frequency", "700 kHz", 700e3);
  await typeAndWait("/drive2/free_amplitude", "2 nm", 2e-9);
  assert.equal(await get("/drive2/enable"), true);
  assert.equal(await get("/drive2/frequency"), 700e3);
  assert.equal(await get("/drive2/free_amplitude"), 2e-9);
  assert.equal(await freq.inputValue(), "700 kHz");
  await until(() => document.querySelector("#spec-foot")?.textContent.includes("· drive2 700.0 kHz"), null, "the spectrum's foot naming drive2");

  // Demodulator 3 from the demodulator controls: its oscillator beside its harmonic.
  const k = await get("/demods/3/harmonic");
  await page.selectOption("#demod-select", "3");
  const osc = page.locator('#controls select[data-path="/demods/3/oscillator"]');
  await osc.waitFor();
  const options = await osc.evaluate((s) => [...s.options].map((o) => o.value));
  assert.deepEqual(options, ["drive", "drive2"]);
  assert.equal(await osc.inputValue(), "drive");
  await osc.selectOption("drive2");
  await until(() => window.ftafm.app.nodes.get("/demods/3/oscillator")?.value === "drive2", null, "the oscillator's reply");
  assert.equal(await get("/demods/3/oscillator"), "drive2");
  assert.equal(await get("/demods/4/oscillator"), "drive", "only demodulator 3");
  assert.match(await page.textContent('#demod-select option[value="3"]'), new RegExp(`harmonic ${k} of drive2`));

  // The harmonics panel names it a harmonic of drive2, in the chip and in the table.
  const chip = (i) => `#harm-chips .chip[data-index="${i}"]`;
  await until(([sel, k]) => document.querySelector(sel)?.textContent === `f₂×${k}`, [chip(3), k], "demodulator 3's chip relabelled");
  assert.equal(await page.getAttribute(chip(3), "data-oscillator"), "drive2");
  assert.match(await page.getAttribute(chip(3), "title"), new RegExp(`harmonic ${k} of drive2`));
  assert.equal(await page.textContent(chip(4)), String(await get("/demods/4/harmonic")), "the others plain");
  if (!(await page.getAttribute(chip(3), "class")).includes(" on")) await page.click(chip(3));
  const cell = '#harm-table tr[data-index="3"] td:nth-child(3)';
  await until(([sel, k]) => document.querySelector(sel)?.textContent === `${k} of drive2`, [cell, k], "the table's row for demodulator 3");
  // Harmonic k of the drive is not demodulator 3's any more (the readouts skip it).
  assert.notEqual(await page.evaluate((k) => window.ftafm.app.history.indexOf(k), k), 3);

  // A script beside the page puts demodulator 1 on drive2: the chip follows (the page
  // re-reads the oscillators every 3 s).
  await request("set", { path: "/demods/1/oscillator", value: "drive2" });
  const k1 = await get("/demods/1/harmonic");
  await until(([sel, k]) => document.querySelector(sel)?.textContent === `f₂×${k}`, [chip(1), k1], "demodulator 1's chip relabelled");

  // Refusals: the daemon's message under the field, the value unchanged.
  const above = await refused("/drive2/frequency", "6 MHz");
  t.diagnostic(above);
  assert.match(above, /\/drive2\/frequency/);
  assert.match(above, /Nyquist/);
  assert.equal(await freq.inputValue(), "700 kHz", "reverted to the daemon's value");
  assert.equal(await get("/drive2/frequency"), 700e3);
  const paper = await refused("/synth/engine", "paper");
  t.diagnostic(paper);
  assert.match(paper, /\/drive2\/enable/);
  assert.equal(await get("/synth/engine"), "coupled");
  assert.equal(await page.inputValue('#controls select[data-path="/synth/engine"]'), "coupled");

  // Back on the drive from the page: the plain harmonic again.
  await osc.selectOption("drive");
  await until(() => window.ftafm.app.nodes.get("/demods/3/oscillator")?.value === "drive", null, "the oscillator's reply");
  await until(([sel, k]) => document.querySelector(sel)?.textContent === String(k), [chip(3), k], "demodulator 3's chip back to its harmonic");
  assert.equal(await get("/demods/3/oscillator"), "drive");
  assert.deepEqual(pageErrors, []);
});
