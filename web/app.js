// The ftafm dashboard: one WebSocket (conn.js), a history of the lock-in outputs
// (history.js), and panels that each draw their own canvas when they have something new.
// Messages are only stored when they arrive; drawing happens on requestAnimationFrame.
//
// A panel is an object with optional onData(message) and draw(now); to add one, put its
// <section class="panel"> in index.html, write its module, add it to `panels` below and to
// ASSETS in src/server/assets.rs (the daemon serves only the files listed there).

import { Connection } from "./conn.js";
import { DemodHistory } from "./history.js";
import { SpectrumPanel } from "./spectrum.js";
import { HarmonicsPanel } from "./harmonics.js";
import { ContrastPanel } from "./contrast.js";
import { ScopePanel } from "./scope.js";
import { StatusPanel } from "./status.js";
import { ControlsPanel } from "./controls.js";
import { ForcePanel } from "./force.js";
import { ImagePanel } from "./image.js";
import { SweeperPanel } from "./sweeper.js";
import { PidsPanel } from "./pids.js";
import { si } from "./units.js";

const STREAMS = ["demods", "spectrum", "scope", "status", "force", "image", "sweep"];
const FORMATS = { demods: "binary", spectrum: "binary", scope: "binary", status: "json", force: "binary", image: "json", sweep: "json" };
// The lock-in's time points (1 kHz by default) come 20 to a binary message: the page then
// handles about 50 messages a second instead of 1000, every point still in the history.
// (The daemon sends a batch when full or 0.1 s after its first point, whichever is first.)
const SUBSCRIBE_EXTRA = { demods: { batch: 20 } };
// subscribed by their panels, only while on screen
const ON_DEMAND = new Set(["force", "image"]);
const zero = () => Object.fromEntries(STREAMS.map((s) => [s, 0]));

const stats = {
  messages: zero(), // data messages received per stream, since the page loaded (demods: time points)
  gaps: zero(), // messages lost (seq gaps) per stream (demods: time points)
  frames: zero(), // WebSocket messages received per stream (a batched demods message holds many points)
  draws: { harmonics: 0, contrast: 0, scope: 0, spectrum: 0, force: 0, image: 0, sweep: 0, pids: 0 },
  connects: 0,
  disconnects: [], // the last 20 closes of the connection: { at: page time (ms), why: the status line's words }
  state: "connecting",
  fps: 0, // redraws per second of the time plot (the page's animation rate)
  rafFps: 0, // animation frames per second the page took (it asks for about every second one)
  latency: new Float64Array(1000), // ms, synthesis → this page, of the last demods messages (a ring)
  latencyCount: 0,
  framesSkipped: 0, // animation frames not drawn because the page was behind its messages
  behind: false, // the page handles messages 0.5 s later than it did (its backlog): it draws less
  strained: false, // the daemon reported falling behind real time in the last 5 s: the page draws less
  sets: 0,
  rejects: 0,
  references: 0,
};

const app = {
  stats,
  hello: null,
  nodes: new Map(), // path → node as in `list`
  params: { f1: 0, modes: 0, fDrive: 0, fDrive2: 0 }, // fDrive2: 0 while the second drive is off
  history: new DemodHistory(30000),
  conn: null,
  /** The last change made from this page: { path, value, t } with t the simulated time (s)
   * from which the signal chain runs with it (the `set` reply's; null if unknown). */
  lastSet: null,
  onSet(path, value, t = null) {
    app.lastSet = { path, value, t };
    const n = app.nodes.get(path);
    if (n) n.value = value;
    updateParams();
    if (/^\/demods\/\d+\/oscillator$/.test(path)) syncOscillators();
    controls.updateDemodOptions();
    image.onSet(path, value);
  },
};

const spectrum = new SpectrumPanel(app);
const harmonics = new HarmonicsPanel(app);
const contrast = new ContrastPanel(app);
const scope = new ScopePanel(app);
const status = new StatusPanel(app);
const controls = new ControlsPanel(app);
const force = new ForcePanel(app);
const image = new ImagePanel(app);
const sweeper = new SweeperPanel(app);
const pids = new PidsPanel(app);
const panels = [spectrum, harmonics, contrast, scope, status, force, image, sweeper, pids];
app.force = force; // the scope marks the tap at the latest estimate's pulse phase
const byStream = { spectrum, scope, status, force, image, sweep: sweeper };
app.sweeper = sweeper;

function updateParams() {
  const v = (p) => app.nodes.get(p)?.value;
  const q = v("/cantilever/q");
  app.params.f1 = v("/cantilever/f1") ?? 0;
  app.params.modes = (Array.isArray(q) ? q.length : 0) + (v("/cantilever/extra_modes") ?? 0);
  app.params.fDrive = v("/drive/frequency") ?? 0;
  app.params.fDrive2 = v("/drive2/enable") ? v("/drive2/frequency") ?? 0 : 0;
  spectrum.dirty = true;
}

const OSCILLATOR_PATHS = Array.from({ length: 32 }, (_, i) => `/demods/${i}/oscillator`);

/** The history and the harmonics panel learn each demodulator's oscillator from its node
 * (the demods stream does not carry it). */
function syncOscillators() {
  for (let i = 0; i < OSCILLATOR_PATHS.length; i++) {
    app.history.setOscillator(i, app.nodes.get(OSCILLATOR_PATHS[i])?.value ?? "drive");
  }
}

/** The mode markers need f1 and the number of modes: re-read them now and then. */
async function refreshParams() {
  if (!app.conn.open) return;
  try {
    // one request for all: the demodulators' oscillators may change from a script
    const paths = ["/cantilever/f1", "/cantilever/q", "/cantilever/extra_modes", "/drive/frequency",
      "/drive2/enable", "/drive2/frequency", ...OSCILLATOR_PATHS];
    const r = await app.conn.request("get", { paths });
    for (const path of paths) {
      if (!(path in r.values)) continue;
      const n = app.nodes.get(path);
      if (n) n.value = r.values[path];
      else app.nodes.set(path, { path, value: r.values[path] });
    }
    updateParams();
    syncOscillators();
    controls.updateDemodOptions();
  } catch (e) {
    if (e.code !== "disconnected") console.warn("ftafm: reading cantilever parameters:", e.message);
  }
}

let lastSeq = {};
const every = {}; // per stream: the subscription's `every` (1 when absent)
const connEl = document.getElementById("conn");
const connText = document.getElementById("conn-text");
const facts = document.getElementById("facts");

/**
 * How far the page has fallen behind its demodulator messages (ms): how late the newest was
 * handled after its synthesis, less the least lateness of the last 10 s. The difference
 * leaves out what is constant (the pipeline's own latency, and the offset between the
 * daemon's and the browser's clocks when they are different machines) and grows while
 * messages queue. Stale (no message for 2 s) counts as not behind.
 */
const backlog = {
  minima: [], // per-second least lateness, newest last (10 at most)
  current: Infinity, // least lateness in the second being collected
  since: 0, // when that second began (ms, epoch)
  late: 0, // the newest message's lateness (ms)
  at: -Infinity, // when it was handled (ms, epoch)
  add(late, recvMs) {
    this.late = late;
    this.at = recvMs;
    this.current = Math.min(this.current, late);
    if (recvMs - this.since >= 1000) {
      this.minima.push(this.current);
      if (this.minima.length > 10) this.minima.shift();
      this.current = Infinity;
      this.since = recvMs;
    }
  },
  reset() {
    this.minima = [];
    this.current = Infinity;
    this.since = 0;
    this.at = -Infinity;
  },
  behind(nowMs, limit) {
    if (nowMs - this.at > 2000) return false;
    const floor = Math.min(this.current, ...this.minima);
    return this.late - floor > limit;
  },
};

function onState(state, detail) {
  stats.state = state;
  if (state === "closed") {
    stats.disconnects.push({ at: Math.round(performance.now()), why: detail });
    if (stats.disconnects.length > 20) stats.disconnects.shift();
  }
  connEl.dataset.state = state;
  connText.textContent = state === "open" ? "connected" : state === "connecting" ? `connecting…${detail ? " (" + detail + ")" : ""}` : `disconnected: ${detail}`;
  document.body.classList.toggle("offline", state !== "open");
}

async function onOpen(conn) {
  lastSeq = {};
  backlog.reset();
  stats.connects = conn.connects;
  try {
    // `force` (1 kHz) and `image` only while their panels are on screen: the panels subscribe
    // and unsubscribe
    const subs = Promise.all(STREAMS.filter((s) => !ON_DEMAND.has(s)).map((stream) => conn.request("subscribe", { stream, format: FORMATS[stream], ...SUBSCRIBE_EXTRA[stream] })));
    force.onOpen(conn);
    image.onOpen(conn);
    sweeper.onOpen(conn);
    subs.catch(() => {}); // reported by the await below
    app.hello = await conn.request("hello");
    if (app.hello.protocol !== 1) console.warn(`ftafm: the daemon speaks protocol ${app.hello.protocol}; this page was written for 1`);
    const list = await conn.request("list");
    for (const n of list.nodes) app.nodes.set(n.path, n);
    updateParams();
    syncOscillators();
    controls.setNodes(app.nodes);
    pids.setNodes(app.nodes);
    await subs;
  } catch (e) {
    if (e.code !== "disconnected") console.warn("ftafm: setting up the connection:", e.message);
  }
}

function onData(m, recvMs) {
  if (!(m.stream in stats.messages)) return;
  stats.frames[m.stream]++;
  if (m.batched) for (const p of m.batched) onMessage(p, recvMs); // a batched demods message
  else onMessage(m, recvMs);
}

/** One data message, or one time point of a batched demods message. */
function onMessage(m, recvMs) {
  const s = m.stream;
  stats.messages[s]++;
  const prev = lastSeq[s];
  const step = every[s] ?? 1; // a stream taken every n-th message advances by n
  if (prev !== undefined && m.seq > prev + step) stats.gaps[s] += (m.seq - prev - step) / step;
  lastSeq[s] = m.seq;
  if (s === "demods") {
    app.history.push(m.t, m.demods);
    const late = recvMs - Number(m.t_synth_ns) / 1e6;
    stats.latency[stats.latencyCount++ % stats.latency.length] = late;
    backlog.add(late, recvMs);
  } else {
    if (s === "status") {
      noteStrain(m, performance.now());
      pids.onData(m); // the PID units' latest updates ride on status
    }
    try {
      byStream[s].onData(m);
    } catch (e) {
      console.error(`ftafm: handling a ${s} message failed`, e);
    }
  }
}

/** A stream (re)subscribed, taking every `step`-th message: its seq starts afresh, so no gap
 * is counted against the old one. */
app.resetSeq = (stream, step = 1) => {
  delete lastSeq[stream];
  every[stream] = step;
};

app.conn = new Connection(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`, { onState, onOpen, onData });

// Drawing: every animation frame asks each panel to draw; panels skip when nothing changed.
// ?off=ScopePanel,SpectrumPanel skips drawing those panels: for profiling the page.
const OFF = new Set((new URLSearchParams(location.search).get("off") || "").split(","));
let fpsT0 = performance.now(), fpsDraws = 0, fpsFrames = 0, factsT = 0;
// On a busy machine drawing can take the page's whole main thread: messages then queue
// behind it, the browser stops reading the socket and the daemon finally drops the page as
// stalled. While the page is behind its messages (see `backlog`) it draws at most twice a
// second, and at most a fifth of the time: a drawn frame costs the thread from its callback
// to the next one (the canvases are rasterised after the callback returns), and the page
// waits four such costs between draws.
let lastDraw = -Infinity, drawCost = 0, drew = false;
const BEHIND_MS = 500, SLOW_DRAW_MS = 500, FRAME_MS = 26;

// The daemon may share the machine with this page (two vCPUs, say), where the page's drawing
// costs as much CPU as the synthesiser. While the daemon reports falling behind real time (a
// paced chain whose real-time factor is below 0.98, or a sample ring more than 5 % full) the
// page draws at most 10 times a second, and for 5 s after the last such report, giving the
// rest back to the instrument. Where the daemon runs elsewhere this costs only smoothness.
const STRAINED_FRAME_MS = 100, STRAINED_HOLD_MS = 5000;
let strainedUntil = -Infinity;
function noteStrain(s, now) {
  const behind = s.realtime && typeof s.realtime_factor === "number" && s.realtime_factor < 0.98;
  const filling = s.ring_capacity > 0 && s.ring_fill > 0.05 * s.ring_capacity;
  if (behind || filling) strainedUntil = now + STRAINED_HOLD_MS;
}
function frame(now) {
  fpsFrames++;
  if (drew) {
    drawCost = now - lastDraw;
    drew = false;
  }
  stats.behind = backlog.behind(performance.timeOrigin + now, BEHIND_MS);
  stats.strained = now < strainedUntil;
  const frameMs = stats.strained ? STRAINED_FRAME_MS : FRAME_MS;
  // Every panel draws in the same frames, at most ~30 a second (every second frame of a 60 Hz
  // display): each frame that changes a canvas costs the browser a composited frame, so
  // panels drawing in frames of their own would cost up to twice as many.
  if (now - lastDraw < frameMs) {
    // Not asking for every frame lets the browser skip the frames in between (an animation
    // frame requested is a frame produced, drawn into or not).
    setTimeout(() => requestAnimationFrame(frame), Math.max(0, frameMs - (now - lastDraw) - 8));
    return;
  }
  if (stats.behind && now - lastDraw < Math.max(SLOW_DRAW_MS, 4 * drawCost)) {
    stats.framesSkipped++;
    requestAnimationFrame(frame);
    return;
  }
  lastDraw = now;
  drew = true;
  const before = stats.draws.harmonics;
  for (const p of panels) {
    if (OFF.has(p.constructor.name)) continue;
    try {
      p.draw(now);
    } catch (e) {
      console.error("ftafm: drawing failed", e);
    }
  }
  fpsDraws += stats.draws.harmonics - before;
  if (now - fpsT0 >= 1000) {
    stats.fps = (fpsDraws * 1000) / (now - fpsT0);
    stats.rafFps = (fpsFrames * 1000) / (now - fpsT0);
    fpsT0 = now;
    fpsDraws = fpsFrames = 0;
  }
  if (now - factsT > 250) {
    factsT = now;
    const h = app.hello;
    const t = app.history.tNow;
    const esc = (v) => String(v).replace(/[&<>]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;" })[c]);
    facts.innerHTML =
      (h ? `<span>${esc(h.server)} ${esc(h.version)} · protocol ${esc(h.protocol)}</span><span>f<sub>s</sub> <b>${si(h.sample_rate, "Hz", 3)}</b></span>` : "") +
      `<span title="simulated time of the newest lock-in output">t <b>${isFinite(t) ? t.toFixed(2) + " s" : "–"}</b></span>`;
  }
  // The next draw is due in a frame's time: ask for the frame before it is due.
  setTimeout(() => requestAnimationFrame(frame), (stats.strained ? STRAINED_FRAME_MS : FRAME_MS) - 10);
}
requestAnimationFrame(frame);
setInterval(refreshParams, 3000);
app.conn.start();

// For tests and the console: live counters, the readouts and the panels.
window.ftafm = {
  stats,
  app,
  panels: { spectrum, harmonics, contrast, scope, status, controls, force, image, sweeper, pids },
  /** 0.2 s mean amplitude (m) at harmonic k of the drive, or null. */
  amplitude(k) {
    const i = app.history.indexOf(k);
    const m = i >= 0 ? app.history.mean(i, 0.2) : null;
    return m ? m.r : null;
  },
  contrast: () => contrast.values(),
  /** Which contrasts are outside the noise, and the contrast axis' half range (%). */
  contrastResolved: () => contrast.resolved(),
  /** 0.5 s means of the FT-AFM estimates: { E (Pa), F (N), tau, latest message }. */
  force: () => force.values(),
  /** The PID units as the newest status gave them: { unit (chosen), t, pids }. */
  pids: () => pids.values(),
  /** The scan image: channel, frame, line, colour range, the region's statistics. */
  image: () => image.values(),
  /** The sweep shown: its points, final message, whether one runs, and the CSV export. */
  sweep: () => ({ points: sweeper.points, final: sweeper.final, running: sweeper.running, csv: sweeper.csv() }),
};
