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

import { measureArgs, openDashboard } from "./measure.mjs";

const { seconds, query, daemonFlags } = measureArgs("dashboard_soak.mjs", 60);

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

const { daemon, page, close } = await openDashboard(daemonFlags, query);
let ok = false;
try {
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
  await close();
}
process.exit(ok ? 0 : 1);
