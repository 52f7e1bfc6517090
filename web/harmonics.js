// Harmonic amplitudes R (log scale) and phases against time for the chosen demodulators,
// with a readout table of 0.2 s means. Data accumulate in the history at the demodulators'
// rate (1 kHz); the plots redraw at most ~30 times a second.

import { COLORS, Plot, decadeRange } from "./plot.js";
import { si } from "./units.js";
import { DEMODS } from "./history.js";
import { Strip } from "./strip.js";

const DEFAULT_HARMONICS = [1, 6, 17, 18];
// ~30 fps: every second frame of a 60 Hz display (a little under 33 ms, so frame-time jitter
// does not push the draw to every third frame).
const MIN_FRAME_MS = 26;
const READOUT_MS = 200;

function esc(s) {
  return String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
}

export class HarmonicsPanel {
  constructor(app) {
    this.app = app;
    this.hist = app.history;
    this.selected = new Map(); // demod index → colour
    this.strips = new Map(); // demod index → { r, p }: its lines' bins (strip.js)
    this.defaulted = false;
    this.drawn = -1;
    this.lastDraw = 0;
    this.lastReadout = 0;
    this.chipKey = "";
    this.dirty = true;
    const redraw = () => { this.dirty = true; };
    this.rPlot = new Plot(document.getElementById("harm-r"), {
      x: { label: "time before now", unit: "s" },
      y: { label: "R", unit: "m", log: true },
      margin: { b: 30, l: 70 },
    }, redraw);
    this.pPlot = new Plot(document.getElementById("harm-phase"), {
      x: { unit: "s", title: false },
      y: { label: "phase", unit: "°", ticks: [-180, -90, 0, 90, 180] },
      margin: { b: 20, l: 70 },
    }, redraw);
    this.windowSel = document.getElementById("harm-window");
    this.windowSel.addEventListener("change", redraw);
    this.chips = document.getElementById("harm-chips");
    this.tbody = document.querySelector("#harm-table tbody");
    this.chips.addEventListener("click", (e) => {
      const b = e.target.closest(".chip");
      if (!b) return;
      this.toggle(Number(b.dataset.index));
    });
  }

  toggle(i) {
    if (this.selected.has(i)) this.selected.delete(i);
    else {
      const used = new Set(this.selected.values());
      this.selected.set(i, COLORS.find((c) => !used.has(c)) ?? COLORS[i % COLORS.length]);
    }
    this.chipKey = "";
    this.dirty = true;
    this.lastReadout = 0;
  }

  /** Chips for every demodulator (its harmonic as the label, "f₂×k" for a harmonic of the
   * second drive); rebuilt when harmonics or oscillators change. */
  updateChips() {
    const h = this.hist.harmonic;
    const osc = this.hist.oscillator;
    const key = Array.from(h).join(",") + "|" + osc.join(",") + "|" + Array.from(this.selected.entries()).join(";");
    if (key === this.chipKey) return;
    this.chipKey = key;
    const parts = [];
    for (let i = 0; i < DEMODS; i++) {
      const on = this.selected.has(i);
      const style = on ? ` style="background:${this.selected.get(i)}"` : "";
      const drive = this.hist.onDrive(i);
      const label = h[i] < 0 ? "–" : drive ? String(h[i]) : `f₂×${h[i]}`;
      const cls = `chip${on ? " on" : ""}${h[i] < 0 ? " off" : ""}${drive ? "" : " drive2"}`;
      const title = h[i] < 0 ? `demodulator ${i} (disabled)`
        : drive ? `demodulator ${i}, harmonic ${h[i]}`
        : `demodulator ${i}, harmonic ${h[i]} of drive2 (/drive2/frequency)`;
      parts.push(`<button type="button" class="${cls}" data-index="${i}" data-oscillator="${esc(osc[i])}" title="${esc(title)}"${style}>${label}</button>`);
    }
    this.chips.innerHTML = parts.join("");
  }

  draw(now) {
    const hist = this.hist;
    if (!this.defaulted && hist.len > 0) {
      this.defaulted = true;
      for (const k of DEFAULT_HARMONICS) {
        const i = hist.indexOf(k);
        if (i >= 0) this.toggle(i);
      }
    }
    if (now - this.lastReadout >= READOUT_MS) {
      this.lastReadout = now;
      this.updateChips();
      this.updateTable();
    }
    if (!this.dirty && hist.version === this.drawn) return;
    if (now - this.lastDraw < MIN_FRAME_MS) return;
    this.lastDraw = now;
    this.drawn = hist.version;
    this.dirty = false;
    this.app.stats.draws.harmonics++;

    const W = Number(this.windowSel.value);
    const tNow = hist.tNow;
    const t0 = tNow - W;
    // Bins a pixel wide (the two plots share their width), kept per channel between frames.
    const dt = W / Math.max(1, this.rPlot.right - this.rPlot.left);
    const positive = (v) => v > 0;
    const finite = (v) => v === v;
    let lo = Infinity, hi = 0;
    for (const i of this.selected.keys()) {
      let s = this.strips.get(i);
      if (!s) this.strips.set(i, (s = { r: new Strip(), p: new Strip() }));
      if (!hist.len) continue;
      s.r.sync(hist, i, hist.r[i], dt, W, positive);
      s.p.sync(hist, i, hist.p[i], dt, W, finite);
      const range = s.r.range(t0);
      if (range) { lo = Math.min(lo, range[0]); hi = Math.max(hi, range[1]); }
    }
    for (const i of this.strips.keys()) if (!this.selected.has(i)) this.strips.delete(i);
    const yr = hi > 0 ? decadeRange(lo, hi, 1, 6) : [1e-12, 1e-7];
    this.rPlot.begin([-W, 0], yr);
    this.pPlot.begin([-W, 0], [-180, 180]);
    const DEG = 180 / Math.PI;
    for (const [i, color] of this.selected) {
      const s = this.strips.get(i);
      if (!hist.len || !s) continue;
      s.r.draw(this.rPlot, tNow, t0, color);
      s.p.draw(this.pPlot, tNow, t0, color, DEG);
    }
    if (!hist.len) this.rPlot.message("waiting for demodulator data…");
    else if (!this.selected.size) this.rPlot.message("choose demodulators above");
    this.rPlot.end();
    this.pPlot.end();
  }

  updateTable() {
    // harmonics of the drive first, then those of the second drive
    const rows = [...this.selected.entries()]
      .map(([i, color]) => ({ i, color, m: this.hist.mean(i, 0.2), k: this.hist.harmonic[i], osc: this.hist.oscillator[i] }))
      .sort((a, b) => (a.osc === "drive" ? 0 : 1) - (b.osc === "drive" ? 0 : 1) || a.k - b.k);
    const html = rows.map(({ i, color, m, k, osc }) => {
      const r = m ? m.r : NaN;
      const ph = m ? (m.phase * 180) / Math.PI : NaN;
      const of = osc === "drive" ? "" : ` of ${esc(osc)}`;
      return `<tr data-index="${i}" data-harmonic="${k}" data-oscillator="${esc(osc)}"><td><span class="swatch" style="background:${color}"></span></td>` +
        `<td>${i}</td><td>${k >= 0 ? k + of : "off"}</td>` +
        `<td class="r" data-value="${isFinite(r) ? r : ""}">${si(r, "m", 4)}</td>` +
        `<td class="phase" data-value="${isFinite(ph) ? ph : ""}">${isFinite(ph) ? ph.toFixed(2).replace("-", "−") + "°" : "–"}</td></tr>`;
    });
    this.tbody.innerHTML = html.join("");
  }
}
