// Browser test of what a new user meets first, on a daemon at its embedded defaults: a tune
// from the page (retracted, so the free lever's resonance), the first scan (the softer disc
// stands out in the channel shown first), refusals and ranges in the user's units, and the
// Status panel with a warning at three window widths. One daemon, one browser.
//
//   cargo build --release && (cd tests/e2e && npm ci) && node --test tests/e2e/first_use.test.mjs

import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import { launchBrowser } from "./browser.mjs";
import { daemons, startDaemon, stopDaemon } from "./daemon.mjs";

// Hang guards, not margins: the waits below end on events (replies, lines, sweep points).
const WAIT = 60000;
const TEST = { timeout: 180000 };
const MODULUS = "/sample/youngs_modulus";

let daemon, context, page, closeBrowser;
const pageErrors = [];

async function until(fn, arg, what, timeout = WAIT) {
  try {
    return await page.waitForFunction(fn, arg, { timeout, polling: 100 });
  } catch (e) {
    const state = await page.evaluate(() => JSON.stringify({ stats: { ...window.ftafm?.stats, latency: undefined } })).catch(() => "?");
    throw new Error(`timed out after ${timeout} ms waiting for ${what}; page state: ${state}`);
  }
}

const get = (path) => page.evaluate((p) => window.ftafm.app.conn.request("get", { path: p }).then((r) => r.value), path);

before(async () => {
  daemon = await startDaemon("127.0.0.1:0");
  ({ context, page, close: closeBrowser } = await launchBrowser({ viewport: { width: 1600, height: 1000 } }));
  context.setDefaultTimeout(WAIT);
  page.on("pageerror", (e) => pageErrors.push(String(e)));
  await page.goto(daemon.url);
  await page.waitForSelector('#conn[data-state="open"]', { timeout: WAIT });
});

after(async () => {
  await closeBrowser?.().catch((e) => console.warn(`ftafm e2e: closing the browser: ${e}`));
  for (const d of [...daemons]) await stopDaemon({ proc: d });
});

test("a tune from the page at the default settings retracts the tip and finds the free resonance", TEST, async (t) => {
  await page.locator("#p-sweep").scrollIntoViewIfNeeded();
  await until(() => document.getElementById("sw-start").value !== "", null, "the sweeper set-up read from the daemon");
  assert.equal(await page.inputValue("#sw-parameter"), "/drive/frequency");
  // The defaults tap: 20 nm from the surface with a 30 nm free amplitude.
  assert.equal(await get("/surface/distance"), 20e-9);
  await page.click("#sw-run");
  await until(() => window.ftafm.sweep().final?.outcome === "done", null, "the tune to finish");
  const { tune, retracted } = (await page.evaluate(() => window.ftafm.sweep())).final;
  const text = await page.textContent("#sw-result");
  t.diagnostic(`${text}; retracted ${JSON.stringify(retracted)}`);
  // Tapping, the fit read 100.32 kHz and Q = 33.7; free, f1 = 100 kHz and Q = 100.
  assert.ok(Math.abs(tune.f0 / 100e3 - 1) < 5e-4, `f0 ${tune.f0}`);
  assert.ok(Math.abs(tune.q / 100 - 1) < 0.03, `Q ${tune.q}`);
  assert.equal(retracted.from, 20e-9);
  assert.ok(retracted.clear && retracted.distance >= 59e-9, JSON.stringify(retracted));
  assert.match(text, /^f0 = 100\.0\d* kHz, Q = (9\d|10\d)\.\d, .*; surface retracted from 20 nm to 6\d(\.\d+)? nm for the tune, then back to 20 nm \(the free lever's resonance\)$/);
  assert.equal(await get("/surface/distance"), 20e-9, "the distance restored");
});

test("the first scan started from the page shows the softer disc above the noise", TEST, async (t) => {
  await page.locator("#p-image").scrollIntoViewIfNeeded();
  await until(() => window.ftafm.image().subscribed, null, "the image subscription");
  assert.equal(await page.inputValue("#image-channel"), "height", "the height is the channel shown first");
  assert.equal(await page.getAttribute("#scan-start", "data-scanning"), "false");
  await page.click("#scan-start");
  await until(() => window.ftafm.image().pixels === 64, null, "the default 64 × 64 scan's lines");
  // The disc (a third of the scan across, at the centre) spans lines 21–43 of 64: wait for
  // the frame's lines through it (20 s of instrument time at 2 lines/s), then compare the
  // pixels well inside it with those well outside (line 0 is the feedback's start).
  await until(() => { const f = window.ftafm.panels.image.cur; return f && f.pixels === 64 && f.covers(1, 46); }, null,
    "the lines through the disc", 120000);
  const s = await page.evaluate(() => {
    const f = window.ftafm.panels.image.cur, P = f.pixels, h = f.data.get("height");
    const inside = [], outside = [];
    for (let r = 1; r <= 46; r++) {
      for (let c = 0; c < P; c++) {
        const v = h[r * P + c];
        if (!Number.isFinite(v)) continue;
        const d = Math.hypot((c + 0.5) / P - 0.5, (r + 0.5) / P - 0.5);
        if (d < 1 / 6 - 1.5 / P) inside.push(v);
        else if (d > 1 / 6 + 1.5 / P) outside.push(v);
      }
    }
    const stats = (a) => { const m = a.reduce((x, y) => x + y, 0) / a.length; return [m, a.reduce((x, y) => x + (y - m) ** 2, 0) / (a.length - 1)]; };
    const [mi, vi] = stats(inside), [mo, vo] = stats(outside);
    return { inside: inside.length, outside: outside.length, step: mi - mo, cnr: Math.abs(mi - mo) / Math.sqrt((vi + vo) / 2) };
  });
  t.diagnostic(`height: disc − silicon ${(s.step * 1e12).toFixed(2)} pm, CNR per pixel ${s.cnr.toFixed(1)} (${s.inside} pixels inside, ${s.outside} outside)`);
  assert.ok(s.inside > 100 && s.outside > 1000, JSON.stringify(s));
  assert.ok(s.step < 0, "the softer disc is indented further: lower");
  assert.ok(s.cnr > 3, `the disc stands out pixel by pixel: CNR ${s.cnr}`);
  await page.click("#scan-start");
  await until(() => document.getElementById("scan-start").dataset.scanning === "false", null, "the scan to stop");
});

test("ranges show their open and closed ends; refusals speak the user's units", TEST, async () => {
  await page.evaluate(() => window.scrollTo(0, 0));
  const range = (p) => page.textContent(`.ctl[data-path="${p}"] .range`);
  assert.equal(await range(MODULUS), "0 < E ≤ 10 TPa");
  assert.equal(await range("/drive/frequency"), "2.56 kHz ≤ f < 5 MHz");
  assert.equal(await range("/surface/distance"), "0 < d ≤ 1 µm");
  const input = page.locator(`input[data-path="${MODULUS}"]`);
  await input.fill("-5 GPa");
  await input.press("Enter");
  await until((p) => document.querySelector(`.error[data-for="${p}"]`)?.textContent.length > 0, MODULUS, "the refusal");
  assert.equal(await page.textContent(`.error[data-for="${MODULUS}"]`),
    "/sample/youngs_modulus = -5 GPa is out of range: allowed 0 < value ≤ 10 TPa");
  assert.equal(await input.inputValue(), "129 GPa", "reverted to the server's value");
});

test("the Status panel keeps its labels and values in view beside a long warning", TEST, async (t) => {
  // A 300 kHz lever puts the high demodulators out of band: the status warns in a long line.
  await page.evaluate(() => window.ftafm.app.conn.request("preset", { name: "tap300" }));
  await until(() => document.querySelector('#status dd[data-key="warning"]')?.textContent.length > 100, null, "a warning in the status");
  for (const width of [1280, 1600, 1920]) {
    await page.setViewportSize({ width, height: 1000 });
    // The panel redraws on each status message (2 a second): measure after a redraw.
    const n = await page.evaluate(() => window.ftafm.stats.messages.status);
    await until((n) => window.ftafm.stats.messages.status >= n + 2, n, "two status messages");
    const m = await page.evaluate(() => {
      const panel = document.getElementById("p-status").getBoundingClientRect();
      const box = (el) => { const r = el.getBoundingClientRect(); return { left: r.left, right: r.right, width: r.width, height: r.height, text: el.textContent }; };
      return {
        scrollWidth: document.scrollingElement.scrollWidth,
        innerWidth: window.innerWidth,
        panel: { left: panel.left, right: panel.right },
        cells: [...document.querySelectorAll("#status dt, #status dd")].map(box),
        // the lines each label's text takes (its box is as tall as its row)
        labels: [...document.querySelectorAll("#status dt")].map((el) => {
          const range = document.createRange();
          range.selectNodeContents(el);
          return { text: el.textContent, lines: new Set([...range.getClientRects()].map((r) => Math.round(r.top))).size };
        }),
      };
    });
    t.diagnostic(`${width} px: page ${m.scrollWidth} px wide, status panel ${Math.round(m.panel.left)}–${Math.round(m.panel.right)} px`);
    assert.ok(m.scrollWidth <= m.innerWidth, `no horizontal overflow at ${width} px: ${m.scrollWidth} > ${m.innerWidth}`);
    for (const c of m.cells) {
      assert.ok(c.width > 0 && c.left >= m.panel.left - 0.5 && c.right <= m.panel.right + 0.5,
        `"${c.text.slice(0, 40)}" inside the panel at ${width} px (${Math.round(c.left)}–${Math.round(c.right)})`);
    }
    // Labels stay on one line (they wrapped word by word); the warning wraps instead.
    for (const l of m.labels) assert.equal(l.lines, 1, `label "${l.text}" on one line at ${width} px`);
    for (const key of ["overruns", "latency p50/p99", "regime", "warning"]) {
      assert.ok(await page.isVisible(`#status dd[data-key="${key}"]`), `${key} visible at ${width} px`);
    }
  }
  assert.deepEqual(pageErrors, []);
});
