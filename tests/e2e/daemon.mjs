// The daemon for the browser tests: `target/release/ftafm serve` on a port of its own,
// stopped at the end of a test file, also when the runner dies. FTAFM_BIN overrides the
// binary's path; FTAFM_E2E_LOG names a file to which every daemon's log (its stderr; set
// RUST_LOG for more) is appended, to see what the daemon made of a failing test.

import { spawn } from "node:child_process";
import { appendFileSync, readdirSync, readFileSync } from "node:fs";
import { setPriority } from "node:os";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const BIN = process.env.FTAFM_BIN ?? path.join(here, "../../target/release/ftafm");

/** Every daemon started and not yet exited. */
export const daemons = new Set();

// If the runner dies some other way (also when killed), do not leave a daemon behind.
process.on("exit", () => { for (const d of daemons) d.kill("SIGKILL"); });
for (const sig of ["SIGINT", "SIGTERM"]) process.once(sig, () => process.exit(128 + (sig === "SIGINT" ? 2 : 15)));

/**
 * Starts `ftafm serve --bind bind …extra`; resolves with the process and its dashboard URL
 * (first stdout line).
 */
export function startDaemon(bind, extra = []) {
  return new Promise((resolve, reject) => {
    const args = ["serve", "--bind", bind, ...extra];
    const proc = spawn(BIN, args, { stdio: ["ignore", "pipe", "pipe"] });
    daemons.add(proc);
    let out = "", err = "";
    const timer = setTimeout(() => { proc.kill("SIGKILL"); reject(new Error(`daemon did not print its URL within 20 s; stderr:\n${err}`)); }, 20000);
    proc.stdout.setEncoding("utf8");
    proc.stderr.setEncoding("utf8");
    proc.stderr.on("data", (s) => {
      err += s;
      if (process.env.FTAFM_E2E_LOG) appendFileSync(process.env.FTAFM_E2E_LOG, s);
    });
    proc.stdout.on("data", (s) => {
      out += s;
      const nl = out.indexOf("\n");
      if (nl < 0) return;
      const m = /http:\/\/[^\s]+\//.exec(out.slice(0, nl));
      clearTimeout(timer);
      if (m) resolve({ proc, url: m[0], stderr: () => err });
      else { proc.kill("SIGKILL"); reject(new Error(`no URL in the daemon's first line: ${out.slice(0, nl)}`)); }
    });
    proc.on("error", (e) => { clearTimeout(timer); reject(e); });
    proc.on("exit", (code, sig) => {
      daemons.delete(proc);
      clearTimeout(timer);
      reject(new Error(`daemon exited (${code ?? sig}) before printing its URL; stderr:\n${err}`));
    });
  });
}

/**
 * Sets the nice value of the daemon's threads whose names match `pattern` (Linux: a thread's
 * id is a valid target of setpriority, and raising a nice value needs no privilege); returns
 * the names of the threads changed. Only those threads yield: the rest of the daemon (its
 * HTTP and WebSocket workers) keeps its share of a busy machine.
 */
export function niceThreads(d, pattern, nice) {
  const dir = `/proc/${d.proc.pid}/task`;
  const changed = [];
  for (const tid of readdirSync(dir)) {
    let name;
    try { name = readFileSync(`${dir}/${tid}/comm`, "utf8").trim(); } catch { continue; } // exited
    if (!pattern.test(name)) continue;
    setPriority(Number(tid), nice);
    changed.push(name);
  }
  return changed;
}

/** SIGTERM (the daemon closes its clients with 1001), SIGKILL after 5 s. */
export async function stopDaemon(d) {
  if (!d || d.proc.exitCode !== null || d.proc.signalCode !== null) return;
  const exited = new Promise((r) => d.proc.once("exit", r));
  d.proc.kill("SIGTERM");
  const timer = setTimeout(() => d.proc.kill("SIGKILL"), 5000);
  await exited;
  clearTimeout(timer);
}

