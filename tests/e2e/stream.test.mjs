// Browser test of a streamed source: a daemon whose samples come from a client
// (`/source/kind = "stream"`), fed by a second process (`ftafm replay`, paced by the wall
// clock, looping a recording of two tones), with the dashboard open. The Status panel says
// where the samples come from and what came, skipped and dropped, and warns that the
// synthesiser's nodes shape nothing; the lock-in reads the recording's tones.
//
//   cargo build --release && (cd tests/e2e && npm ci) && node --test tests/e2e/stream.test.mjs

import { after, before, test } from "node:test";
import assert from "node:assert/strict";
import { spawn } from "node:child_process";
import { mkdtempSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import path from "node:path";
import { fileURLToPath } from "node:url";
import { launchBrowser } from "./browser.mjs";
import { daemons, startDaemon, stopDaemon } from "./daemon.mjs";

const here = path.dirname(fileURLToPath(import.meta.url));
const BIN = process.env.FTAFM_BIN ?? path.join(here, "../../target/release/ftafm");
// Hang guards, not margins: every wait ends on an event.
const WAIT = 60000;
const TEST = { timeout: 180000 };
const RATE = 2e6;
const OVERLAY = `# e2e: a streamed source at a rate that leaves the browser the CPU
[synth]
sample_rate = 2e6
[source]
kind = "stream"
`;
// 0.5 s of H1 (12 nm, phase 0.7) and H2 (0.9 nm, phase −1.2) of the 100 kHz drive, in m:
// a whole number of drive periods, so the loop's seam is continuous.
const TONES = [[1, 12e-9, 0.7], [2, 0.9e-9, -1.2]];

let daemon, context, page, work, closeBrowser, replay;
const pageErrors = [];

before(async () => {
  work = mkdtempSync(path.join(tmpdir(), "ftafm-e2e-stream-"));
  const overlay = path.join(work, "stream.toml");
  writeFileSync(overlay, OVERLAY);
  const n = RATE / 2;
  const x = new Float32Array(n);
  for (let i = 0; i < n; i++) {
    const theta = (2 * Math.PI * 1e5 * i) / RATE;
    x[i] = TONES.reduce((sum, [k, a, phi]) => sum + a * Math.cos(k * theta + phi), 0);
  }
  const file = path.join(work, "tones.f32");
  writeFileSync(file, Buffer.from(x.buffer));
  daemon = await startDaemon("127.0.0.1:0", ["--config", overlay]);
  const ws = daemon.url.replace(/^http/, "ws") + "ws";
  replay = spawn(BIN, ["replay", file, "--format", "raw-f32", "--sample-rate", String(RATE), "--units", "m", "--loop", "--seconds", "120", "--url", ws],
    { stdio: ["ignore", "ignore", "pipe"] });
  replay.stderr.setEncoding("utf8");
  let replayErr = "";
  replay.stderr.on("data", (s) => { replayErr += s; });
  replay.on("exit", (code) => { if (code) console.warn(`ftafm replay exited ${code}: ${replayErr}`); });
  ({ context, page, close: closeBrowser } = await launchBrowser({ viewport: { width: 1600, height: 1000 } }));
  context.setDefaultTimeout(WAIT);
  page.on("pageerror", (e) => pageErrors.push(String(e)));
  await page.goto(daemon.url);
  await page.waitForSelector('#conn[data-state="open"]', { timeout: WAIT });
});

after(async () => {
  replay?.kill("SIGKILL");
  await closeBrowser?.().catch((e) => console.warn(`ftafm e2e: closing the browser: ${e}`));
  for (const d of [...daemons]) await stopDaemon({ proc: d });
  if (work) rmSync(work, { recursive: true, force: true });
});

test("a streamed recording: the Status panel names the source and counts the stream, the lock-in reads its tones", TEST, async () => {
  const streamed = '#status dd[data-key="streamed"]';
  // Samples have come (the count is past a second of the stream) and none was lost.
  await page.waitForFunction((sel) => {
    const t = document.querySelector(sel)?.textContent ?? "";
    return /M samples, 0 skipped, 0 dropped/.test(t);
  }, streamed, { timeout: WAIT, polling: 200 });
  assert.equal(await page.textContent('#status dd[data-key="source"]'), "stream");
  const warnings = await page.$$eval('#status dd[data-key="warning"]', (els) => els.map((e) => e.textContent));
  assert.ok(warnings.some((w) => w.includes("the source is a stream")), warnings.join(" | "));
  // The newest output of the demodulators at H1 and H2: the recording's tones, on the
  // reference at the recording's sample 0.
  for (const [k, a, phi] of TONES) {
    const v = await page.evaluate((i) => window.ftafm.app.conn.request("get", { path: `/demods/${i}/sample` }).then((r) => r.value), k - 1);
    assert.equal(v.harmonic, k);
    assert.ok(Math.abs(v.r / a - 1) < 1e-3, `H${k}: r ${v.r} against ${a}`);
    const dphi = ((v.phase - phi + 3 * Math.PI) % (2 * Math.PI)) - Math.PI;
    assert.ok(Math.abs(dphi) < 1e-3, `H${k}: phase ${v.phase} against ${phi}`);
  }
  assert.deepEqual(pageErrors, []);
});
