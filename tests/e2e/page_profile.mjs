// Where the dashboard's time goes: opens the page on a daemon started with the given flags,
// lets it settle, then records a JavaScript CPU profile and the page's task metrics for the
// given time and prints the busiest functions (self time) and the split between script,
// layout, style and the rest, as one JSON object.
//
//   cargo build --release
//   node tests/e2e/page_profile.mjs --seconds 10 -- --preset tap300 --config my.toml
//
// Not a test (node --test does not pick it up): it measures the machine.

import { chromium } from "playwright-core";
import { startDaemon, stopDaemon } from "./daemon.mjs";

const args = process.argv.slice(2);
const split = args.indexOf("--");
const own = split < 0 ? args : args.slice(0, split);
const daemonFlags = split < 0 ? [] : args.slice(split + 1);
let seconds = 10;
let query = "";
for (let i = 0; i < own.length; i++) {
  if (own[i] === "--seconds" && i + 1 < own.length) seconds = Number(own[++i]);
  else if (own[i] === "--query" && i + 1 < own.length) query = own[++i];
  else {
    console.error(`unknown argument ${own[i]}; usage: page_profile.mjs [--seconds S] [--query PAGE_QUERY] [-- DAEMON FLAGS]`);
    process.exit(2);
  }
}
if (!(seconds > 0)) {
  console.error("--seconds must be a positive number");
  process.exit(2);
}

const daemon = await startDaemon("127.0.0.1:0", daemonFlags);
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium",
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"],
});
try {
  const page = await browser.newPage({ viewport: { width: 1600, height: 1360 } });
  await page.goto(query ? `${daemon.url}?${query}` : daemon.url);
  await page.waitForSelector('#conn[data-state="open"]');
  await page.waitForTimeout(3000);
  const cdp = await page.context().newCDPSession(page);
  await cdp.send("Performance.enable");
  await cdp.send("Profiler.enable");
  await cdp.send("Profiler.setSamplingInterval", { interval: 500 });
  const metrics = async () => Object.fromEntries((await cdp.send("Performance.getMetrics")).metrics.map((m) => [m.name, m.value]));
  const before = await metrics();
  await cdp.send("Profiler.start");
  await page.waitForTimeout(seconds * 1000);
  const { profile } = await cdp.send("Profiler.stop");
  const after = await metrics();
  const self = new Map();
  const dt = profile.timeDeltas;
  const byId = new Map(profile.nodes.map((n) => [n.id, n]));
  const hits = new Map();
  profile.samples.forEach((id, i) => hits.set(id, (hits.get(id) ?? 0) + (dt[i] ?? 0)));
  for (const [id, us] of hits) {
    const f = byId.get(id).callFrame;
    const key = `${f.functionName || "(anonymous)"} ${f.url.split("/").pop()}:${f.lineNumber + 1}`;
    self.set(key, (self.get(key) ?? 0) + us);
  }
  const total = [...self.values()].reduce((a, b) => a + b, 0);
  const top = [...self.entries()].sort((a, b) => b[1] - a[1]).slice(0, 25).map(([k, us]) => [k, +(us / 1e3 / seconds).toFixed(1)]);
  const per = (name) => +(((after[name] ?? 0) - (before[name] ?? 0)) / seconds * 100).toFixed(1);
  console.log(JSON.stringify({
    seconds,
    daemon_flags: daemonFlags,
    query,
    percent_of_a_core: { task: per("TaskDuration"), script: per("ScriptDuration"), layout: per("LayoutDuration"), style: per("RecalcStyleDuration") },
    self_ms_per_s: top,
    profiled_ms_per_s: +(total / 1e3 / seconds).toFixed(1),
  }, null, 1));
} finally {
  await browser.close();
  await stopDaemon(daemon);
}
