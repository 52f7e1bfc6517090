// The sweeper (`/sweeper/*` and the `sweep` stream, docs/sweeper.md): set up a tune or an
// approach curve, run or abort it, watch its progress, see the amplitude and phase of
// harmonic 1 (and one more harmonic) against the swept node, the way up and the way back in
// two colours, and export the points as CSV. The daemon does the sweeping; this panel only
// sets nodes and draws what the stream brings.

import { Plot, COLORS } from "./plot.js";
import { parseSI, refusalInUserUnits, si, siShort } from "./units.js";

const UNITS = {
  "/drive/frequency": "Hz",
  "/surface/distance": "m",
  "/drive/free_amplitude": "m",
  "/sample/youngs_modulus": "Pa",
};
const LEG_COLORS = { up: COLORS[0], down: COLORS[1] };

export class SweeperPanel {
  constructor(app) {
    this.app = app;
    this.points = []; // point messages of the sweep shown
    this.final = null;
    this.sweepId = null;
    this.dirty = true;
    const $ = (id) => document.getElementById(id);
    this.el = {
      parameter: $("sw-parameter"),
      start: $("sw-start"),
      stop: $("sw-stop"),
      points: $("sw-points"),
      direction: $("sw-direction"),
      averaging: $("sw-averaging"),
      harmonic: $("sw-harmonic"),
      run: $("sw-run"),
      abort: $("sw-abort"),
      csv: $("sw-csv"),
      progress: $("sw-progress"),
      result: $("sw-result"),
    };
    const redraw = () => { this.dirty = true; };
    this.rPlot = new Plot($("sw-r"), { x: { label: "value" }, y: { label: "amplitude", unit: "m" }, margin: { l: 62 } }, redraw);
    this.pPlot = new Plot($("sw-phase"), { x: { label: "value" }, y: { label: "H1 phase to drive", unit: "°" }, margin: { l: 62 } }, redraw);
    this.el.run.addEventListener("click", () => this.run());
    this.el.abort.addEventListener("click", () => this.abort());
    this.el.csv.addEventListener("click", () => this.exportCsv());
    this.el.harmonic.addEventListener("change", redraw);
    this.el.parameter.addEventListener("change", () => this.suggestRange());
  }

  /** After (re)connecting: the stream is subscribed with the others; read the set-up. */
  async onOpen() {
    const conn = this.app.conn;
    try {
      for (const key of ["parameter", "start", "stop", "points", "direction", "averaging"]) {
        const r = await conn.request("get", { path: `/sweeper/${key}` });
        this.el[key].value = r.value;
      }
      // The ends in the swept node's unit, as the user types them ("99 kHz").
      for (const key of ["start", "stop"]) this.el[key].value = siShort(Number(this.el[key].value), this.unit());
      const enabled = (await conn.request("get", { path: "/sweeper/enable" })).value;
      this.setRunning(enabled);
    } catch (e) {
      if (e.code !== "disconnected") console.warn("ftafm: sweeper set-up:", e.message);
    }
  }

  /** The unit of the node `path` (default: the swept one), from `list`. */
  unit(path = this.el.parameter.value) {
    return this.app.nodes.get(path)?.unit ?? UNITS[path] ?? "";
  }

  /** Around the node's present value: f1 ± 1 % for a tune, 40 → 8 nm for an approach. */
  suggestRange() {
    const p = this.el.parameter.value;
    const v = this.app.nodes.get(p)?.value;
    const show = (x) => siShort(x, this.unit(), 6);
    if (p === "/drive/frequency" && v) {
      this.el.start.value = show(Math.round(v * 0.99));
      this.el.stop.value = show(Math.round(v * 1.01));
    } else if (p === "/surface/distance") {
      this.el.start.value = show(40e-9);
      this.el.stop.value = show(8e-9);
      this.el.direction.value = "both";
    } else if (v) {
      this.el.start.value = show(v * 0.5);
      this.el.stop.value = show(v * 1.5);
    }
  }

  /** A refusal in the user's units: the sweep's ends in the swept node's, others in their own. */
  refusal(message) {
    return refusalInUserUnits(message, (path) =>
      path === "/sweeper/start" || path === "/sweeper/stop" ? this.unit() : this.unit(path));
  }

  setRunning(running) {
    this.running = running;
    this.el.run.disabled = running;
    this.el.abort.disabled = !running;
  }

  async run() {
    const num = (el) => Number(el.value);
    this.el.result.textContent = "";
    this.el.result.classList.remove("error");
    let start, stop;
    try {
      // Typed in the swept node's unit, with or without a prefix ("99.5 kHz", "99500").
      start = parseSI(this.el.start.value, this.unit());
      stop = parseSI(this.el.stop.value, this.unit());
    } catch (e) {
      this.el.result.textContent = e.message;
      this.el.result.classList.add("error");
      return;
    }
    const values = {
      "/sweeper/parameter": this.el.parameter.value,
      "/sweeper/start": start,
      "/sweeper/stop": stop,
      "/sweeper/points": num(this.el.points),
      "/sweeper/direction": this.el.direction.value,
      "/sweeper/averaging": num(this.el.averaging),
      "/sweeper/enable": true,
    };
    try {
      // The first point may arrive before the reply: its new sweep id starts the display.
      const before = this.sweepId;
      await this.app.conn.request("set", { values });
      if (this.sweepId === before) {
        this.setRunning(true);
        this.el.progress.textContent = "starting…";
      }
    } catch (e) {
      this.el.result.textContent = this.refusal(e.message);
      this.el.result.classList.add("error");
      this.app.stats.rejects++;
    }
    this.dirty = true;
  }

  async abort() {
    try {
      await this.app.conn.request("set", { path: "/sweeper/enable", value: false });
    } catch (e) {
      this.el.result.textContent = this.refusal(e.message);
    }
  }

  onData(m) {
    if (m.sweep !== this.sweepId) {
      // A new sweep (perhaps started by a script): show it from its first point.
      this.sweepId = m.sweep;
      this.points = [];
      this.final = null;
      this.setRunning(!m.done);
    }
    if (m.done) {
      this.final = m;
      this.setRunning(false);
      this.el.progress.textContent = `${m.outcome}: ${m.measured} of ${m.points} points${m.restored ? ", node restored" : ""}`;
      this.el.result.textContent = this.summary(m);
      this.el.result.classList.toggle("error", m.outcome === "failed");
    } else {
      this.points.push(m);
      this.el.progress.textContent = `${m.parameter}: point ${m.point + 1} of ${m.points} (${Math.round(m.progress * 100)} %), ${m.leg}`;
    }
    this.dirty = true;
  }

  summary(m) {
    if (m.outcome === "failed") return `failed: ${m.reason}`;
    if (m.tune) {
      const t = m.tune;
      return `f0 = ${si(t.f0, "Hz", 7)}, Q = ${t.q.toFixed(1)}, phase at f0 ${(t.phase_to_drive_at_f0 * 180 / Math.PI).toFixed(1)}°${this.retracted(m)}`;
    }
    if (m.tune === null) return `the tune did not fit a resonance${this.retracted(m)}`;
    if (m.approach) {
      const a = m.approach;
      const at = (v) => (v == null ? "—" : si(v, "m", 3));
      const h = a.hysteresis ? `${(a.hysteresis.max * 100).toFixed(2)} % at ${at(a.hysteresis.at)}` : "—";
      // Each jump with the branches it joins: where attractive and repulsive orbits coexist,
      // which one the curve is on is the physics.
      const jumps = a.jumps.map((j) => `${j.leg} ${at(j.from)} → ${at(j.to)}${j.regime_before && j.regime_after ? ` (${j.regime_before} → ${j.regime_after})` : ""}`);
      return `contact at ${at(a.contact_up)} (up), ${at(a.contact_down)} (down); ${a.jumps.length} jump${a.jumps.length === 1 ? "" : "s"}${jumps.length ? ": " + jumps.join(", ") : ""}; hysteresis ${h}`;
    }
    return "";
  }

  /** What a tune did to the surface: it retracts the tip out of reach, as an auto-tune does. */
  retracted(m) {
    const r = m.retracted;
    if (!r) return "";
    const back = m.restored ? `, then back to ${siShort(r.from, "m", 4)}` : "";
    const where = `surface retracted from ${siShort(r.from, "m", 4)} to ${siShort(r.distance, "m", 4)} for the tune${back}`;
    return r.clear ? `; ${where} (the free lever's resonance)` : `; ${where}: not clear of the tip's swing, it may still touch`;
  }

  /** r and phase of harmonic `k` of the drive at a point (NaN where it was not measured). */
  at(p, k) {
    const d = p.demods.find((d) => d.harmonic === k && this.app.history.onDrive(d.index));
    return d && typeof d.r === "number" ? d.r : NaN;
  }

  draw() {
    if (!this.dirty) return;
    this.dirty = false;
    const unit = UNITS[this.points[0]?.parameter ?? this.el.parameter.value] ?? "";
    this.rPlot.opts.x = { label: this.points[0]?.parameter ?? "value", unit };
    this.pPlot.opts.x = this.rPlot.opts.x;
    if (!this.points.length) {
      this.rPlot.begin([0, 1], [0, 1]).message(this.running ? "sweeping…" : "set up a sweep and run it");
      this.pPlot.begin([0, 1], [-180, 0]).message("");
      return;
    }
    const k = Number(this.el.harmonic.value) || 0;
    const values = this.points.map((p) => p.value);
    const lo = Math.min(...values), hi = Math.max(...values);
    const series = (leg, f) => this.points.filter((p) => p.leg === leg).sort((a, b) => a.value - b.value).map((p) => [p.value, f(p)]);
    const rMax = Math.max(...this.points.map((p) => this.at(p, 1)).filter(isFinite), 1e-15);
    this.rPlot.begin([lo, hi === lo ? lo + 1 : hi], [0, rMax * 1.08]);
    this.rPlot.clip(() => {
      for (const leg of ["up", "down"]) {
        const s = series(leg, (p) => this.at(p, 1));
        this.rPlot.line(s.length, (i) => s[i][0], (i) => s[i][1], LEG_COLORS[leg], 1.6);
        if (k > 1) {
          const sk = series(leg, (p) => this.at(p, k) * (rMax / Math.max(...this.points.map((q) => this.at(q, k)).filter(isFinite), 1e-30)));
          this.rPlot.line(sk.length, (i) => sk[i][0], (i) => sk[i][1], LEG_COLORS[leg], 0.8);
        }
      }
    });
    this.rPlot.end();
    this.pPlot.begin([lo, hi === lo ? lo + 1 : hi], [-180, 0]);
    this.pPlot.clip(() => {
      for (const leg of ["up", "down"]) {
        const s = series(leg, (p) => (typeof p.h1_phase_to_drive === "number" ? p.h1_phase_to_drive * 180 / Math.PI : NaN));
        this.pPlot.line(s.length, (i) => s[i][0], (i) => s[i][1], LEG_COLORS[leg], 1.6);
      }
    });
    this.pPlot.hline(-90, "#9aa0aa", [4, 4]);
    this.pPlot.end();
    this.app.stats.draws.sweep = (this.app.stats.draws.sweep ?? 0) + 1;
  }

  /** The points as CSV: value, leg, the mean deflection and force estimates (empty where a
   * point has none), then r and phase of every demodulator measured. */
  csv() {
    const cols = [];
    for (const p of this.points) for (const d of p.demods) if (!cols.some((c) => c.index === d.index)) cols.push({ index: d.index, harmonic: d.harmonic });
    cols.sort((a, b) => a.index - b.index);
    const force = ["max_force_N", "max_force_sigma_N", "contact_time_ratio", "contact_time_ratio_sigma", "youngs_modulus_Pa", "youngs_modulus_sigma_Pa"];
    const forceKey = (h) => h.replace(/_(N|Pa)$/, "");
    const head = ["value", "leg", "h1_phase_to_drive_rad", "mean_deflection_m", ...force, ...cols.flatMap((c) => [`r_demod${c.index}_h${c.harmonic}_m`, `phase_demod${c.index}_h${c.harmonic}_rad`])];
    const rows = this.points.map((p) => {
      const cells = [p.value, p.leg, p.h1_phase_to_drive ?? "", p.mean_deflection ?? "", ...force.map((h) => p.force?.[forceKey(h)] ?? "")];
      for (const c of cols) {
        const d = p.demods.find((d) => d.index === c.index);
        cells.push(d?.r ?? "", d?.phase ?? "");
      }
      return cells.join(",");
    });
    return [`# ftafm sweep ${this.sweepId ?? ""} of ${this.points[0]?.parameter ?? ""}`, head.join(","), ...rows].join("\n") + "\n";
  }

  exportCsv() {
    const blob = new Blob([this.csv()], { type: "text/csv" });
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = `ftafm-sweep-${this.sweepId ?? "0"}.csv`;
    a.click();
    setTimeout(() => URL.revokeObjectURL(a.href), 1000);
  }
}
