// The README's screenshots, taken from the real dashboard in headless Chromium:
//
//   cargo build --release && node tests/e2e/screenshots.mjs
//
// docs/dashboard.png: spectrum, harmonics, Fig. 3b (reference at 129 GPa, now 116.1 GPa,
// 2 s means), the photodiode trace folded on the drive cycle (Fig. 4) and the status.
// docs/dashboard-scan.png: the live FT-AFM force panel and the default scan of the default
// sample, started from the page as a user starts it (the height shown first).
// Not a test (node --test does not pick it up); run it when the dashboard changes.

import path from "node:path";
import { fileURLToPath } from "node:url";
import { chromium } from "playwright-core";
import { startDaemon, stopDaemon } from "./daemon.mjs";

const here = path.dirname(fileURLToPath(import.meta.url));
const docs = path.join(here, "../../docs");
const daemon = await startDaemon("127.0.0.1:0");
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium",
  args: ["--headless", "--no-sandbox", "--disable-gpu"],
});
try {
  const page = await browser.newPage({ viewport: { width: 1600, height: 1360 } });
  await page.goto(daemon.url);
  await page.waitForSelector('#conn[data-state="open"]');
  const simulated = async (s) => {
    const t0 = await page.evaluate(() => window.ftafm.app.history.tNow);
    await page.waitForFunction(([t, s]) => window.ftafm.app.history.tNow >= t + s, [t0, s], { timeout: 60000 });
  };
  const setModulus = async (text, value) => {
    const input = page.locator('input[data-path="/sample/youngs_modulus"]');
    await input.fill(text);
    await input.press("Enter");
    await page.waitForFunction((v) => window.ftafm.app.nodes.get("/sample/youngs_modulus")?.value === v, value);
  };
  await simulated(2.2);
  await page.click("#ref-set");
  await setModulus("116.1 GPa", 116.1e9);
  await simulated(2.5);
  await page.waitForTimeout(500);
  await page.screenshot({ path: path.join(docs, "dashboard.png") });
  await page.locator("#p-image").scrollIntoViewIfNeeded();
  await page.waitForFunction(() => window.ftafm.image().subscribed);
  await page.click("#scan-start");
  // The first frame almost complete on screen (64 lines at 2 lines/s; the image clears at
  // the next frame, 4 s after line 56).
  await page.waitForFunction(() => { const i = window.ftafm.image(); return i.pixels === 64 && i.frame === 0 && i.lines >= 56; }, null, { timeout: 180000 });
  await page.locator("#p-force").scrollIntoViewIfNeeded();
  await page.waitForTimeout(1000);
  await page.evaluate(() => window.scrollTo(0, document.getElementById("p-force").offsetTop - 10));
  await page.waitForTimeout(500);
  await page.screenshot({ path: path.join(docs, "dashboard-scan.png") });
  console.log("wrote docs/dashboard.png and docs/dashboard-scan.png");
  // What the page lost (seq gaps) per stream: the force trend's breaks are the panel's time
  // off screen (it subscribes only while visible), not losses, when force shows 0 here.
  console.log("messages lost by the page:", JSON.stringify(await page.evaluate(() => window.ftafm.stats.gaps)));
} finally {
  await browser.close();
  await stopDaemon(daemon);
}
