// The browser for the browser tests: Debian's headless Chromium (CHROMIUM overrides its
// path), started by this process and driven by playwright-core over the DevTools protocol.
//
// Why not playwright's own launch: it starts Chromium in a session of its own (setsid), and
// Linux's autogroup scheduling (on by default) shares the CPU between sessions before it
// shares it between threads. Beside CPU hogs (`stress-ng --cpu 2` on the 2-vCPU machines),
// the kernel then left the page's renderer runnable but unscheduled for seconds at a time:
// 26 of 59 s without a millisecond of CPU, a page that answered after 53 s, and a daemon
// that closed the frozen page's socket. Started from the test runner's session, Chromium
// shares a group with the runner and the daemon: under the same load, no second without
// CPU and every answer within 150 ms. (tests/e2e/measure.mjs keeps playwright's launch: the
// soak measures a dashboard in a session of its own, as a user's desktop runs it.)

import { spawn } from "node:child_process";
import { existsSync, mkdtempSync, readFileSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import path from "node:path";
import { chromium } from "playwright-core";

const CHROMIUM = process.env.CHROMIUM ?? "/usr/bin/chromium";
// Playwright's own launch adds the switches that keep a page's timers and rendering at full
// rate whatever its visibility; these are the ones that matter here.
const ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
  "--disable-background-networking", "--disable-component-update", "--disable-sync",
  "--disable-background-timer-throttling", "--disable-backgrounding-occluded-windows",
  "--disable-renderer-backgrounding", "--disable-ipc-flooding-protection", "--disable-hang-monitor",
  "--no-default-browser-check", "--disable-default-apps", "--disable-extensions",
  "--password-store=basic", "--remote-debugging-port=0"];

/** Every browser process started and not yet exited. */
const browsers = new Set();
process.on("exit", () => { for (const b of browsers) b.kill("SIGKILL"); });

/**
 * Starts Chromium and opens one page in a fresh context of `viewport` (downloads accepted
 * when asked). Resolves with { context, page, close }; `close()` ends the browser and removes
 * its profile.
 */
export async function launchBrowser({ viewport = { width: 1600, height: 1000 }, acceptDownloads = false } = {}) {
  const profile = mkdtempSync(path.join(tmpdir(), "ftafm-e2e-browser-"));
  const proc = spawn(CHROMIUM, [...ARGS, `--user-data-dir=${profile}`, "about:blank"], { stdio: ["ignore", "ignore", "pipe"] });
  browsers.add(proc);
  const exited = new Promise((r) => proc.once("exit", () => { browsers.delete(proc); r(); }));
  const endpoint = await new Promise((resolve, reject) => {
    let err = "";
    const timer = setTimeout(() => reject(new Error(`chromium printed no DevTools endpoint within 30 s:\n${err}`)), 30000);
    proc.stderr.setEncoding("utf8");
    proc.stderr.on("data", (s) => {
      err += s;
      const m = /DevTools listening on (ws:\/\/\S+)/.exec(err);
      if (m) { clearTimeout(timer); resolve(m[1]); }
    });
    proc.once("error", (e) => { clearTimeout(timer); reject(e); });
    proc.once("exit", (code, sig) => { clearTimeout(timer); reject(new Error(`chromium exited (${code ?? sig}):\n${err}`)); });
  });
  const browser = await chromium.connectOverCDP(endpoint);
  const context = await browser.newContext({ viewport, acceptDownloads });
  const page = await context.newPage();
  const close = async () => {
    await context.close().catch(() => {});
    await browser.close().catch(() => {});
    proc.kill("SIGTERM");
    const timer = setTimeout(() => proc.kill("SIGKILL"), 5000);
    await exited;
    clearTimeout(timer);
    // The browser's children (renderers, utilities) end just after it and may still write
    // to the profile: retry while the directory is busy, and never fail a test on a leftover.
    try {
      rmSync(profile, { recursive: true, force: true, maxRetries: 50, retryDelay: 100 });
    } catch (e) {
      console.warn(`ftafm e2e: could not remove the browser profile ${profile}: ${e}`);
    }
  };
  return { context, page, close };
}

/** Serves the dashboard's files from the directory `FTAFM_E2E_WEB` names, where it is set,
 * in place of the daemon's embedded copy: a page edited in `web/` is tested without
 * rebuilding the binary. The page itself (/) stays the daemon's: Chromium lets only a page
 * it loaded from the loopback address open the loopback WebSocket (its local network
 * access checks). */
export async function serveWebFrom(page, daemonUrl) {
  const web = process.env.FTAFM_E2E_WEB;
  if (!web) return;
  const origin = new URL(daemonUrl).origin;
  const types = { ".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8", ".svg": "image/svg+xml" };
  await page.route((url) => url.origin === origin && url.pathname !== "/" && !url.pathname.startsWith("/ws"), (route) => {
    const file = path.join(web, new URL(route.request().url()).pathname);
    if (!existsSync(file)) return route.continue();
    return route.fulfill({ status: 200, contentType: types[path.extname(file)] ?? "application/octet-stream", body: readFileSync(file) });
  });
}
