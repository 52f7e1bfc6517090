// Scan images (the `image` stream, docs/protocol.md): one message per finished trace line, each
// channel an array of `pixels` values (null: missing), line 0 at the top. The panel draws the
// chosen channel with a colour map, a colour scale and a length scale as lines arrive,
// thumbnails of the main channels, the line/frame progress, the contrast of a region dragged
// on the image, and links to the daemon's export of the last finished frame
// (GET /image/<channel>.gsf | .npy).
//
// Light by construction: a line is coloured once into a pixels × pixels offscreen canvas per
// shown channel (the whole image is recoloured only when its colour range moves), and the
// screen canvases are redrawn, by scaling that canvas, only when something changed. The
// stream is only subscribed while the panel is on screen and the page visible.

import { si, siShort } from "./units.js";

// The channel shown first: the height (the feedback's output), where the default scan's
// softer disc stands out of the noise pixel by pixel (docs/scan.md, "Measured"); h17 and
// h18, the paper's channels, need longer pixels for that and are among the thumbnails.
const DEFAULT_CHANNEL = "height";
const THUMBS = ["height", "amplitude", "phase", "h6", "h17", "h18"];
const FT_CHANNELS = ["contact_time_ratio", "max_force", "youngs_modulus"];
// Bimodal AM-FM's, while the second excitation drives (and mode 2's PLL runs, for the last two).
const BIMODAL_CHANNELS = ["frequency_shift2", "indentation", "bimodal_modulus"];
const UNITS = {
  height: "m", amplitude: "m", phase: "rad", contact_time_ratio: "1", max_force: "N", youngs_modulus: "Pa",
  frequency_shift2: "Hz", indentation: "m", bimodal_modulus: "Pa",
};
const LABELS = {
  height: "height (feedback output)",
  amplitude: "amplitude A₁",
  phase: "phase φ₁",
  contact_time_ratio: "contact time ratio τ",
  max_force: "peak force F",
  youngs_modulus: "Young's modulus E",
  frequency_shift2: "mode 2's frequency shift Δf₂",
  indentation: "indentation d (bimodal)",
  bimodal_modulus: "Young's modulus E (bimodal)",
};
const MIN_FRAME_MS = 33; // at most ~30 redraws a second
const RANGE_MS = 250; // colour ranges are re-evaluated at most this often
const READOUT_MS = 200;
const POLL_MS = 1000; // /scan/enable, while the panel is on screen
const BACKGROUND = "#e4e6eb"; // missing pixels
const RANGE_SAMPLE = 4096; // values sorted for a robust range, at most
// Every channel is kept for every pixel while that stays small; beyond it only the shown ones.
const KEEP_ALL_VALUES = 4 << 20;

// ---- colour maps: 256-entry RGB lookup tables ----

/** matplotlib's viridis at 17 evenly spaced points, interpolated linearly to 256. */
const VIRIDIS = ["440154", "48186a", "472d7b", "424086", "3b528b", "33638d", "2c728e", "26828e", "21918c",
  "1fa088", "28ae80", "3fbc73", "5ec962", "84d44b", "addc30", "d8e219", "fde725"];

function lutFrom(fn) {
  const lut = new Uint8Array(256 * 3);
  for (let i = 0; i < 256; i++) {
    const [r, g, b] = fn(i / 255);
    lut[3 * i] = Math.round(Math.max(0, Math.min(1, r)) * 255);
    lut[3 * i + 1] = Math.round(Math.max(0, Math.min(1, g)) * 255);
    lut[3 * i + 2] = Math.round(Math.max(0, Math.min(1, b)) * 255);
  }
  return lut;
}

function anchors(hexes) {
  const pts = hexes.map((h) => [0, 2, 4].map((i) => parseInt(h.slice(i, i + 2), 16) / 255));
  return (x) => {
    const f = x * (pts.length - 1);
    const i = Math.min(pts.length - 2, Math.floor(f));
    const u = f - i;
    return [0, 1, 2].map((c) => pts[i][c] * (1 - u) + pts[i + 1][c] * u);
  };
}

export const COLOUR_MAPS = {
  viridis: { label: "viridis", lut: lutFrom(anchors(VIRIDIS)) },
  // the classic AFM "hot" map (black → red → orange → white), close to Gwyddion's
  afmhot: { label: "AFM hot", lut: lutFrom((x) => [2 * x, 2 * x - 0.5, 2 * x - 1]) },
  grey: { label: "grey", lut: lutFrom((x) => [x, x, x]) },
};

// ---- helpers ----

const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);

function unitOf(name, units) {
  return units?.[name] ?? UNITS[name] ?? (/^h\d+$/.test(name) ? "m" : "1");
}

function labelOf(name) {
  if (LABELS[name]) return LABELS[name];
  const m = /^h(\d+)$/.exec(name);
  return m ? `harmonic ${m[1]} amplitude` : name;
}

/** Channel order: height, amplitude, phase, h2…h32 by number, the FT-AFM channels, the bimodal ones, the rest. */
function channelRank(name) {
  const base = ["height", "amplitude", "phase"].indexOf(name);
  if (base >= 0) return base;
  const m = /^h(\d+)$/.exec(name);
  if (m) return 10 + Number(m[1]);
  const ft = FT_CHANNELS.indexOf(name);
  if (ft >= 0) return 100000 + ft;
  const bimodal = BIMODAL_CHANNELS.indexOf(name);
  return bimodal >= 0 ? 150000 + bimodal : 200000;
}

/** A "nice" length (1, 2 or 5 × 10ⁿ m) of about a quarter of `size`. */
export function scaleBarLength(size) {
  if (!(size > 0)) return 0;
  const raw = size / 4;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const f = raw / mag;
  return (f >= 5 ? 5 : f >= 2 ? 2 : 1) * mag;
}

function fmtDuration(s) {
  if (!isFinite(s)) return "–";
  if (s < 10) return `${Math.max(0, s).toFixed(1)} s`;
  if (s < 120) return `${Math.round(s)} s`;
  if (s < 7200) return `${Math.floor(s / 60)} min ${String(Math.round(s % 60)).padStart(2, "0")} s`;
  return `${(s / 3600).toFixed(1)} h`;
}

/**
 * Mean, sample standard deviation and count of the finite values of a pixels × pixels image,
 * inside the box [c0, r0, c1, r1] (inclusive) or, with `inside` false, outside it.
 */
function boxStats(values, P, box, inside) {
  const [c0, r0, c1, r1] = box;
  const pick = (r, c) => (r >= r0 && r <= r1 && c >= c0 && c <= c1) === inside;
  let n = 0, s = 0;
  for (let r = 0; r < P; r++) {
    for (let c = 0; c < P; c++) {
      const v = values[r * P + c];
      if (v === v && pick(r, c)) { n++; s += v; }
    }
  }
  if (!n) return { n: 0, mean: NaN, std: NaN };
  const mean = s / n;
  let s2 = 0;
  for (let r = 0; r < P; r++) {
    for (let c = 0; c < P; c++) {
      const v = values[r * P + c];
      if (v === v && pick(r, c)) s2 += (v - mean) ** 2;
    }
  }
  return { n, mean, std: n > 1 ? Math.sqrt(s2 / (n - 1)) : 0 };
}

const REGIMES = { "-1": "attractive", "0": "free", "1": "repulsive" };

/**
 * The regime most pixels of the box (inside or outside it) were imaged in, from the
 * daemon's `regime` channel (−1 attractive, 0 free, +1 repulsive), or null.
 */
function boxRegime(values, P, box, inside) {
  const [c0, r0, c1, r1] = box;
  const counts = { "-1": 0, "0": 0, "1": 0 };
  for (let r = 0; r < P; r++) {
    for (let c = 0; c < P; c++) {
      const v = values[r * P + c];
      if (v === v && (r >= r0 && r <= r1 && c >= c0 && c <= c1) === inside && String(v) in counts) counts[String(v)]++;
    }
  }
  const [code, n] = Object.entries(counts).sort((a, b) => b[1] - a[1])[0];
  return n ? REGIMES[code] : null;
}

// ---- data ----

/** One image: every kept channel as pixels² values (NaN: not yet scanned or missing). */
class Frame {
  constructor(m, epoch) {
    this.epoch = epoch;
    this.generation = m.generation;
    this.frame = m.frame;
    this.pixels = m.pixels;
    this.size = m.size;
    this.key = `${epoch}/${m.generation}/${m.frame}/${m.pixels}`;
    this.data = new Map(); // channel → Float32Array(pixels²)
    this.units = {};
    this.rows = new Uint8Array(m.pixels); // 1 where the line arrived
    this.nRows = 0;
    this.log = []; // lines in order of arrival (layers colour what they have not yet)
    this.lastLine = -1;
    this.done = false;
  }

  /** A channel's values, created (all missing) on first use. */
  channel(name) {
    let a = this.data.get(name);
    if (!a) {
      a = new Float32Array(this.pixels * this.pixels).fill(NaN);
      this.data.set(name, a);
    }
    return a;
  }

  /** Whether every line from r0 to r1 (inclusive) arrived. */
  covers(r0, r1) {
    for (let r = r0; r <= r1; r++) if (!this.rows[r]) return false;
    return true;
  }
}

/** A channel of the current frame coloured into a pixels × pixels canvas. */
class Layer {
  constructor(name) {
    this.name = name;
    this.canvas = document.createElement("canvas");
    this.ctx = this.canvas.getContext("2d");
    this.img = null;
    this.frameKey = null;
    this.painted = 0; // how much of the frame's line log is coloured
    this.range = null; // [lo, hi] the colours stand for
    this.rangeAt = -Infinity; // when the range was last evaluated
    this.rangeLog = -1; // the log length it was evaluated at
    this.mapKey = "";
    this.version = 0; // +1 whenever the canvas changed
  }
}

export class ImagePanel {
  constructor(app) {
    this.app = app;
    this.cur = null; // frame being scanned
    this.last = null; // last finished frame
    this.layers = new Map();
    this.channelNames = [];
    this.channel = DEFAULT_CHANNEL;
    this.latest = null; // the newest message (without its channel arrays)
    this.rateLog = []; // [t, frameKey, line] of recent lines, for the measured line rate
    this.framesFinished = 0; // frames whose last line arrived, on this connection
    this.exportable = false; // the daemon has a finished frame to export
    this.epoch = 0; // +1 per connection: a restarted daemon counts generations afresh
    this.scanning = null; // /scan/enable as last read
    this.region = null; // [fx0, fy0, fx1, fy1], fractions of the image, or null
    this.regionStats = null;
    this.drag = null;
    this.pendingScan = false;
    this.unsupported = null; // the daemon's message if it has no image stream
    this.dirty = true;
    this.lastDraw = 0;
    this.lastReadout = 0;
    this.readoutKey = "";
    this.drawnKey = "";

    const $ = (id) => document.getElementById(id);
    this.canvas = $("image-canvas");
    this.ctx = this.canvas.getContext("2d", { alpha: false });
    this.progressEl = $("image-progress");
    this.select = $("image-channel");
    this.mapSel = $("image-map");
    this.scaleSel = $("image-scale");
    this.regionEl = $("image-region");
    this.startBtn = $("scan-start");
    this.scanErr = $("scan-error");
    this.links = { gsf: $("image-gsf"), npy: $("image-npy") };
    this.thumbsEl = $("image-thumbs");
    this.thumbs = THUMBS.map((name) => {
      const fig = document.createElement("figure");
      fig.className = "thumb";
      fig.dataset.channel = name;
      fig.title = `${labelOf(name)}: click to show it large`;
      fig.innerHTML = `<canvas></canvas><figcaption>${esc(name)}</figcaption>`;
      this.thumbsEl.append(fig);
      const canvas = fig.querySelector("canvas");
      return { name, fig, canvas, ctx: canvas.getContext("2d", { alpha: false }), key: "" };
    });
    this.thumbsEl.addEventListener("click", (e) => {
      const fig = e.target.closest(".thumb");
      if (fig) this.choose(fig.dataset.channel);
    });
    this.select.addEventListener("change", () => this.choose(this.select.value));
    this.mapSel.innerHTML = Object.entries(COLOUR_MAPS).map(([k, v]) => `<option value="${k}">${esc(v.label)}</option>`).join("");
    const redraw = () => { this.dirty = true; };
    this.mapSel.addEventListener("change", redraw);
    this.scaleSel.addEventListener("change", () => {
      for (const l of this.layers.values()) { l.rangeAt = -Infinity; l.rangeLog = -1; }
      this.dirty = true;
    });
    this.startBtn.addEventListener("click", () => this.toggleScan());
    this.setupRegion();
    new ResizeObserver(redraw).observe(this.canvas);
    new ResizeObserver(() => { for (const t of this.thumbs) t.key = ""; }).observe(this.thumbsEl);
    this.updateLinks();
    this.updateChannelOptions();
    this.choose(DEFAULT_CHANNEL);

    // subscribed only while on screen, as the force panel
    this.visible = false;
    this.subscribed = false;
    this.busy = false;
    new IntersectionObserver((entries) => {
      for (const e of entries) this.visible = e.isIntersecting;
      this.updateSubscription();
    }).observe($("p-image"));
    document.addEventListener("visibilitychange", () => this.updateSubscription());
    setInterval(() => this.pollScan(), POLL_MS);
  }

  // ---- connection ----

  /** After (re)connecting: nothing is subscribed on the new socket; exports are re-learned. */
  onOpen() {
    this.subscribed = false;
    this.framesFinished = 0;
    this.exportable = false;
    this.epoch++;
    this.updateLinks();
    this.updateSubscription();
    this.pollScan(true);
  }

  async updateSubscription() {
    const conn = this.app.conn;
    if (this.busy || !conn || !conn.open) return;
    const want = this.visible && !document.hidden;
    if (want === this.subscribed) return;
    this.busy = true;
    try {
      if (want) {
        this.app.resetSeq?.("image");
        this.rateLog = [];
        await conn.request("subscribe", { stream: "image", format: "json" });
      } else {
        await conn.request("unsubscribe", { stream: "image" });
      }
      this.subscribed = want;
    } catch (e) {
      if (e.code !== "disconnected") console.warn("ftafm: image stream:", e.message);
      if (e.code === "unknown_stream") this.unsupported = e.message;
    } finally {
      this.busy = false;
    }
    if (!this.unsupported && (this.visible && !document.hidden) !== this.subscribed && conn.open) this.updateSubscription();
  }

  /** Reads /scan/enable (the Start/Stop button follows it). */
  async pollScan(force = false) {
    const conn = this.app.conn;
    if (!conn?.open || (!force && (!this.visible || document.hidden))) return;
    try {
      const r = await conn.request("get", { path: "/scan/enable" });
      this.setScanning(r.value);
    } catch (e) {
      if (e.code === "unknown_path") this.setScanning(null);
      else if (e.code !== "disconnected") console.warn("ftafm: /scan/enable:", e.message);
    }
  }

  setScanning(on) {
    const scanning = typeof on === "boolean" ? on : null;
    if (scanning !== this.scanning) this.dirty = true; // the canvas' message may change
    this.scanning = scanning;
    const b = this.startBtn;
    b.disabled = this.scanning === null || this.pendingScan;
    b.textContent = this.scanning ? "Stop scan" : "Start scan";
    b.classList.toggle("ghost", !!this.scanning);
    b.dataset.scanning = String(this.scanning);
  }

  /** Controls (controls.js) report their sets here. */
  onSet(path, value) {
    if (path === "/scan/enable") this.setScanning(value);
  }

  async toggleScan() {
    if (this.scanning === null || this.pendingScan) return;
    const value = !this.scanning;
    let now = this.scanning;
    this.pendingScan = true;
    this.startBtn.disabled = true;
    this.scanErr.textContent = "";
    try {
      let reply;
      for (let attempt = 0; ; attempt++) {
        try {
          reply = await this.app.conn.request("set", { path: "/scan/enable", value });
          break;
        } catch (e) {
          // "busy": the previous change has not reached the signal chain yet
          if (e.code === "busy" && attempt < 20) await new Promise((r) => setTimeout(r, 50));
          else throw e;
        }
      }
      const n = this.app.nodes.get("/scan/enable");
      if (n) n.value = reply.value;
      this.app.stats.sets++;
      now = reply.value;
    } catch (e) {
      this.scanErr.textContent = e.message; // the server's words
      this.app.stats.rejects++;
      this.pollScan(true);
    } finally {
      this.pendingScan = false;
      this.setScanning(now);
    }
  }

  // ---- data ----

  onData(m) {
    const P = m.pixels;
    const chans = m.channels;
    if (!(P > 0) || !chans || !(m.line >= 0 && m.line < P)) return;
    const key = `${this.epoch}/${m.generation}/${m.frame}/${P}`;
    if (!this.cur || this.cur.key !== key) {
      this.cur = new Frame(m, this.epoch);
    }
    const f = this.cur;
    f.size = m.size;
    const names = Object.keys(chans);
    // at large images keep only the channels shown
    const keepAll = P * P * names.length <= KEEP_ALL_VALUES;
    const row = m.line * P;
    for (const name of names) {
      if (!keepAll && name !== this.channel && !THUMBS.includes(name) && !f.data.has(name)) continue;
      const src = chans[name];
      if (!Array.isArray(src)) continue;
      const dst = f.channel(name);
      f.units[name] = unitOf(name, m.units);
      const n = Math.min(P, src.length);
      for (let i = 0; i < n; i++) {
        const v = src[i];
        dst[row + i] = typeof v === "number" ? v : NaN;
      }
    }
    if (!f.rows[m.line]) { f.rows[m.line] = 1; f.nRows++; }
    f.log.push(m.line);
    f.lastLine = m.line;
    if (m.line === P - 1) {
      f.done = true;
      this.framesFinished++;
      this.last = f;
    }
    // a frame finished (this one, or the one before a frame > 0): the daemon can export it
    if (!this.exportable && (f.done || m.frame > 0)) {
      this.exportable = true;
      this.updateLinks();
    }
    // channel list: rebuilt when the set changes
    const sorted = names.slice().sort((a, b) => channelRank(a) - channelRank(b) || a.localeCompare(b));
    if (sorted.join(",") !== this.channelNames.join(",")) {
      this.channelNames = sorted;
      this.updateChannelOptions();
    }
    const { channels, units, ...rest } = m;
    this.latest = rest;
    this.rateLog.push([m.t, key, m.line]);
    if (this.rateLog.length > 12) this.rateLog.shift();
    this.dirty = true;
  }

  /** Lines per second over the recent lines of this frame, or the daemon's figure. */
  lineRate() {
    const log = this.rateLog;
    const last = log[log.length - 1];
    if (!last) return NaN;
    let j = log.length - 1;
    while (j > 0 && log[j - 1][1] === last[1] && log[j - 1][2] < log[j][2]) j--;
    const first = log[j];
    const dl = last[2] - first[2], dt = last[0] - first[0];
    if (dl >= 2 && dt > 0) return dl / dt;
    return this.latest?.line_rate ?? NaN;
  }

  updateChannelOptions() {
    const names = this.channelNames.length ? this.channelNames : [this.channel];
    const opts = names.includes(this.channel) ? names : [...names, this.channel];
    this.select.innerHTML = opts.map((n) => `<option value="${esc(n)}">${esc(n)} — ${esc(labelOf(n))}</option>`).join("");
    this.select.value = this.channel;
  }

  choose(name) {
    if (!name) return;
    this.channel = name;
    if (this.select.value !== name) {
      if (![...this.select.options].some((o) => o.value === name)) this.updateChannelOptions();
      this.select.value = name;
    }
    for (const t of this.thumbs) t.fig.classList.toggle("on", t.name === name);
    this.updateLinks();
    this.readoutKey = "";
    this.lastReadout = 0;
    this.dirty = true;
  }

  updateLinks() {
    const ready = this.exportable;
    for (const [ext, a] of Object.entries(this.links)) {
      const href = `/image/${encodeURIComponent(this.channel)}.${ext}`;
      if (ready) a.setAttribute("href", href);
      else a.removeAttribute("href");
      a.setAttribute("aria-disabled", String(!ready));
      a.classList.toggle("disabled", !ready);
      a.title = ready
        ? `${this.channel} of the last finished frame as ${ext === "gsf" ? "a Gwyddion Simple Field" : "a NumPy array (row 0 at the top)"}`
        : "available once a frame has finished";
    }
  }

  // ---- colouring ----

  layer(name) {
    let l = this.layers.get(name);
    if (!l) {
      l = new Layer(name);
      this.layers.set(name, l);
    }
    return l;
  }

  /**
   * The colour range of a channel over the lines scanned so far: full, or robust (0.5 … 99.5 %
   * quantiles of at most RANGE_SAMPLE values taken evenly from those lines).
   */
  computeRange(values, frame) {
    const P = frame.pixels, robust = this.scaleSel.value !== "full";
    const step = robust ? Math.max(1, Math.ceil((frame.nRows * P) / RANGE_SAMPLE)) : 1;
    const sample = robust ? new Float64Array(Math.ceil((frame.nRows * P) / step) + P) : null;
    let lo = Infinity, hi = -Infinity, k = 0, j = 0;
    for (let r = 0; r < P; r++) {
      if (!frame.rows[r]) continue;
      for (let i = r * P, end = i + P; i < end; i++, j++) {
        const v = values[i];
        if (v !== v) continue;
        if (v < lo) lo = v;
        if (v > hi) hi = v;
        if (robust && j % step === 0) sample[k++] = v;
      }
    }
    if (!(hi >= lo)) return null;
    if (robust && k > 20) {
      const a = sample.subarray(0, k).sort();
      const q = (p) => a[Math.min(k - 1, Math.max(0, Math.round(p * (k - 1))))];
      lo = q(0.005);
      hi = q(0.995);
    }
    if (!(hi > lo)) {
      const pad = Math.abs(lo) * 1e-6 || 1e-30;
      lo -= pad;
      hi += pad;
    }
    return [lo, hi];
  }

  /** Colours what is new in `name`'s layer; true if its canvas changed. */
  updateLayer(name, now) {
    const f = this.cur;
    const l = this.layer(name);
    if (!f) return false;
    const values = f.data.get(name);
    const P = f.pixels;
    let full = false;
    if (l.frameKey !== f.key) {
      l.frameKey = f.key;
      if (l.canvas.width !== P) { l.canvas.width = P; l.canvas.height = P; }
      l.img = l.ctx.createImageData(P, P); // transparent: missing
      l.painted = 0;
      l.range = null;
      l.rangeAt = -Infinity;
      l.rangeLog = -1;
      full = true;
    }
    const logLen = f.log.length;
    if (!values) {
      l.rangeLog = logLen; // nothing to colour
      if (full) { l.ctx.clearRect(0, 0, P, P); l.version++; }
      return full;
    }
    if (l.rangeLog !== logLen && (now - l.rangeAt >= RANGE_MS || !l.range)) {
      const r = this.computeRange(values, f);
      l.rangeAt = now;
      l.rangeLog = logLen;
      if (r && (!l.range || Math.abs(r[0] - l.range[0]) > 1e-3 * (r[1] - r[0]) || Math.abs(r[1] - l.range[1]) > 1e-3 * (r[1] - r[0]))) {
        l.range = r;
        full = true;
      }
    }
    const mapKey = this.mapSel.value;
    if (l.mapKey !== mapKey) { l.mapKey = mapKey; full = true; }
    if (!l.range) return full;
    if (full) {
      this.paintRows(l, values, P, null);
      l.ctx.putImageData(l.img, 0, 0);
      l.painted = logLen;
      l.version++;
      return true;
    }
    if (l.painted >= logLen) return false;
    const rows = new Set(f.log.slice(l.painted));
    this.paintRows(l, values, P, rows);
    for (const r of rows) l.ctx.putImageData(l.img, 0, 0, 0, r, P, 1);
    l.painted = logLen;
    l.version++;
    return true;
  }

  /** Maps values to colours into the layer's ImageData: all rows, or just `rows`. */
  paintRows(l, values, P, rows) {
    const lut = (COLOUR_MAPS[this.mapSel.value] ?? COLOUR_MAPS.viridis).lut;
    const d = l.img.data;
    const [lo, hi] = l.range;
    const k = 255 / (hi - lo);
    const paint = (r) => {
      for (let i = r * P, end = i + P; i < end; i++) {
        const v = values[i], o = 4 * i;
        if (v !== v) { d[o + 3] = 0; continue; }
        let j = Math.round((v - lo) * k);
        j = j < 0 ? 0 : j > 255 ? 255 : j;
        d[o] = lut[3 * j];
        d[o + 1] = lut[3 * j + 1];
        d[o + 2] = lut[3 * j + 2];
        d[o + 3] = 255;
      }
    };
    if (rows) for (const r of rows) paint(r);
    else for (let r = 0; r < P; r++) paint(r);
  }

  // ---- region ----

  setupRegion() {
    const c = this.canvas;
    const toFrac = (e) => {
      const b = c.getBoundingClientRect(), R = this.rect;
      if (!R) return null;
      return [(e.clientX - b.left - R.x) / R.s, (e.clientY - b.top - R.y) / R.s];
    };
    const clamp = (v) => Math.max(0, Math.min(1, v));
    c.addEventListener("pointerdown", (e) => {
      const p = toFrac(e);
      if (!p || p[0] < 0 || p[0] > 1 || p[1] < 0 || p[1] > 1 || e.button !== 0) return;
      try {
        c.setPointerCapture(e.pointerId); // the drag may end outside the canvas
      } catch {
        // not an active pointer (a synthetic event): fine without capture
      }
      this.drag = { start: p, end: p, x: e.clientX, y: e.clientY };
      this.dirty = true;
    });
    c.addEventListener("pointermove", (e) => {
      if (!this.drag) return;
      const p = toFrac(e);
      if (p) this.drag.end = [clamp(p[0]), clamp(p[1])];
      this.dirty = true;
    });
    const finish = (e) => {
      const d = this.drag;
      if (!d) return;
      this.drag = null;
      const moved = Math.hypot(e.clientX - d.x, e.clientY - d.y);
      if (moved < 4) this.region = null; // a click clears the region
      else {
        const [a, b] = [d.start, d.end];
        this.region = [Math.min(a[0], b[0]), Math.min(a[1], b[1]), Math.max(a[0], b[0]), Math.max(a[1], b[1])];
      }
      this.readoutKey = "";
      this.lastReadout = 0;
      this.dirty = true;
    };
    c.addEventListener("pointerup", finish);
    c.addEventListener("pointercancel", finish);
  }

  /** Pixel bounds [c0, r0, c1, r1] (inclusive) of the pixels whose centres lie in the region. */
  regionPixels(P) {
    const g = this.region;
    if (!g) return null;
    const lo = (f) => Math.max(0, Math.ceil(f * P - 0.5));
    const hi = (f) => Math.min(P - 1, Math.floor(f * P - 0.5));
    let [c0, r0, c1, r1] = [lo(g[0]), lo(g[1]), hi(g[2]), hi(g[3])];
    // a region smaller than a pixel: the pixel under its centre
    if (c1 < c0) c0 = c1 = Math.min(P - 1, Math.floor(((g[0] + g[2]) / 2) * P));
    if (r1 < r0) r0 = r1 = Math.min(P - 1, Math.floor(((g[1] + g[3]) / 2) * P));
    return [c0, r0, c1, r1];
  }

  /**
   * Statistics of the region against the rest of the image: on the current frame when the
   * region is scanned in it, else on the last finished frame.
   */
  computeRegion() {
    if (!this.region) return null;
    let f = this.cur;
    if (!f) return null;
    let px = this.regionPixels(f.pixels);
    // the region not yet scanned in this frame: the last finished one of the same raster
    const l = this.last;
    if (!f.covers(px[1], px[3]) && l && l !== f && l.epoch === f.epoch && l.generation === f.generation && l.pixels === f.pixels && l.data.has(this.channel)) {
      f = this.last;
      px = this.regionPixels(f.pixels);
    }
    const values = f.data.get(this.channel);
    if (!values) return null;
    const P = f.pixels;
    const [c0, r0, c1, r1] = px;
    const a = boxStats(values, P, px, true), b = boxStats(values, P, px, false);
    // The paper's sign (1 − S_Si/S_Inh): the rest of the image is the reference.
    const contrast = 1 - b.mean / a.mean;
    const cnr = Math.abs(a.mean - b.mean) / b.std;
    // Where attractive and repulsive orbits coexist, the region can be on the other branch:
    // its contrast then compares two orbits, not two materials.
    const regimes = f.data.get("regime");
    const branchIn = regimes ? boxRegime(regimes, P, px, true) : null;
    const branchOut = regimes ? boxRegime(regimes, P, px, false) : null;
    return {
      channel: this.channel,
      unit: f.units[this.channel] ?? unitOf(this.channel),
      frame: f.frame,
      generation: f.generation,
      finished: f.done,
      complete: f.nRows === P,
      pixels: [c0, r0, c1, r1],
      meanIn: a.mean, stdIn: a.std, nIn: a.n,
      meanOut: b.mean, stdOut: b.std, nOut: b.n,
      difference: a.mean - b.mean,
      contrast, cnr,
      branchIn, branchOut,
      acrossBranches: !!(branchIn && branchOut && branchIn !== branchOut),
    };
  }

  updateReadout(now) {
    const f = this.cur;
    const key = `${this.channel}|${f?.key}|${f?.log.length}|${this.region?.join(",")}|${this.last?.key}`;
    if (key === this.readoutKey) return;
    this.readoutKey = key;
    this.lastReadout = now;
    const s = (this.regionStats = this.computeRegion());
    if (!this.region) {
      this.regionEl.innerHTML = `<tr><td class="muted">Drag a rectangle on the image to measure a region's contrast against the rest of the image.</td></tr>`;
      return;
    }
    if (!s || !s.nIn) {
      this.regionEl.innerHTML = `<tr><td class="muted">no ${esc(this.channel)} data in the region yet</td></tr>`;
      return;
    }
    const u = s.unit;
    const [c0, r0, c1, r1] = s.pixels;
    const pct = (v) => (isFinite(v) ? `${(v * 100).toFixed(2).replace("-", "−")} %` : "–");
    const src = `${s.finished ? "finished" : "current"} frame ${s.frame}${s.complete ? "" : " (lines so far)"}`;
    this.regionEl.innerHTML =
      `<tr><th></th><th>mean</th><th>std</th><th>pixels</th></tr>` +
      `<tr data-key="in"><th>region</th><td data-value="${s.meanIn}">${si(s.meanIn, u)}</td><td>${si(s.stdIn, u, 3)}</td><td>${s.nIn}</td></tr>` +
      `<tr data-key="out"><th>rest of image</th><td data-value="${s.meanOut}">${si(s.meanOut, u)}</td><td>${si(s.stdOut, u, 3)}</td><td>${s.nOut}</td></tr>` +
      // A height "contrast" in % means nothing: heights are compared as a difference in m.
      (this.channel === "height"
        ? `<tr data-key="difference" title="mean(region) − mean(rest)"><th>height difference ⟨in⟩ − ⟨out⟩</th><td colspan="3" data-value="${isFinite(s.difference) ? s.difference : ""}"><b>${si(s.difference, u)}</b></td></tr>`
        : `<tr data-key="contrast" title="c = 1 − mean(rest) / mean(region), the paper's 1 − S_Si/S_Inh: negative when the region is weaker"><th>contrast c = 1 − ⟨out⟩/⟨in⟩</th><td colspan="3" data-value="${isFinite(s.contrast) ? s.contrast : ""}"><b>${pct(s.contrast)}</b></td></tr>`) +
      `<tr data-key="cnr" title="contrast-to-noise ratio |mean(region) − mean(rest)| / std(rest)"><th>CNR |Δ⟨⟩| / σ<sub>out</sub></th><td colspan="3" data-value="${isFinite(s.cnr) ? s.cnr : ""}">${isFinite(s.cnr) ? s.cnr.toPrecision(3) : s.cnr === Infinity ? "∞" : "–"}</td></tr>` +
      (s.acrossBranches
        ? `<tr data-key="branches" class="warn"><td colspan="4">the region was imaged on the <b>${esc(s.branchIn)}</b> branch and the rest on the <b>${esc(s.branchOut)}</b>: this contrast compares two orbits, not two materials</td></tr>`
        : "") +
      `<tr><td colspan="4" class="muted">${esc(s.channel)}, columns ${c0}–${c1}, lines ${r0}–${r1}; ${esc(src)}</td></tr>`;
  }

  // ---- drawing ----

  updateProgress() {
    const m = this.latest;
    let text;
    if (this.unsupported) text = `this daemon has no image stream (${this.unsupported})`;
    else if (!m) text = this.scanning === false ? "scan stopped: press Start scan" : this.subscribed ? "waiting for the first scan line…" : "";
    else {
      const rate = this.lineRate();
      const left = m.pixels - 1 - m.line;
      const eta = this.scanning === false ? "" : `, ETA ${fmtDuration(left / rate)}`;
      text = `line ${m.line + 1}/${m.pixels}, frame ${m.frame}, ${isFinite(rate) ? rate.toFixed(1) : "–"} lines/s${eta}` +
        ` · ${siShort(m.size, "m", 4)} × ${siShort(m.size, "m", 4)}, ${m.pixels} × ${m.pixels} px` +
        (this.scanning === false ? " · scan stopped" : "");
    }
    if (this.progressEl.textContent !== text) this.progressEl.textContent = text;
  }

  draw(now) {
    if (now - this.lastReadout >= READOUT_MS) {
      this.lastReadout = now;
      this.updateProgress();
      this.updateReadout(now);
    }
    if (!this.dirty && !this.pendingRange(now)) return;
    if (now - this.lastDraw < MIN_FRAME_MS) return;
    this.lastDraw = now;
    this.dirty = false;
    const shown = new Set([this.channel, ...THUMBS]);
    let changed = false;
    for (const name of shown) changed = this.updateLayer(name, now) || changed;
    for (const name of this.layers.keys()) if (!shown.has(name)) this.layers.delete(name);
    const l = this.layers.get(this.channel);
    const key = `${l?.version}|${l?.frameKey}|${this.canvas.clientWidth}x${this.canvas.clientHeight}|${this.region}|${JSON.stringify(this.drag)}|${this.mapSel.value}|${this.latest?.size}|${this.scanning}|${this.unsupported}`;
    if (changed || key !== this.drawnKey) {
      this.drawnKey = key;
      this.app.stats.draws.image = (this.app.stats.draws.image ?? 0) + 1;
      this.drawMain();
    }
    this.drawThumbs();
  }

  /** Whether a layer has lines waiting for a range re-evaluation. */
  pendingRange(now) {
    const f = this.cur;
    if (!f) return false;
    for (const l of this.layers.values()) if (l.rangeLog !== f.log.length && now - l.rangeAt >= RANGE_MS) return true;
    return false;
  }

  drawMain() {
    const c = this.canvas, ctx = this.ctx;
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(120, Math.round(c.clientWidth)), h = Math.max(120, Math.round(c.clientHeight));
    if (c.width !== Math.round(w * dpr) || c.height !== Math.round(h * dpr)) {
      c.width = Math.round(w * dpr);
      c.height = Math.round(h * dpr);
    }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.fillStyle = "#ffffff";
    ctx.fillRect(0, 0, w, h);
    ctx.font = "11px system-ui, -apple-system, 'Segoe UI', Roboto, sans-serif";
    const BAR = 14, LABELS = 76, TOP = 20, BOTTOM = 8;
    const s = Math.max(40, Math.floor(Math.min(h - TOP - BOTTOM, w - 8 - 12 - BAR - LABELS)));
    const x0 = Math.max(4, Math.floor((w - (s + 12 + BAR + LABELS)) / 2)), y0 = TOP;
    this.rect = { x: x0, y: y0, s };
    const f = this.cur, l = this.layers.get(this.channel);
    const unit = f?.units[this.channel] ?? unitOf(this.channel);

    ctx.fillStyle = "#1d2129";
    ctx.textBaseline = "alphabetic";
    ctx.textAlign = "left";
    ctx.fillText(`${this.channel} — ${labelOf(this.channel)}`, x0, TOP - 6);
    if (f) {
      ctx.textAlign = "right";
      ctx.fillStyle = "#6b717c";
      ctx.fillText(`generation ${f.generation} · frame ${f.frame}`, x0 + s, TOP - 6);
    }

    ctx.fillStyle = BACKGROUND;
    ctx.fillRect(x0, y0, s, s);
    const has = f && l && l.frameKey === f.key && l.range;
    if (has) {
      ctx.imageSmoothingEnabled = false;
      ctx.drawImage(l.canvas, 0, 0, f.pixels, f.pixels, x0, y0, s, s);
    }
    ctx.strokeStyle = "#9aa0a9";
    ctx.lineWidth = 1;
    ctx.strokeRect(x0 - 0.5, y0 - 0.5, s + 1, s + 1);

    // length scale bar, bottom left inside the image
    const size = f?.size ?? this.latest?.size;
    const L = scaleBarLength(size);
    if (has && L > 0) {
      const bw = (L / size) * s, bx = x0 + 10, by = y0 + s - 12;
      ctx.fillStyle = "rgba(0,0,0,0.55)";
      ctx.fillRect(bx - 1, by - 1, bw + 2, 6);
      ctx.fillStyle = "#ffffff";
      ctx.fillRect(bx, by, bw, 4);
      ctx.font = "600 11px system-ui, -apple-system, 'Segoe UI', Roboto, sans-serif";
      ctx.textAlign = "left";
      ctx.textBaseline = "bottom";
      ctx.lineWidth = 3;
      ctx.strokeStyle = "rgba(0,0,0,0.7)";
      const label = siShort(L, "m", 3);
      ctx.strokeText(label, bx, by - 3);
      ctx.fillText(label, bx, by - 3);
      ctx.font = "11px system-ui, -apple-system, 'Segoe UI', Roboto, sans-serif";
    }

    // region (or the one being dragged)
    const g = this.drag ? [Math.min(this.drag.start[0], this.drag.end[0]), Math.min(this.drag.start[1], this.drag.end[1]), Math.max(this.drag.start[0], this.drag.end[0]), Math.max(this.drag.start[1], this.drag.end[1])] : this.region;
    if (g) {
      const rx = x0 + g[0] * s, ry = y0 + g[1] * s, rw = (g[2] - g[0]) * s, rh = (g[3] - g[1]) * s;
      ctx.lineWidth = 1.5;
      ctx.setLineDash([]);
      ctx.strokeStyle = "rgba(0,0,0,0.8)";
      ctx.strokeRect(rx, ry, rw, rh);
      ctx.setLineDash([4, 3]);
      ctx.strokeStyle = "#ffffff";
      ctx.strokeRect(rx, ry, rw, rh);
      ctx.setLineDash([]);
    }

    // colour scale bar with min / max (and the middle) in SI units
    const cx = x0 + s + 12;
    ctx.imageSmoothingEnabled = true;
    ctx.drawImage(this.colourBar(this.mapSel.value), 0, 0, 1, 256, cx, y0, BAR, s);
    ctx.strokeStyle = "#9aa0a9";
    ctx.lineWidth = 1;
    ctx.strokeRect(cx - 0.5, y0 - 0.5, BAR + 1, s + 1);
    ctx.fillStyle = "#1d2129";
    ctx.textAlign = "left";
    const r = has ? l.range : null;
    const tx = cx + BAR + 5;
    ctx.textBaseline = "top";
    ctx.fillText(r ? si(r[1], unit) : "–", tx, y0);
    ctx.textBaseline = "middle";
    if (r) {
      ctx.fillStyle = "#6b717c";
      ctx.fillText(si((r[0] + r[1]) / 2, unit), tx, y0 + s / 2);
      ctx.fillStyle = "#1d2129";
    }
    ctx.textBaseline = "bottom";
    ctx.fillText(r ? si(r[0], unit) : "–", tx, y0 + s);

    if (!has) {
      ctx.fillStyle = "#6b717c";
      ctx.textAlign = "center";
      ctx.textBaseline = "middle";
      const msg = this.unsupported ? "no image stream on this daemon"
        : f && !f.data.has(this.channel) ? `no ${this.channel} values in this image`
          : this.scanning === false && !f ? "scan stopped: press Start scan"
            : "waiting for scan lines…";
      ctx.fillText(msg, x0 + s / 2, y0 + s / 2);
    }
  }

  /** A 1 × 256 canvas of the colour map, its top the high end (cached per map). */
  colourBar(name) {
    this.bars ??= new Map();
    let c = this.bars.get(name);
    if (!c) {
      const lut = (COLOUR_MAPS[name] ?? COLOUR_MAPS.viridis).lut;
      c = document.createElement("canvas");
      c.width = 1;
      c.height = 256;
      const ctx = c.getContext("2d");
      const img = ctx.createImageData(1, 256);
      for (let y = 0; y < 256; y++) {
        const j = 255 - y;
        img.data.set([lut[3 * j], lut[3 * j + 1], lut[3 * j + 2], 255], 4 * y);
      }
      ctx.putImageData(img, 0, 0);
      this.bars.set(name, c);
    }
    return c;
  }

  drawThumbs() {
    const f = this.cur;
    const dpr = window.devicePixelRatio || 1;
    for (const t of this.thumbs) {
      const l = this.layers.get(t.name);
      const key = `${l?.version}|${l?.frameKey}|${t.canvas.clientWidth}`;
      if (key === t.key) continue;
      t.key = key;
      const w = Math.max(16, Math.round(t.canvas.clientWidth));
      if (t.canvas.width !== Math.round(w * dpr)) {
        t.canvas.width = t.canvas.height = Math.round(w * dpr);
      }
      const ctx = t.ctx;
      ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
      ctx.fillStyle = BACKGROUND;
      ctx.fillRect(0, 0, w, w);
      if (f && l && l.frameKey === f.key && l.range) {
        ctx.imageSmoothingEnabled = false;
        ctx.drawImage(l.canvas, 0, 0, f.pixels, f.pixels, 0, 0, w, w);
      }
    }
  }

  /** For tests and the console. */
  values() {
    const f = this.cur, l = this.layers.get(this.channel);
    return {
      channel: this.channel,
      channels: this.channelNames.slice(),
      subscribed: this.subscribed,
      scanning: this.scanning,
      generation: f?.generation ?? null,
      frame: f?.frame ?? null,
      line: f?.lastLine ?? null,
      lines: f?.nRows ?? 0,
      // The last finished frame: its identity and how many of its lines arrived.
      lastFrame: this.last ? { generation: this.last.generation, frame: this.last.frame, pixels: this.last.pixels, lines: this.last.nRows } : null,
      pixels: f?.pixels ?? null,
      framesFinished: this.framesFinished,
      exportable: this.exportable,
      range: l?.range ?? null,
      rect: this.rect ?? null,
      region: this.regionStats,
      latest: this.latest,
    };
  }
}
