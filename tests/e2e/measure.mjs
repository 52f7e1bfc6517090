// What the measuring scripts (dashboard_soak.mjs, page_profile.mjs) share: their command
// line and the dashboard opened in headless Chromium on a daemon of its own. Not a test.

import { chromium } from "playwright-core";
import { startDaemon, stopDaemon } from "./daemon.mjs";

/**
 * `[--seconds S] [--query PAGE_QUERY] [-- DAEMON FLAGS]` from the process's arguments;
 * exits with status 2 and the usage on anything else.
 */
export function measureArgs(script, defaultSeconds) {
  const args = process.argv.slice(2);
  const split = args.indexOf("--");
  const own = split < 0 ? args : args.slice(0, split);
  const daemonFlags = split < 0 ? [] : args.slice(split + 1);
  let seconds = defaultSeconds;
  let query = "";
  for (let i = 0; i < own.length; i++) {
    if (own[i] === "--seconds" && i + 1 < own.length) seconds = Number(own[++i]);
    else if (own[i] === "--query" && i + 1 < own.length) query = own[++i];
    else {
      console.error(`unknown argument ${own[i]}; usage: ${script} [--seconds S] [--query PAGE_QUERY] [-- DAEMON FLAGS]`);
      process.exit(2);
    }
  }
  if (!(seconds > 0)) {
    console.error("--seconds must be a positive number");
    process.exit(2);
  }
  return { seconds, query, daemonFlags };
}

/**
 * Starts `ftafm serve` with `daemonFlags` and opens its dashboard (with `query`) in headless
 * Chromium, connected; `close()` stops both.
 */
export async function openDashboard(daemonFlags, query) {
  const daemon = await startDaemon("127.0.0.1:0", daemonFlags);
  const browser = await chromium.launch({
    executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium",
    args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"],
  });
  const close = async () => {
    await browser.close();
    await stopDaemon(daemon);
  };
  try {
    const page = await browser.newPage({ viewport: { width: 1600, height: 1360 } });
    await page.goto(query ? `${daemon.url}?${query}` : daemon.url);
    await page.waitForSelector('#conn[data-state="open"]');
    return { daemon, page, close };
  } catch (e) {
    await close();
    throw e;
  }
}
