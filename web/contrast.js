// Harmonic amplitudes S(k) and the relative contrast of the paper's Fig. 3b, with the
// paper's sign: c_rel(k) = 1 − S_ref(k) / S_now(k) for k = 1 … 32 (the paper's
// 1 − S_Si/S_Inh with the reference in place of silicon), where S is the 2 s mean of the
// lock-in amplitude at harmonic k and S_ref was captured by "Set reference". 2 s resolve the
// paper's ≈ 3 % at harmonics 17 and 18 (116.1 vs 129 GPa) above the default noise.

import { Plot, decadeRange } from "./plot.js";
import { si, siShort } from "./units.js";

const K = 32;
const SPAN = 2; // s of averaging (simulated time)
const UPDATE_MS = 200;
const NOW = "#0b62a4";
const POS = "#0b62a4";
const NEG = "#d55e00";
const WEAK = "#c4c8d0";
const STEPS = [0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000];

export class ContrastPanel {
  constructor(app) {
    this.app = app;
    this.ref = new Float64Array(K + 1).fill(NaN);
    this.refNoise = new Float64Array(K + 1).fill(NaN);
    this.now = new Float64Array(K + 1).fill(NaN);
    this.noise = new Float64Array(K + 1).fill(NaN);
    this.c = new Float64Array(K + 1).fill(NaN);
    this.hasRef = false;
    this.last = 0;
    this.dirty = true;
    const redraw = () => { this.dirty = true; };
    this.ampPlot = new Plot(document.getElementById("amp-canvas"), {
      x: { label: "harmonic k", unit: "1", ticks: [1, 4, 8, 12, 16, 20, 24, 28, 32] },
      y: { label: "S(k)", unit: "m", log: true },
      margin: { b: 30, l: 70 },
    }, redraw);
    this.cPlot = new Plot(document.getElementById("contrast-canvas"), {
      x: { label: "harmonic k", unit: "1", ticks: [1, 4, 8, 12, 16, 20, 24, 28, 32] },
      y: { label: "c_rel = 1 − S_ref/S", unit: "%" },
      margin: { b: 30, l: 70 },
    }, redraw);
    this.info = document.getElementById("ref-info");
    document.getElementById("ref-set").addEventListener("click", () => this.setReference());
    document.getElementById("ref-clear").addEventListener("click", () => this.clearReference());
  }

  /** Mean amplitude at harmonic k over the last SPAN seconds, and its standard error. */
  measure(k) {
    const h = this.app.history;
    const i = h.indexOf(k);
    if (i < 0) return null;
    const m = h.mean(i, SPAN);
    if (!m) return null;
    // scatter of r over the same span
    const from = h.firstSince(h.tNow - SPAN);
    let s2 = 0, n = 0;
    for (let j = from; j < h.len; j++) {
      const v = h.r[i][h.pos(j)];
      if (v === v) { s2 += (v - m.r) ** 2; n++; }
    }
    // standard error of the mean: successive outputs are correlated over about the filter's
    // response time, order × τ, so the span holds about span / (2·order·τ) independent ones
    const nodes = this.app.nodes;
    const tc = nodes.get(`/demods/${i}/timeconstant`)?.value ?? 5e-4;
    const order = nodes.get(`/demods/${i}/order`)?.value ?? 4;
    const nEff = Math.max(1, Math.min(n, SPAN / (2 * order * tc)));
    return { r: m.r, sd: n > 1 ? Math.sqrt(s2 / (n - 1) / nEff) : NaN };
  }

  setReference() {
    let got = 0;
    for (let k = 1; k <= K; k++) {
      const m = this.measure(k);
      this.ref[k] = m ? m.r : NaN;
      this.refNoise[k] = m ? m.sd : NaN;
      if (m) got++;
    }
    this.hasRef = got > 0;
    const E = this.app.nodes.get("/sample/youngs_modulus")?.value;
    const t = this.app.history.tNow;
    this.refDesc = this.hasRef
      ? `Reference: ${got} harmonics at t = ${t.toFixed(2)} s` + (typeof E === "number" ? `, sample E = ${siShort(E, "Pa", 5)}` : "")
      : "No demodulator data to take a reference from yet.";
    this.app.stats.references++;
    this.last = 0;
    this.dirty = true;
  }

  clearReference() {
    this.ref.fill(NaN);
    this.hasRef = false;
    this.refDesc = null;
    this.last = 0;
    this.dirty = true;
  }

  update() {
    for (let k = 1; k <= K; k++) {
      const m = this.measure(k);
      this.now[k] = m ? m.r : NaN;
      this.noise[k] = m ? m.sd : NaN;
      this.c[k] = 1 - this.ref[k] / this.now[k];
    }
    const E = this.app.nodes.get("/sample/youngs_modulus")?.value;
    this.info.textContent = this.hasRef
      ? `${this.refDesc} · now E = ${typeof E === "number" ? siShort(E, "Pa", 5) : "?"} · 2 s means · grey: within the noise`
      : this.refDesc ?? "No reference yet: set one on the reference material (e.g. silicon), then change the sample.";
  }

  /** Whether S_now(k) differs from S_ref(k) by more than 3 standard errors of the two means. */
  reliable(k) {
    const diff = Math.abs(this.ref[k] - this.now[k]);
    return diff > 3 * Math.hypot(this.noise[k] || 0, this.refNoise[k] || 0);
  }

  draw(now) {
    if (now - this.last < UPDATE_MS && !this.dirty) return;
    if (now - this.last >= UPDATE_MS) {
      this.last = now;
      this.update();
    }
    this.dirty = false;
    this.app.stats.draws.contrast++;
    this.drawAmplitudes();
    this.drawContrast();
  }

  drawAmplitudes() {
    const p = this.ampPlot;
    let lo = Infinity, hi = 0;
    for (let k = 1; k <= K; k++) for (const v of [this.now[k], this.ref[k]]) if (v > 0) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    const yr = hi > 0 ? decadeRange(lo, hi, 2, 7) : [1e-13, 1e-7];
    p.begin([0.4, K + 0.6], yr);
    const bw = Math.max(2, (p.X(2) - p.X(1)) * 0.62);
    p.clip((ctx) => {
      for (let k = 1; k <= K; k++) {
        const v = this.now[k];
        if (!(v > 0)) continue;
        const x = p.X(k), y = p.Y(v);
        ctx.fillStyle = NOW;
        ctx.fillRect(x - bw / 2, y, bw, p.bottom - y);
      }
      if (this.hasRef) {
        ctx.strokeStyle = "#1d2129";
        ctx.lineWidth = 2;
        ctx.beginPath();
        for (let k = 1; k <= K; k++) {
          const v = this.ref[k];
          if (!(v > 0)) continue;
          const x = p.X(k), y = Math.round(p.Y(v));
          ctx.moveTo(x - bw / 2 - 2, y);
          ctx.lineTo(x + bw / 2 + 2, y);
        }
        ctx.stroke();
      }
    });
    if (!(hi > 0)) p.message("waiting for demodulator data…");
    else p.label(p.right - 4, p.top + 3, this.hasRef ? "bars: now · black: reference (2 s means)" : "bars: now (2 s mean)", "#4a4f57", "right", "top");
    p.end();
  }

  drawContrast() {
    const p = this.cPlot;
    // y range: the largest reliable |c|, snapped to a step, so the data set the scale (±1 %
    // until something is resolved)
    let m = 0;
    if (this.hasRef) for (let k = 1; k <= K; k++) if (isFinite(this.c[k]) && this.reliable(k)) m = Math.max(m, Math.abs(this.c[k]) * 100);
    const top = m > 0 ? (STEPS.find((s) => s >= m * 1.1) ?? STEPS[STEPS.length - 1]) : 1;
    this.axis = top;
    p.opts.y.ticks = null;
    p.begin([0.4, K + 0.6], [-top, top]);
    p.hline(0, "#7d838d");
    if (this.hasRef) {
      const bw = Math.max(2, (p.X(2) - p.X(1)) * 0.62);
      p.clip((ctx) => {
        for (let k = 1; k <= K; k++) {
          const c = this.c[k] * 100;
          if (!isFinite(c)) continue;
          const clipped = Math.max(-top, Math.min(top, c));
          const x = p.X(k), y0 = p.Y(0), y1 = p.Y(clipped);
          ctx.fillStyle = !this.reliable(k) ? WEAK : c >= 0 ? POS : NEG;
          ctx.fillRect(x - bw / 2, Math.min(y0, y1), bw, Math.max(1, Math.abs(y1 - y0)));
          if (clipped !== c) {
            // off scale: a white arrow head inside the end of the bar
            const sgn = c > 0 ? 1 : -1;
            ctx.beginPath();
            ctx.moveTo(x - bw / 2 + 1, y1 + sgn * 8);
            ctx.lineTo(x + bw / 2 - 1, y1 + sgn * 8);
            ctx.lineTo(x, y1 + sgn * 2);
            ctx.fillStyle = "#ffffff";
            ctx.fill();
          }
        }
      });
      p.label(p.right - 4, p.top + 3, "< 0: weaker than the reference (the paper's sign)", "#4a4f57", "right", "top");
    } else {
      p.message("press “Set reference” to compare with the current amplitudes");
    }
    p.end();
  }

  /** For tests and scripts: {k: c_rel} of the harmonics with a reference. */
  values() {
    const out = {};
    for (let k = 1; k <= K; k++) if (isFinite(this.c[k])) out[k] = this.c[k];
    return out;
  }

  /** For tests: {k: true} where c_rel is outside the noise (drawn in colour, not grey), and
   * the axis' half range (%). */
  resolved() {
    const out = {};
    for (let k = 1; k <= K; k++) if (isFinite(this.c[k])) out[k] = this.reliable(k);
    return { reliable: out, axis: this.axis };
  }
}
