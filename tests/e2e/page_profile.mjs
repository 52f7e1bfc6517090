// Where the dashboard's time goes: opens the page on a daemon started with the given flags,
// lets it settle, then records a JavaScript CPU profile and the page's task metrics for the
// given time and prints the busiest functions (self time) and the split between script,
// layout, style and the rest, as one JSON object.
//
//   cargo build --release
//   node tests/e2e/page_profile.mjs --seconds 10 -- --preset tap300 --config my.toml
//
// Not a test (node --test does not pick it up): it measures the machine.

import { measureArgs, openDashboard } from "./measure.mjs";

const { seconds, query, daemonFlags } = measureArgs("page_profile.mjs", 10);
const { page, close } = await openDashboard(daemonFlags, query);
try {
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
  await close();
}
