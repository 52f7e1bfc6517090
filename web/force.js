// FT-AFM force estimates (the `force` stream, docs/protocol.md): the reconstructed tap force
// over one drive period, the latest τ, F, E with their standard deviations, and trends of E
// and F over the last 10 s with a running 0.5 s mean ± std, so a change can be seen to settle.
// Messages (1 kHz by default) are only stored on arrival; drawing happens on animation frames.

import { Plot, StickyRange } from "./plot.js";
import { si } from "./units.js";
import { forceWaveform } from "./conn.js";

const TREND_S = 10; // seconds of trend shown
const FORCE_PAGE_HZ = 50; // force estimates a second the page takes at most
const STATS_S = 0.5; // running mean ± std window
const CAP = 16384; // ring capacity: > 10 s at 1 kHz
const MIN_FRAME_MS = 26; // ~30 fps, as the harmonics plots
const READOUT_MS = 200;

const num = (v) => (typeof v === "number" && isFinite(v) ? v : NaN);

export class ForcePanel {
  constructor(app) {
    this.app = app;
    this.latest = null;
    this.shown = null;
    this.t = new Float64Array(CAP);
    this.E = new Float64Array(CAP);
    this.F = new Float64Array(CAP);
    this.tau = new Float64Array(CAP);
    this.head = 0; // index of the next write
    this.len = 0;
    this.version = 0;
    this.drawn = -1;
    this.lastDraw = 0;
    this.lastReadout = 0;
    this.dirty = true;
    const redraw = () => { this.dirty = true; };
    this.wPlot = new Plot(document.getElementById("force-wave"), {
      x: { label: "drive phase θ", unit: "°", ticks: [0, 45, 90, 135, 180, 225, 270, 315, 360] },
      y: { label: "force", unit: "N" },
      margin: { l: 62 },
    }, redraw);
    this.ePlot = new Plot(document.getElementById("force-e"), {
      x: { label: "time before now", unit: "s" },
      y: { label: "E", unit: "Pa" },
      margin: { l: 62 },
    }, redraw);
    this.fPlot = new Plot(document.getElementById("force-f"), {
      x: { label: "time before now", unit: "s" },
      y: { label: "F", unit: "N" },
      margin: { l: 62 },
    }, redraw);
    this.wRange = new StickyRange();
    this.readout = document.getElementById("force-readout");
    this.foot = document.getElementById("force-foot");
    // The force stream (1 kHz by default, ~6 kB a message) is only subscribed while the panel
    // is on screen and the page visible: the daemon only produces it for subscribers.
    this.visible = false;
    this.subscribed = false;
    this.busy = false;
    new IntersectionObserver((entries) => {
      for (const e of entries) this.visible = e.isIntersecting;
      this.updateSubscription();
    }).observe(document.getElementById("p-force"));
    document.addEventListener("visibilitychange", () => this.updateSubscription());
  }

  /** After (re)connecting: nothing is subscribed on the new socket. */
  onOpen() {
    this.subscribed = false;
    this.updateSubscription();
  }

  async updateSubscription() {
    const conn = this.app.conn;
    if (this.busy || !conn || !conn.open) return;
    const want = this.visible && !document.hidden;
    if (want === this.subscribed) return;
    this.busy = true;
    try {
      if (want) {
        // The page draws at most ~50 estimates a second: it takes every n-th of the stream
        // (`every`), so it keeps up and a seq gap is a real loss.
        // Before `list` has answered the rates are unknown: assume the default 1 kHz.
        const node = (p, fallback) => Number(this.app.nodes.get(p)?.value ?? fallback);
        const rate = node("/demods/0/rate", 1000) / Math.max(1, node("/inversion/averaging", 1) || 1);
        const every = Number.isFinite(rate) ? Math.max(1, Math.round(rate / FORCE_PAGE_HZ)) : 20;
        this.app.resetSeq?.("force", every);
        await conn.request("subscribe", { stream: "force", format: "binary", every });
      } else {
        await conn.request("unsubscribe", { stream: "force" });
      }
      this.subscribed = want;
    } catch (e) {
      if (e.code !== "disconnected") console.warn("ftafm: force stream:", e.message);
    } finally {
      this.busy = false;
    }
    // the wish may have changed meanwhile
    if ((this.visible && !document.hidden) !== this.subscribed && conn.open) this.updateSubscription();
  }

  onData(m) {
    this.latest = m;
    // An estimate of the old settings' model (the new one is being built) is shown as
    // such, and kept out of the trends and their means.
    if (m.stale) {
      this.version++;
      return;
    }
    const i = this.head;
    this.t[i] = num(m.t);
    this.E[i] = num(m.youngs_modulus);
    this.F[i] = num(m.max_force);
    this.tau[i] = num(m.contact_time_ratio);
    this.head = (i + 1) % CAP;
    if (this.len < CAP) this.len++;
    this.version++;
  }

  /** Ring position of the j-th stored point, oldest first. */
  pos(j) {
    return (this.head - this.len + j + CAP) % CAP;
  }

  get tNow() {
    return this.len ? this.t[this.pos(this.len - 1)] : NaN;
  }

  /** First stored index with t ≥ t0. */
  firstSince(t0) {
    let lo = 0, hi = this.len;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (this.t[this.pos(mid)] < t0) lo = mid + 1;
      else hi = mid;
    }
    return lo;
  }

  /** Mean and standard deviation of `arr` over the last `seconds` (finite values only). */
  stats(arr, seconds = STATS_S) {
    if (!this.len) return null;
    const from = this.firstSince(this.tNow - seconds);
    let n = 0, s = 0, s2 = 0;
    for (let j = from; j < this.len; j++) {
      const v = arr[this.pos(j)];
      if (v === v) { n++; s += v; }
    }
    if (!n) return null;
    const mean = s / n;
    for (let j = from; j < this.len; j++) {
      const v = arr[this.pos(j)];
      if (v === v) s2 += (v - mean) ** 2;
    }
    return { mean, std: n > 1 ? Math.sqrt(s2 / (n - 1)) : 0, n };
  }

  /** For tests and the console: 0.5 s means of E (Pa), F (N), τ, and the latest message. */
  values() {
    const g = (a) => this.stats(a)?.mean ?? null;
    return { E: g(this.E), F: g(this.F), tau: g(this.tau), latest: this.latest };
  }

  draw(now) {
    if (now - this.lastReadout >= READOUT_MS) {
      this.lastReadout = now;
      this.updateReadout();
    }
    if (!this.dirty && this.version === this.drawn) return;
    if (now - this.lastDraw < MIN_FRAME_MS) return;
    this.lastDraw = now;
    this.drawn = this.version;
    this.dirty = false;
    this.app.stats.draws.force++;
    this.drawWave();
    this.drawTrend(this.ePlot, this.E, "#0b62a4", "Pa");
    this.drawTrend(this.fPlot, this.F, "#d55e00", "N");
  }

  drawWave() {
    const p = this.wPlot, m = this.latest;
    const w = forceWaveform(m);
    if (w && w.length) {
      let lo = Infinity, hi = -Infinity;
      for (const v of w) if (typeof v === "number" && isFinite(v)) { if (v < lo) lo = v; if (v > hi) hi = v; }
      if (hi > lo) {
        const pad = 0.08 * (hi - lo);
        this.wRange.update(Math.min(0, lo - pad), hi + pad);
      }
    }
    p.begin([0, 360], this.wRange.r ?? [-1e-8, 8e-8]);
    if (w && w.length) {
      const n = w.length;
      p.hline(0, "#9aa0a9");
      // closed over the period: the point at 360° repeats θ = 0
      p.line(n + 1, (j) => (j * 360) / n, (j) => num(w[j % n]), "#0b62a4", 1.6);
      const ph = num(m.pulse_phase);
      if (ph === ph) {
        const deg = ((((ph * 180) / Math.PI) % 360) + 360) % 360;
        p.vline(deg, "#d55e00", [4, 3]);
      }
      p.label(p.left + 6, p.top + 4, `latest estimate · ${m.method === "two_harmonic" ? "two-harmonic" : "full"} method`, "#4a4f57");
    } else {
      p.message(this.app.nodes.get("/inversion/enable")?.value === false ? "inversion disabled (/inversion/enable)" : "waiting for force estimates… (received while this panel is on screen)");
    }
    p.end();
  }

  drawTrend(p, arr, color, unit) {
    const tNow = this.tNow;
    const from = this.len ? this.firstSince(tNow - TREND_S) : 0;
    const n = this.len - from;
    let lo = Infinity, hi = -Infinity;
    for (let j = from; j < this.len; j++) {
      const v = arr[this.pos(j)];
      if (v < lo) lo = v;
      if (v > hi) hi = v;
    }
    let yr;
    if (hi >= lo) {
      const pad = Math.max(0.08 * (hi - lo), 0.02 * Math.abs(hi) || 1e-12);
      yr = [lo - pad, hi + pad];
    } else yr = unit === "Pa" ? [0, 2e11] : [0, 1e-7];
    p.begin([-TREND_S, 0], yr);
    if (n > 0) {
      const st = this.stats(arr);
      if (st) {
        // the running 0.5 s mean ± std over its window
        const x0 = Math.max(-TREND_S, -STATS_S);
        p.clip((ctx) => {
          ctx.fillStyle = "rgba(0, 158, 115, 0.16)";
          const y1 = p.Y(st.mean + st.std), y2 = p.Y(st.mean - st.std);
          ctx.fillRect(p.X(x0), y1, p.X(0) - p.X(x0), Math.max(1, y2 - y1));
        });
      }
      // a pause in the stream (panel off screen, reconnecting) breaks the line: NaN skips a point
      const t = this.t;
      const yAt = (j) => (j > 0 && t[this.pos(from + j)] - t[this.pos(from + j - 1)] > 0.05 ? NaN : arr[this.pos(from + j)]);
      p.line(n, (j) => t[this.pos(from + j)] - tNow, yAt, color, 1.1);
      if (st) {
        p.hline(st.mean, "#009e73", [5, 3]);
        p.label(p.left + 6, p.top + 4, `0.5 s: ${si(st.mean, unit, 4)} ± ${si(st.std, unit, 3)}`, "#1a7f37", "left", "top", true);
      }
    } else {
      p.message("no estimates yet");
    }
    p.end();
  }

  updateReadout() {
    const m = this.latest;
    // The message the readout and the footer show: `latest` moves on between readouts.
    this.shown = m;
    const row = (key, label, value, sigma, arr, unit, digits) => {
      const st = this.stats(arr);
      const mean = st ? st.mean : NaN;
      const fmt = (v, d = digits) => (unit ? si(v, unit, d) : isFinite(v) ? v.toFixed(digits) : "–");
      return `<tr data-key="${key}"><th>${label}</th>` +
        `<td class="now" data-value="${isFinite(value) ? value : ""}">${fmt(value)} <span class="pm">± ${fmt(sigma, 3)}</span></td>` +
        `<td class="mean" data-value="${isFinite(mean) ? mean : ""}">${fmt(mean)} <span class="pm">± ${st ? fmt(st.std, 3) : "–"}</span></td></tr>`;
    };
    if (!m) {
      this.readout.innerHTML = `<tr><td colspan="3" class="muted">waiting for the force stream…</td></tr>`;
      this.foot.textContent = "";
      return;
    }
    this.readout.innerHTML =
      `<tr><th></th><th>latest ± σ</th><th>0.5 s mean ± std</th></tr>` +
      row("tau", "contact time ratio τ", num(m.contact_time_ratio), num(m.contact_time_ratio_sigma), this.tau, null, 4) +
      row("F", "peak force F", num(m.max_force), num(m.max_force_sigma), this.F, "N", 4) +
      row("E", "Young's modulus E", num(m.youngs_modulus), num(m.youngs_modulus_sigma), this.E, "Pa", 4);
    const range = m.table_range && m.table_range !== "inside"
      ? ` · <span class="bad">table range: ${m.table_range === "below_table" ? "below the table's lower end" : m.table_range === "above_table" ? "above the table's upper end" : String(m.table_range).replace(/[<>&]/g, "")}</span>`
      : "";
    const method = m.method === "two_harmonic" ? "two-harmonic (cut-cosine pulse)" : "full (Fourier series)";
    const stale = m.stale
      ? ` · <span class="bad" data-stale="true">stale: made with the model of the previous settings (epoch ${Number(m.epoch)}); the new model is being built</span>`
      : "";
    // Why the estimate may be biased or poor, each with what to change (a row each).
    const warnings = Array.isArray(m.warnings) && m.warnings.length
      ? m.warnings.map((w) => `<div class="bad" data-force-warning="true">⚠ ${String(w).replace(/[<>&]/g, "")}</div>`).join("")
      : "";
    // The modulus's 68 % interval: asymmetric where E is poorly resolved, which ± σ hides.
    const iv = Array.isArray(m.youngs_modulus_interval) ? m.youngs_modulus_interval.map(num) : [];
    const interval = iv.length === 2 && iv.every(isFinite)
      ? ` · <span data-key="E-interval">E 68 % interval ${si(iv[0], "Pa", 3)} – ${si(iv[1], "Pa", 3)}</span>`
      : "";
    this.foot.innerHTML = `method <b>${method}</b> · ${forceWaveform(m)?.length ?? 0} points · t = ${num(m.t).toFixed(3)} s${interval}${range}${stale}${warnings}`;
  }
}
