// The photodiode spectrum (the paper's Fig. 3a): peak amplitude per bin on a log scale
// against frequency, with the cantilever's flexural resonances and the drive harmonics marked.

import { Plot } from "./plot.js";
import { si } from "./units.js";

// Clamped-free beam eigenvalues λn (cos λ + sech λ = 0); beyond the fifth, (2n − 1)π/2 is
// exact to better than 1e-7.
const LAMBDA = [1.875104069, 4.694091133, 7.854757438, 10.995540735, 14.137168391];
export function lambda(n) {
  return n <= LAMBDA.length ? LAMBDA[n - 1] : ((2 * n - 1) * Math.PI) / 2;
}
/** Resonance frequencies of the first `count` flexural modes for a first mode at f1. */
export function modeFrequencies(f1, count) {
  const out = [];
  for (let n = 1; n <= count; n++) out.push(f1 * (lambda(n) / lambda(1)) ** 2);
  return out;
}

const MODE_COLOR = "#d55e00";
const HARM_COLOR = "#6b7a90";
const TRACE = "#0b62a4";

export class SpectrumPanel {
  constructor(app) {
    this.app = app;
    this.data = null;
    this.dirty = true;
    this.decades = null; // [lo, hi] exponents of the amplitude axis
    this.plot = new Plot(document.getElementById("spec-canvas"), {
      x: { label: "frequency", unit: "Hz" },
      y: { label: "amplitude", unit: "m", log: true },
      margin: { t: 26, l: 70 },
      hover: true,
    }, () => { this.dirty = true; });
    this.range = document.getElementById("spec-range");
    this.showModes = document.getElementById("spec-modes");
    this.showHarm = document.getElementById("spec-harm");
    this.foot = document.getElementById("spec-foot");
    this.avgSel = document.getElementById("spec-avg");
    for (const el of [this.range, this.showModes, this.showHarm]) el.addEventListener("change", () => { this.dirty = true; });
  }

  onData(m) {
    let mags = m.magnitudes;
    const N = Number(this.avgSel.value);
    if (N > 1) {
      // power average: ⟨|X|²⟩ over about the last N spectra, shown as an amplitude
      const a = 1 / N;
      if (!this.pow || this.pow.length !== mags.length || this.powN !== N) {
        this.pow = Float64Array.from(mags, (v) => v * v);
        this.powN = N;
      } else {
        for (let i = 0; i < mags.length; i++) this.pow[i] += a * (mags[i] * mags[i] - this.pow[i]);
      }
      if (!this.avg || this.avg.length !== mags.length) this.avg = new Float32Array(mags.length);
      for (let i = 0; i < mags.length; i++) this.avg[i] = Math.sqrt(this.pow[i]);
      mags = this.avg;
    } else {
      this.pow = null;
    }
    // Amplitude axis: widen at once, narrow only when the data left a whole decade free.
    let max = 0;
    for (let i = 0; i < mags.length; i++) if (mags[i] > max) max = mags[i];
    const sample = [];
    const stride = Math.max(1, Math.floor(mags.length / 2048));
    for (let i = 1; i < mags.length; i += stride) if (mags[i] > 0) sample.push(mags[i]);
    sample.sort((a, b) => a - b);
    const floor = sample.length ? sample[Math.floor(sample.length * 0.01)] : max * 1e-6;
    if (max > 0) {
      const hi = Math.ceil(Math.log10(max * 1.5));
      const lo = Math.floor(Math.log10(Math.max(floor * 0.5, max * 1e-9)));
      if (!this.decades) this.decades = [lo, hi];
      else {
        const d = this.decades;
        if (hi > d[1] || hi < d[1] - 1) d[1] = hi;
        if (lo < d[0] || lo > d[0] + 1) d[0] = lo;
        if (d[1] - d[0] < 2) d[0] = d[1] - 2;
      }
    }
    this.data = { t: m.t, binWidth: m.bin_width, mags };
    this.dirty = true;
  }

  xRange(nyquist) {
    const v = this.range.value;
    const fd = this.app.params.fDrive;
    if (v === "h32" && fd > 0) return [0, Math.min(nyquist, 32.5 * fd)];
    const f = Number(v);
    return [0, f > 0 ? Math.min(f, nyquist) : nyquist];
  }

  draw() {
    if (!this.dirty) return;
    this.dirty = false;
    const p = this.plot;
    const d = this.data;
    const nyq = d ? d.binWidth * (d.mags.length - 1) : (this.app.hello?.sample_rate ?? 1e7) / 2;
    const xr = this.xRange(nyq);
    const dec = this.decades ?? [-15, -7];
    p.begin(xr, [10 ** dec[0], 10 ** dec[1]]);
    const { fDrive, fDrive2, f1, modes } = this.app.params;
    // drive harmonics: ticks along the top with their numbers in the margin
    if (this.showHarm.checked && fDrive > 0) {
      const kmax = Math.floor(xr[1] / fDrive);
      const px = (p.X(fDrive) - p.X(0));
      const every = px >= 16 ? 1 : px >= 7 ? 5 : 10;
      const ctx = p.ctx;
      ctx.strokeStyle = HARM_COLOR;
      ctx.lineWidth = 1;
      ctx.beginPath();
      for (let k = 1; k <= kmax; k++) {
        const x = Math.round(p.X(k * fDrive)) + 0.5;
        const len = k % 5 === 0 ? 9 : 5;
        ctx.moveTo(x, p.top);
        ctx.lineTo(x, p.top + len);
      }
      ctx.stroke();
      ctx.font = "10px system-ui, sans-serif";
      ctx.fillStyle = HARM_COLOR;
      ctx.textAlign = "center";
      ctx.textBaseline = "bottom";
      for (let k = 1; k <= kmax; k++) if (k === 1 || k % every === 0) ctx.fillText(String(k), p.X(k * fDrive), p.top - 2);
      ctx.textAlign = "left";
      ctx.fillText("k", p.left - 24, p.top - 2);
    }
    if (d) {
      const bw = d.binWidth, mags = d.mags;
      const n = Math.min(mags.length, Math.ceil(xr[1] / bw) + 2);
      p.line(n, (i) => i * bw, (i) => mags[i], TRACE, 1.1);
      this.app.stats.draws.spectrum++;
    } else {
      p.message("waiting for spectra…");
    }
    if (this.showModes.checked && f1 > 0) {
      const fs = modeFrequencies(f1, modes);
      fs.forEach((f, i) => {
        const label = i === 0 ? `f1 ${si(f, "Hz", 4)}` : `f${i + 1} ${si(f, "Hz", 4)}`;
        p.vline(f, MODE_COLOR, [5, 4], label, p.top + 12 + (i % 2) * 15);
      });
    }
    if (p.hover && d && p.hover.x >= p.left && p.hover.x <= p.right) this.drawHover(d);
    p.end();
    this.foot.textContent = d
      ? `Δf = ${si(d.binWidth, "Hz", 4)} · ${d.mags.length} bins · t = ${d.t.toFixed(3)} s` +
        (this.pow ? ` · power average of ~${this.powN} spectra` : "") +
        (f1 > 0 ? ` · ${modes} modes from f1 = ${si(f1, "Hz", 4)}` : "") +
        (fDrive > 0 ? ` · drive ${si(fDrive, "Hz", 4)}` : "") +
        (fDrive2 > 0 ? ` · drive2 ${si(fDrive2, "Hz", 4)}` : "")
      : "";
  }

  /** Crosshair readout: the strongest bin within ±4 px of the cursor. */
  drawHover(d) {
    const p = this.plot;
    const bw = d.binWidth;
    const i0 = Math.max(0, Math.floor(p.invX(p.hover.x - 4) / bw));
    const i1 = Math.min(d.mags.length - 1, Math.ceil(p.invX(p.hover.x + 4) / bw));
    let best = i0;
    for (let i = i0; i <= i1; i++) if (d.mags[i] > d.mags[best]) best = i;
    const f = best * bw, a = d.mags[best];
    p.vline(f, "rgba(0,0,0,0.35)");
    const fd = this.app.params.fDrive;
    const k = fd > 0 ? ` · k = ${(f / fd).toFixed(2)}` : "";
    p.label(p.right - 6, p.top + 4, `${si(f, "Hz", 5)}${k} · ${si(a, "m", 3)}`, "#1d2129", "right", "top", true);
  }
}
