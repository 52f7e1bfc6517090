// The daemon in real time with the dashboard open: does the chain keep up while a browser
// draws every stream on the same machine? Runs `ftafm serve` with the given flags, opens the
// dashboard in headless Chromium for the given time, then prints the daemon's counters
// (overruns, late blocks, frames dropped) and what the page lost, as one JSON object.
//
//   cargo build --release
//   node tests/e2e/dashboard_soak.mjs --seconds 600 -- --preset tap300 --config my.toml
//
// `--query off=ScopePanel,SpectrumPanel` opens the page with that query (web/app.js: panels
// not drawn), to see what the page's drawing costs the chain.
//
// Exit status 0 if the daemon overran nothing and skipped no signal time (late blocks),
// 1 otherwise. Not a test (node --test does not pick it up): it measures the machine.

import { chromium } from "playwright-core";
import { startDaemon, stopDaemon } from "./daemon.mjs";

const args = process.argv.slice(2);
const split = args.indexOf("--");
const own = split < 0 ? args : args.slice(0, split);
const daemonFlags = split < 0 ? [] : args.slice(split + 1);
let seconds = 60;
let query = "";
for (let i = 0; i < own.length; i++) {
  if (own[i] === "--seconds" && i + 1 < own.length) seconds = Number(own[++i]);
  else if (own[i] === "--query" && i + 1 < own.length) query = own[++i];
  else {
    console.error(`unknown argument ${own[i]}; usage: dashboard_soak.mjs [--seconds S] [--query PAGE_QUERY] [-- DAEMON FLAGS]`);
    process.exit(2);
  }
}
if (!(seconds > 0)) {
  console.error("--seconds must be a positive number");
  process.exit(2);
}

/** The daemon's Prometheus counters of interest, summed over their labels. */
async function counters(url) {
  const text = await (await fetch(new URL("metrics", url))).text();
  const want = ["ftafm_overrun_samples_total", "ftafm_overrun_blocks_total", "ftafm_late_blocks_total", "ftafm_frames_dropped_total", "ftafm_messages_dropped_total"];
  const out = {};
  for (const line of text.split("\n")) {
    for (const name of want) {
      if (line.startsWith(name + " ") || line.startsWith(name + "{")) {
        out[name] = (out[name] ?? 0) + Number(line.slice(line.lastIndexOf(" ") + 1));
      }
    }
  }
  return out;
}

const daemon = await startDaemon("127.0.0.1:0", daemonFlags);
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium",
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"],
});
let ok = false;
try {
  const page = await browser.newPage({ viewport: { width: 1600, height: 1360 } });
  await page.goto(query ? `${daemon.url}?${query}` : daemon.url);
  await page.waitForSelector('#conn[data-state="open"]');
  const before = await counters(daemon.url);
  const start = Date.now();
  while (Date.now() - start < seconds * 1000) {
    await page.waitForTimeout(Math.min(10000, seconds * 1000 - (Date.now() - start)));
    const now = await counters(daemon.url);
    console.error(`${Math.round((Date.now() - start) / 1000)} s: ${JSON.stringify(now)}`);
  }
  const after = await counters(daemon.url);
  const delta = Object.fromEntries(Object.keys(after).map((k) => [k, after[k] - (before[k] ?? 0)]));
  const page_lost = await page.evaluate(() => window.ftafm.stats.gaps);
  const status = await page.evaluate(() => document.getElementById("status")?.innerText ?? "");
  ok = (delta.ftafm_overrun_samples_total ?? 0) === 0 && (delta.ftafm_late_blocks_total ?? 0) === 0;
  console.log(JSON.stringify({ seconds, daemon_flags: daemonFlags, daemon: delta, page_lost, status }));
} finally {
  await browser.close();
  await stopDaemon(daemon);
}
process.exit(ok ? 0 : 1);
