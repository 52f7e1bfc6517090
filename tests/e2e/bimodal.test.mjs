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
//
// A bimodal map (config/examples/bimodal_map.toml on tap300, on a daemon of its own: a preset
// sets the sample rate only at start) in the image panel: the channel select offers the
// bimodal channels by their labels, and the bimodal modulus is drawn, the softer disc darker
// than the silicon, with its colour scale in Pa.

import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import path from "node:path";
import { fileURLToPath } from "node:url";
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

const EXAMPLE = path.join(path.dirname(fileURLToPath(import.meta.url)), "../../config/examples/bimodal_map.toml");
const PIXELS = 16; // the example's

/** The colours the main image canvas shows at the centres of pixels [column, line]: [r, g, b]
 * each, or null while any of them is not drawn (the background's grey: that line of the
 * current frame is not in yet). */
function drawnAt(pixels) {
  const panel = window.ftafm.panels.image;
  const c = document.getElementById("image-canvas");
  const R = panel.rect, P = window.ftafm.image().pixels;
  if (!R || !P) return null;
  const dpr = c.width / c.clientWidth, ctx = c.getContext("2d");
  const colours = pixels.map(([i, j]) => {
    const d = ctx.getImageData(Math.round((R.x + ((i + 0.5) / P) * R.s) * dpr), Math.round((R.y + ((j + 0.5) / P) * R.s) * dpr), 1, 1).data;
    return [d[0], d[1], d[2]];
  });
  const background = (c) => Math.abs(c[0] - 0xe4) + Math.abs(c[1] - 0xe6) + Math.abs(c[2] - 0xeb) < 20;
  return colours.some(background) ? null : colours;
}

test("a bimodal map: the image panel offers the bimodal channels and draws the modulus in Pa", TEST, async (t) => {
  const map = await startDaemon("127.0.0.1:0", ["--preset", "tap300", "--config", EXAMPLE]);
  // The colour scale's labels are text on the canvas: keep the texts of the main image's
  // last draws (each starts with its title, "channel — label").
  await page.addInitScript(() => {
    const fill = CanvasRenderingContext2D.prototype.fillText;
    window.__imageDraws = [];
    CanvasRenderingContext2D.prototype.fillText = function (text, ...rest) {
      if (this.canvas.id === "image-canvas") {
        const draws = window.__imageDraws;
        if (/^\S+ — /.test(text) || !draws.length) draws.push([]);
        if (draws.length > 4) draws.shift();
        draws[draws.length - 1].push(String(text));
      }
      return fill.call(this, text, ...rest);
    };
  });
  await serveWebFrom(page, map.url);
  await page.goto(map.url);
  await page.waitForSelector('#conn[data-state="open"]', { timeout: WAIT });
  // The map, free-running (no pixel lost however busy the machine), in one change.
  await request("set", { values: { "/synth/realtime": false, "/scan/enable": true } });
  assert.equal(await get("/drive2/enable"), true);
  assert.equal(await get("/pids/0/output"), "drive2_frequency");

  await page.locator("#p-image").scrollIntoViewIfNeeded();
  await until(() => window.ftafm.image().subscribed && window.ftafm.image().channels.includes("bimodal_modulus"), null, "image lines with the bimodal channels");
  const options = await page.$$eval("#image-channel option", (os) => os.map((o) => [o.value, o.textContent]));
  const labels = Object.fromEntries(options);
  assert.equal(labels.frequency_shift2, "frequency_shift2 — mode 2's frequency shift Δf₂");
  assert.equal(labels.indentation, "indentation — indentation d (bimodal)");
  assert.equal(labels.bimodal_modulus, "bimodal_modulus — Young's modulus E (bimodal)");
  const at = (name) => options.findIndex(([v]) => v === name);
  assert.ok(at("h2") < at("frequency_shift2") && at("frequency_shift2") < at("indentation") && at("indentation") < at("bimodal_modulus"), `the bimodal channels after the harmonics, in order: ${options.map(([v]) => v)}`);

  await page.selectOption("#image-channel", "bimodal_modulus");
  assert.equal(await page.evaluate(() => window.ftafm.image().channel), "bimodal_modulus");
  // Frame 0's first line holds the loops' lock-in: wait for frame 1 drawn past the disc
  // (lines 5–10), then for one redraw that shows the four pixels at the disc's centre and
  // four of the silicon above it.
  await until(() => { const i = window.ftafm.image(); return i.frame >= 1 && i.line >= 12 && i.range; }, null, "a later frame scanned past the disc");
  const disc = [[7, 7], [8, 7], [7, 8], [8, 8]], silicon = [[1, 1], [14, 1], [1, 4], [14, 4]];
  const colours = await (await until(drawnAt, [...disc, ...silicon], "the disc and the silicon drawn")).jsonValue();
  const lum = (c) => 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
  const mean = (cs) => cs.reduce((s, c) => s + lum(c), 0) / cs.length;
  const [inDisc, onSilicon] = [mean(colours.slice(0, 4)), mean(colours.slice(4))];
  const im = await page.evaluate(() => window.ftafm.image());
  t.diagnostic(`bimodal_modulus: luminance disc ${inDisc.toFixed(1)}, silicon ${onSilicon.toFixed(1)}; range ${im.range.map((v) => (v / 1e9).toFixed(1)).join(" … ")} GPa`);
  // viridis: the softer disc (94 against 102 GPa, docs/loops.md) toward the dark end
  assert.ok(inDisc < onSilicon - 10, `the disc (${inDisc.toFixed(1)}) darker than the silicon (${onSilicon.toFixed(1)})`);
  assert.ok(im.range[0] > 50e9 && im.range[1] < 200e9 && im.range[0] < im.range[1], `a colour range of tens of GPa: ${im.range}`);

  // The colour scale in Pa: a draw of this channel whose labels carry the unit.
  const texts = await (await until(() => {
    const d = window.__imageDraws.filter((d) => d[0] === "bimodal_modulus — Young's modulus E (bimodal)").at(-1);
    return d && d.filter((s) => /^[−\d.]+ GPa$/.test(s)).length >= 2 && d;
  }, null, "the colour scale's labels in GPa")).jsonValue();
  t.diagnostic(`drawn: ${JSON.stringify(texts)}`);
  assert.deepEqual(pageErrors, []);
  await stopDaemon(map);
});
