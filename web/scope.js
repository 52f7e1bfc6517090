// The photodiode time trace (scope stream), and the same trace with the fundamental and
// the mean removed (the paper's Fig. 4): s_j − (X·cos θ_j − Y·sin θ_j), θ_j = start_phase +
// j·phase_step, with X, Y the latest output of the demodulator at harmonic 1 (demodulator 0
// by default). What remains are the tap pulses and the higher modes they ring up. The
// "folded" view averages that residual over drive phase (mod 2π) across recent traces, which
// lifts the pulse shape out of the ADC and detector noise.

import { Plot, StickyRange } from "./plot.js";
import { si } from "./units.js";

const MAX_BINS = 200; // phase bins per drive period: one per trace sample, at most this
const FOLD_DECAY = 0.95; // weight kept per trace: about the last 20 traces (1 s at 20 Hz)

export class ScopePanel {
  constructor(app) {
    this.app = app;
    this.data = null;
    this.res = new Float32Array(0);
    this.dirty = true;
    const redraw = () => { this.dirty = true; };
    this.raw = new Plot(document.getElementById("scope-raw"), {
      x: { label: "time in trace", unit: "s" },
      y: { label: "deflection", unit: "m" },
    }, redraw);
    this.resPlot = new Plot(document.getElementById("scope-res"), {
      x: { label: "time in trace", unit: "s" },
      y: { label: "without fundamental", unit: "m" },
    }, redraw);
    this.rawRange = new StickyRange();
    this.resRange = new StickyRange();
    this.foldRange = new StickyRange();
    this.foot = document.getElementById("scope-foot");
    this.mode = document.getElementById("scope-mode");
    this.mode.addEventListener("change", () => { this.resRange.reset(); this.foldRange.reset(); this.dirty = true; });
    this.foldSum = null; // per phase bin: weighted sum and weight
    this.foldW = null;
    this.fold = new Float64Array(MAX_BINS); // the non-empty bins: mean and phase (°)
    this.foldX = new Float64Array(MAX_BINS);
    this.foldN = 0;
  }

  /**
   * Adds a residual trace to the folded average (exponentially forgetting older traces).
   * One bin per trace sample of a drive period (traces often start at the same drive phase,
   * so finer bins would stay empty); restarts when the period changes.
   */
  accumulateFold(res, startPhase, step) {
    const TWO_PI = 2 * Math.PI;
    const bins = Math.max(8, Math.min(MAX_BINS, Math.round(TWO_PI / Math.abs(step || TWO_PI))));
    if (!this.foldSum || this.foldSum.length !== bins) {
      this.foldSum = new Float64Array(bins);
      this.foldW = new Float64Array(bins);
      this.fold = new Float64Array(bins);
      this.foldRange.reset();
    }
    const sum = this.foldSum, w = this.foldW;
    for (let b = 0; b < bins; b++) { sum[b] *= FOLD_DECAY; w[b] *= FOLD_DECAY; }
    for (let j = 0; j < res.length; j++) {
      let ph = (startPhase + j * step) % TWO_PI;
      if (ph < 0) ph += TWO_PI;
      const b = Math.min(bins - 1, Math.floor((ph / TWO_PI) * bins + 0.5) % bins);
      sum[b] += res[j];
      w[b] += 1;
    }
    let lo = Infinity, hi = -Infinity;
    let valid = 0;
    for (let b = 0; b < bins; b++) {
      if (w[b] > 1e-6) {
        const v = sum[b] / w[b];
        this.fold[valid] = v;
        this.foldX[valid] = (b * 360) / bins;
        valid++;
        if (v < lo) lo = v;
        if (v > hi) hi = v;
      }
    }
    this.foldN = valid;
    this.foldRange.update(lo, hi);
  }

  /** Demodulator measuring harmonic 1 of the drive: demodulator 0 if it does, else the first
   * that does. */
  fundamental() {
    const h = this.app.history;
    const i = h.harmonic[0] === 1 && h.onDrive(0) ? 0 : h.indexOf(1);
    return i >= 0 && h.latest[i] ? { i, d: h.latest[i] } : null;
  }

  onData(m) {
    const s = m.samples, n = s.length;
    if (this.res.length !== n) this.res = new Float32Array(n);
    const res = this.res;
    const f = this.fundamental();
    const X = f ? f.d.x : 0, Y = f ? f.d.y : 0;
    let sum = 0, lo = Infinity, hi = -Infinity;
    for (let j = 0; j < n; j++) {
      const th = m.start_phase + j * m.phase_step;
      const v = s[j] - (X * Math.cos(th) - Y * Math.sin(th));
      res[j] = v;
      sum += v;
      if (s[j] < lo) lo = s[j];
      if (s[j] > hi) hi = s[j];
    }
    const mean = sum / n;
    let rlo = Infinity, rhi = -Infinity;
    for (let j = 0; j < n; j++) {
      const v = (res[j] -= mean);
      if (v < rlo) rlo = v;
      if (v > rhi) rhi = v;
    }
    this.rawRange.update(lo, hi);
    this.resRange.update(rlo, rhi);
    this.accumulateFold(res, m.start_phase, m.phase_step);
    this.data = { t: m.t, dt: m.dt, samples: s, fund: f, X, Y };
    this.dirty = true;
  }

  draw() {
    if (!this.dirty) return;
    this.dirty = false;
    const d = this.data;
    const folded = this.mode.value === "fold";
    const span = d ? d.dt * (d.samples.length - 1) : 2e-4;
    const rp = this.resPlot;
    this.raw.begin([0, span], this.rawRange.r ?? [-3e-8, 3e-8]);
    if (folded) {
      rp.opts.x = { label: "drive phase θ (two cycles)", unit: "°", ticks: [0, 90, 180, 270, 360, 450, 540, 630, 720] };
      rp.opts.y.label = "averaged residual";
      rp.begin([0, 720], this.foldRange.r ?? [-1e-9, 1e-9]);
    } else {
      rp.opts.x = { label: "time in trace", unit: "s" };
      rp.opts.y.label = "without fundamental";
      rp.begin([0, span], this.resRange.r ?? [-1e-9, 1e-9]);
    }
    if (d) {
      const dt = d.dt, s = d.samples, r = this.res;
      this.raw.line(s.length, (j) => j * dt, (j) => s[j], "#0b62a4", 1.1);
      rp.hline(0, "#9aa0a9");
      if (folded) {
        const f = this.fold, fx = this.foldX, B = this.foldN;
        if (B) rp.line(2 * B + 1, (i) => fx[i % B] + (i >= B ? (i >= 2 * B ? 720 : 360) : 0), (i) => f[i % B], "#d55e00", 1.6);
        // The tap: the drive phase of the force peak, from the latest FT-AFM estimate.
        const ph = this.app.force?.latest?.pulse_phase;
        if (typeof ph === "number" && isFinite(ph)) {
          const deg = ((((ph * 180) / Math.PI) % 360) + 360) % 360;
          for (const x of [deg, deg + 360]) rp.vline(x, "#1d2129", [4, 3], x === deg ? "tap" : null);
        }
        rp.label(rp.left + 6, rp.top + 4, "θ = 0: drive phase zero (cosine reference) · dashed: the tap (force peak)", "#4a4f57");
      } else {
        rp.line(r.length, (j) => j * dt, (j) => r[j], "#d55e00", 1.1);
      }
      if (!d.fund) rp.label(rp.left + 6, rp.bottom - 18, "no demodulator at harmonic 1: only the mean removed", "#c62828");
      this.app.stats.draws.scope++;
    } else {
      this.raw.message("waiting for scope traces…");
      rp.message("waiting for scope traces…");
    }
    this.raw.end();
    rp.end();
    this.foot.textContent = d
      ? `${d.samples.length} samples, Δt = ${si(d.dt, "s", 3)}, t = ${d.t.toFixed(3)} s` +
        (d.fund ? ` · fundamental from demod ${d.fund.i}: X = ${si(d.X, "m", 4)}, Y = ${si(d.Y, "m", 4)}` : "")
      : "";
  }
}
