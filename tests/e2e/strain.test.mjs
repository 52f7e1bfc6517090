// Browser test: while the daemon reports falling behind real time, the dashboard draws at
// most 10 frames a second (it may share a small machine with the daemon), and says so. A
// real headless Chromium against a real daemon paced at 100 MS/s, which no machine of this
// project synthesises in real time, so its status reports a real-time factor far below 1.
// The daemon's two real-time threads (synthesis and DSP, which take whatever CPU they are
// given) run at nice 19, so that the page has the CPU to draw faster than the cap: the count
// below is then the cap's doing, not a starved browser's. Only those threads: the daemon's
// HTTP and WebSocket workers keep their share of a busy machine, or the page would not load.
//
//   cargo build --release && (cd tests/e2e && npm ci) && node --test tests/e2e/strain.test.mjs
//
// FTAFM_BIN and CHROMIUM override the binary paths.

import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import { mkdtempSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import path from "node:path";
import { launchBrowser } from "./browser.mjs";
import { daemons, niceThreads, startDaemon, stopDaemon } from "./daemon.mjs";

// A hang guard, not a margin: every wait ends on an event.
const WAIT = 60000;
const TEST = { timeout: 180000 };
const OVERLAY = `# e2e: a sample rate no machine here keeps up with in real time
[synth]
sample_rate = 100e6
`;

let daemon, context, page, work, closeBrowser;
const pageErrors = [];

before(async () => {
  work = mkdtempSync(path.join(tmpdir(), "ftafm-e2e-strain-"));
  const overlay = path.join(work, "fast.toml");
  writeFileSync(overlay, OVERLAY);
  daemon = await startDaemon("127.0.0.1:0", ["--config", overlay]);
  // The chain starts just after the daemon prints its URL: wait for its two threads.
  let niced = [];
  for (const t0 = Date.now(); niced.length < 2 && Date.now() - t0 < WAIT;) {
    niced = niceThreads(daemon, /^ftafm-(synth|dsp)$/, 19);
    if (niced.length < 2) await new Promise((r) => setTimeout(r, 50));
  }
  assert.deepEqual(niced.sort(), ["ftafm-dsp", "ftafm-synth"], "the real-time threads, at nice 19");
  ({ context, page, close: closeBrowser } = await launchBrowser());
  context.setDefaultTimeout(WAIT);
  page.on("pageerror", (e) => pageErrors.push(String(e)));
  await page.goto(daemon.url);
});

after(async () => {
  // A browser that fails to close must not keep the daemon (and the test file) alive.
  await closeBrowser?.().catch((e) => console.warn(`ftafm e2e: closing the browser: ${e}`));
  for (const d of [...daemons]) await stopDaemon({ proc: d });
  if (work) rmSync(work, { recursive: true, force: true });
});

test("behind real time, the daemon gets the CPU back: the page draws at most 10 frames a second", { ...TEST }, async (t) => {
  // The status stream (2 Hz) reports the real-time factor; the page notes the strain from it.
  await page.waitForFunction(() => window.ftafm?.stats.strained === true, null, { timeout: WAIT, polling: 100 });
  const status = await page.evaluate(() => window.ftafm.panels.status.s);
  assert.equal(status.realtime, true);
  assert.ok(status.realtime_factor < 0.98, `real-time factor ${status.realtime_factor}`);
  // Count the frames the page draws in a stretch of wall time: an upper bound, which a slow
  // machine can only make smaller. The page must stay strained throughout (the daemon
  // cannot catch up), and must have drawn something (a frame rate of 0 passes no test).
  const counted = await page.evaluate(async () => {
    const draws = () => window.ftafm.stats.draws.harmonics;
    const d0 = draws(), t0 = performance.now();
    let strained = true;
    while (performance.now() - t0 < 3000) {
      await new Promise((r) => setTimeout(r, 100));
      strained &&= window.ftafm.stats.strained;
    }
    return { draws: draws() - d0, ms: performance.now() - t0, strained };
  });
  t.diagnostic(`${counted.draws} frames in ${counted.ms.toFixed(0)} ms, real-time factor ${status.realtime_factor.toFixed(3)}`);
  assert.ok(counted.strained, "the page stayed strained while the daemon could not keep up");
  assert.ok(counted.draws >= 1, "the page still draws");
  // 10 a second, and one more for the frame that may fall on each end of the stretch.
  assert.ok(counted.draws <= Math.ceil(counted.ms / 100) + 1, `${counted.draws} frames in ${counted.ms} ms`);
  // The status panel says why the display is slow.
  await page.waitForFunction(() => /daemon is behind real time/.test(document.querySelector('#status dd[data-key="display"]')?.textContent ?? ""),
    null, { timeout: WAIT, polling: 100 });
  assert.deepEqual(pageErrors, []);
});
