// Browser test of the dashboard's PID panel: a real headless Chromium (Debian's
// /usr/bin/chromium, driven by playwright-core) against a real daemon (target/release/ftafm
// on a free port, stopped at the end). A unit enabled from the panel holds harmonic 1's
// amplitude at a set-point the physics reaches (the amplitude the daemon reads 2 nm closer
// to the surface), its updates arrive in the table with the new epoch and its output moves;
// a gain of the wrong sign shows the daemon's refusal under the field and changes nothing.
// A PLL set up and enabled from the panel (unit 1 on the phase of harmonic 1, its output
// the drive frequency chosen in the selector, its limits typed in Hz) locks the drive to
// the free lever's resonance from 1 % off it: the table shows it locked, its frequency
// shift Δf and its output in kHz, the foot names the drive frequency as held by a loop,
// and an upper limit beyond the drive frequency's range is refused under its field.
// Mode 2's PLL set up from the panel (unit 2 on the phase of harmonic 1 of oscillator
// "drive2", its output drive2_frequency): enabled while the second excitation is off, it is
// refused under the enable field, naming /pids/2/oscillator; with the excitation switched on
// from the bimodal controls and started 0.4 % above mode 2's resonance, it locks there:
// the row reads "phase H1 of drive2 → drive2_frequency", locked, and Δf₂ from
// /drive2/frequency; with /drive2/frequency set to the resonance, Δf₂ near 0.
//
//   cargo build --release && (cd tests/e2e && npm ci) && node --test tests/e2e/pids.test.mjs
//
// FTAFM_E2E_WEB=<dir> (e.g. ../../web) serves the page's modules and style from that
// directory instead of the daemon's embedded copies (index.html stays the daemon's): for a
// change of web/ tested against a daemon built before it. By default the test runs the
// dashboard the binary carries.

import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import { launchBrowser, serveWebFrom } from "./browser.mjs";
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
  await serveWebFrom(page, daemon.url);
  await page.goto(daemon.url);
  await page.waitForSelector('#conn[data-state="open"]', { timeout: WAIT });
});

after(async () => {
  await closeBrowser?.().catch((e) => console.warn(`ftafm e2e: closing the browser: ${e}`));
  for (const d of [...daemons]) await stopDaemon({ proc: d });
});

/** Types `text` into the PID control of node `key` of unit `unit` and presses Enter. */
async function type(key, text, unit = 0) {
  const field = page.locator(`#pid-controls input[data-path="/pids/${unit}/${key}"]`);
  await field.fill(text);
  await field.press("Enter");
}

/** Types `text` into unit `unit`'s field `key` and waits for the daemon's reply: the node
 * list holding `value` (to a part in 1e9: the field's decimal text). */
async function typeAndWait(key, text, value, unit) {
  await type(key, text, unit);
  const p = `/pids/${unit}/${key}`;
  await until(([p, v]) => {
    const x = window.ftafm.app.nodes.get(p)?.value;
    return typeof x === "number" && Math.abs(x - v) <= 1e-9 * Math.abs(v);
  }, [p, value], `the reply to ${p} = ${text}`);
}

/** Chooses `value` in unit `unit`'s select `key` and waits for the daemon's reply. */
async function choose(key, value, unit) {
  const p = `/pids/${unit}/${key}`;
  await page.selectOption(`#pid-controls select[data-path="${p}"]`, value);
  await until(([p, v]) => window.ftafm.app.nodes.get(p)?.value === v, [p, value], `the reply to ${p} = ${value}`);
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

test("a PLL set up and enabled from the panel locks to the resonance, and the panel shows it", TEST, async (t) => {
  await page.locator("#p-pids").scrollIntoViewIfNeeded();
  await until(() => window.ftafm.pids().pids?.length === 4, null, "the four units from status");
  const f1 = (await request("get", { path: "/cantilever/f1" })).value;
  const q = (await request("get", { path: "/cantilever/q" })).value[0];
  const drive = 1.01 * f1;
  // The free lever driven 1 % above its resonance (what a script beside the dashboard sets).
  await request("set", { values: { "/surface/distance": 1e-6, "/drive/free_amplitude": 10e-9, "/drive/follow_f1": false, "/drive/frequency": drive } });

  // Unit 1 from the select; its output selector offers the five outputs.
  await page.selectOption("#pid-select", "1");
  await until(() => window.ftafm.pids().unit === 1 && document.querySelector('#pid-controls select[data-path="/pids/1/output"]'), null, "unit 1's controls");
  const outputs = await page.$$eval('#pid-controls select[data-path="/pids/1/output"] option', (os) => os.map((o) => o.value));
  assert.deepEqual([...outputs].sort(), ["drive2_amplitude", "drive2_frequency", "drive_amplitude", "drive_frequency", "surface_distance"]);
  await choose("output", "drive_frequency", 1);
  await choose("input", "phase", 1);
  // The limits and the rate follow the output: hertz now, the set-point radians.
  await until(() => ["output_min", "output_max"].every((k) => document.querySelector(`#pid-controls input[data-path="/pids/1/${k}"]`)?.value.endsWith("Hz")) &&
    document.querySelector('#pid-controls input[data-path="/pids/1/rate"]')?.value.endsWith("Hz/s") &&
    document.querySelector('#pid-controls input[data-path="/pids/1/setpoint"]')?.value.endsWith("rad"), null, "the fields in Hz, Hz/s and rad");

  // PI gains for a 500 Hz crossover on the lever's phase response (tests/pll.rs).
  const i = (-2 * Math.PI * 500) / ((2 * q) / f1);
  const p = (i * q) / (Math.PI * f1);
  await typeAndWait("setpoint", `${Math.PI}`, Math.PI, 1);
  await typeAndWait("i", `${i}`, i, 1);
  await typeAndWait("p", `${p}`, p, 1);
  await typeAndWait("output_min", `${(0.98 * f1) / 1e3} kHz`, 0.98 * f1, 1);
  await typeAndWait("output_max", `${(1.02 * f1) / 1e3} kHz`, 1.02 * f1, 1);
  await page.locator('#pid-controls input[type="checkbox"][data-path="/pids/1/enable"]').check();
  await until(() => window.ftafm.app.nodes.get("/pids/1/enable")?.value === true, null, "the enable's reply");

  // Locked: the table says so after 2000 updates (20 ms at 100 kHz, a few times the lock's).
  const first = await until(() => {
    const u = window.ftafm.pids().pids?.[1];
    return u?.enable && u.output === "drive_frequency" && u.latest ? u.latest : null;
  }, null, "the PLL's first update").then((h) => h.jsonValue());
  const locked = await until((n) => {
    const u = window.ftafm.pids().pids?.[1];
    return u?.latest && u.latest.updates >= n + 2000 && u.locked === true ? u : null;
  }, first.updates, "the PLL locked, 2000 updates on").then((h) => h.jsonValue());
  t.diagnostic(`locked: ${JSON.stringify(locked)}`);
  assert.ok(Math.abs(locked.latest.output - f1) < 20, `the PLL at ${locked.latest.output} Hz, f1 = ${f1} Hz`);
  assert.ok(Math.abs(locked.frequency_shift - (locked.latest.output - drive)) < 1e-6, `Δf ${locked.frequency_shift} Hz`);
  await until((n) => Number(document.querySelector('#pids-table tr[data-unit="1"] td[data-key="updates"]')?.textContent) >= n &&
    document.querySelector('#pids-table tr[data-unit="1"] td[data-key="locked"]')?.textContent === "locked", locked.latest.updates, "the table's row drawn locked");
  const cell = (key) => page.textContent(`#pids-table tr[data-unit="1"] td[data-key="${key}"]`);
  const shown = { route: await cell("route"), output: await cell("output"), shift: await cell("frequency_shift") };
  t.diagnostic(JSON.stringify(shown));
  assert.equal(shown.route, "phase H1 → drive_frequency");
  assert.match(shown.output, /^(99\.9\d+|100\.0\d+) kHz$/);
  assert.match(shown.shift, /^−(99\d\.\d+ |1\.00\d+ k)Hz$/);
  assert.equal(await page.textContent('#pids-table tr[data-unit="0"] td[data-key="locked"]'), "–", "unit 0 is no PLL");
  // The foot names the output the loop holds.
  await until(() => document.querySelector("#pids-held")?.textContent.includes("drive_frequency"), null, "the held output named");
  assert.match(await page.textContent("#pids-held"), /held by a loop: drive_frequency/);
  assert.equal((await request("get", { path: "/drive/frequency" })).value, drive, "the node is left alone");

  // An upper limit beyond the drive frequency's range (below sample_rate / 2 / 32): refused
  // under its field, naming the node; the limit unchanged.
  const rejects = await page.evaluate(() => window.ftafm.stats.rejects);
  await type("output_max", "1 MHz", 1);
  await until((n) => window.ftafm.stats.rejects > n, rejects, "the refusal");
  const error = await page.textContent('#pid-controls .error[data-for="/pids/1/output_max"]');
  t.diagnostic(error);
  assert.match(error, /\/pids\/1\/output_max/);
  assert.equal((await request("get", { path: "/pids/1/output_max" })).value, 1.02 * f1);

  // Off from the panel, and the drive frequency's node set: the loop no longer holds it.
  await page.locator('#pid-controls input[type="checkbox"][data-path="/pids/1/enable"]').uncheck();
  await until(() => window.ftafm.pids().pids?.[1]?.enable === false, null, "the unit reported off");
  await request("set", { path: "/drive/frequency", value: f1 });
  await until(() => window.ftafm.pids().held?.length === 0 && !document.querySelector("#pids-held"), null, "no output held");
  assert.deepEqual(pageErrors, []);
});

test("mode 2's PLL set up from the panel on the second excitation locks, and the panel shows it", TEST, async (t) => {
  await page.locator("#p-pids").scrollIntoViewIfNeeded();
  await until(() => window.ftafm.pids().pids?.length === 4, null, "the four units from status");
  const f2 = await (async () => (await request("get", { path: "/drive2/frequency" })).value)();
  assert.equal(f2, 626.689e3, "the default lever's f2 (ftafm info)");
  assert.equal((await request("get", { path: "/drive2/enable" })).value, false);
  await request("set", { values: { "/surface/distance": 1e-6 } });

  // Unit 2: the oscillator and the input bandwidth among its controls, built from list.
  await page.selectOption("#pid-select", "2");
  await until(() => window.ftafm.pids().unit === 2 && document.querySelector('#pid-controls select[data-path="/pids/2/oscillator"]') &&
    document.querySelector('#pid-controls input[data-path="/pids/2/input_bandwidth"]')?.value, null, "unit 2's controls");
  const oscillators = await page.$$eval('#pid-controls select[data-path="/pids/2/oscillator"] option', (os) => os.map((o) => o.value));
  assert.deepEqual(oscillators, ["drive", "drive2"]);
  assert.equal(await page.inputValue('#pid-controls input[data-path="/pids/2/input_bandwidth"]'), "2 kHz");
  await choose("oscillator", "drive2", 2);
  await choose("input", "phase", 2);
  await choose("output", "drive2_frequency", 2);
  await until(() => ["output_min", "output_max"].every((k) => document.querySelector(`#pid-controls input[data-path="/pids/2/${k}"]`)?.value.endsWith("Hz")),
    null, "the limits in Hz");
  await typeAndWait("input_bandwidth", "1.5 kHz", 1500, 2);
  await typeAndWait("input_bandwidth", "2 kHz", 2000, 2);
  // PI gains for a 300 Hz crossover on mode 2's phase response (tests/bimodal_loops.rs).
  const q2 = 417;
  const i = (-2 * Math.PI * 300) / ((2 * q2) / f2);
  const p = (i * q2) / (Math.PI * f2);
  await typeAndWait("i", `${i}`, i, 2);
  await typeAndWait("p", `${p}`, p, 2);
  await typeAndWait("output_min", `${(0.99 * f2) / 1e3} kHz`, 0.99 * f2, 2);
  await typeAndWait("output_max", `${(1.01 * f2) / 1e3} kHz`, 1.01 * f2, 2);

  // Enabled while the second excitation is off: refused under the field, naming the node.
  const enable = page.locator('#pid-controls input[type="checkbox"][data-path="/pids/2/enable"]');
  const rejects = await page.evaluate(() => window.ftafm.stats.rejects);
  await enable.click(); // not check(): the box goes back off with the refusal
  await until((n) => window.ftafm.stats.rejects > n, rejects, "the refusal");
  const error = await page.textContent('#pid-controls .error[data-for="/pids/2/enable"]');
  t.diagnostic(error);
  assert.match(error, /\/pids\/2\/oscillator = "drive2".*\/drive2\/enable/);
  assert.equal((await request("get", { path: "/pids/2/enable" })).value, false);
  await until(() => !document.querySelector('#pid-controls input[type="checkbox"][data-path="/pids/2/enable"]').checked, null, "the box back off");

  // The second excitation on from the bimodal controls; the set-point is the phase mode 2
  // reads at its resonance, from a demodulator on drive2 (a script beside the page).
  await page.locator('#controls input[type="checkbox"][data-path="/drive2/enable"]').check();
  await until(() => window.ftafm.app.nodes.get("/drive2/enable")?.value === true, null, "the second excitation on");
  const on = await request("set", { values: { "/demods/7/enable": true, "/demods/7/oscillator": "drive2", "/demods/7/harmonic": 1 } });
  await until((t) => window.ftafm.app.history.tNow >= t + 0.3, on.t, "0.3 s of data on drive2");
  const setpoint = await page.evaluate(() => window.ftafm.app.history.mean(7, 0.2).phase);
  t.diagnostic(`mode 2's phase at f2: ${setpoint} rad`);
  assert.ok(Number.isFinite(setpoint));
  await type("setpoint", `${setpoint}`, 2);
  await until((v) => Math.abs(window.ftafm.app.nodes.get("/pids/2/setpoint")?.value - v) <= 1e-12, setpoint, "the set-point's reply");

  // Started 0.4 % above the resonance (2.7 of mode 2's linewidths).
  const off = 1.004 * f2;
  await request("set", { path: "/drive2/frequency", value: off });
  await enable.check();
  await until(() => window.ftafm.app.nodes.get("/pids/2/enable")?.value === true, null, "the enable's reply");
  const first = await until(() => {
    const u = window.ftafm.pids().pids?.[2];
    return u?.enable && u.oscillator === "drive2" && u.latest ? u.latest : null;
  }, null, "mode 2's PLL's first update").then((h) => h.jsonValue());
  const locked = await until((n) => {
    const u = window.ftafm.pids().pids?.[2];
    return u?.latest && u.latest.updates >= n + 2000 && u.locked === true ? u : null;
  }, first.updates, "mode 2's PLL locked, 2000 updates on").then((h) => h.jsonValue());
  t.diagnostic(`locked: ${JSON.stringify(locked)}`);
  assert.ok(Math.abs(locked.latest.output - f2) < 10, `mode 2's PLL at ${locked.latest.output} Hz, f2 = ${f2} Hz`);
  assert.ok(Math.abs(locked.frequency_shift - (locked.latest.output - off)) < 1e-6, `Δf₂ ${locked.frequency_shift} Hz`);
  await until((n) => Number(document.querySelector('#pids-table tr[data-unit="2"] td[data-key="updates"]')?.textContent) >= n &&
    document.querySelector('#pids-table tr[data-unit="2"] td[data-key="locked"]')?.textContent === "locked", locked.latest.updates, "the table's row drawn locked");
  const cell = (key) => page.textContent(`#pids-table tr[data-unit="2"] td[data-key="${key}"]`);
  const shown = { route: await cell("route"), output: await cell("output"), shift: await cell("frequency_shift") };
  t.diagnostic(JSON.stringify(shown));
  assert.equal(shown.route, "phase H1 of drive2 → drive2_frequency");
  assert.match(shown.output, /^626\.6\d+ kHz$/);
  assert.match(shown.shift, /^−2\.50\d+ kHz$/);
  await until(() => document.querySelector("#pids-held")?.textContent.includes("drive2_frequency"), null, "the held output named");

  // /drive2/frequency set to the resonance: the PLL holds it there, Δf₂ near 0.
  const back = await request("set", { path: "/drive2/frequency", value: f2 });
  const near = await until(([n, epoch]) => {
    const u = window.ftafm.pids().pids?.[2];
    return u?.latest && u.latest.epoch >= epoch && u.latest.updates >= n + 2000 && u.locked === true ? u : null;
  }, [locked.latest.updates, back.epoch], "mode 2's PLL locked at f2").then((h) => h.jsonValue());
  t.diagnostic(`at f2: ${JSON.stringify(near)}`);
  assert.ok(Math.abs(near.frequency_shift) < 10, `Δf₂ ${near.frequency_shift} Hz at f2`);
  await until((n) => Number(document.querySelector('#pids-table tr[data-unit="2"] td[data-key="updates"]')?.textContent) >= n, near.latest.updates, "the row redrawn");
  const small = await cell("frequency_shift");
  t.diagnostic(small);
  assert.match(small, /^−?\d+(\.\d+)? m?Hz$/, "a shift of hertz or less");

  // Off from the panel, and the second excitation off: nothing held.
  await enable.uncheck();
  await until(() => window.ftafm.pids().pids?.[2]?.enable === false, null, "the unit reported off");
  await request("set", { path: "/drive2/enable", value: false });
  await until(() => window.ftafm.pids().held?.length === 0 && !document.querySelector("#pids-held"), null, "no output held");
  assert.deepEqual(pageErrors, []);
});
