// The live PID units /pids/0 … /pids/3 (docs/loops.md, "Live PID units"): a table of the
// four from the status stream's `pids` (2 Hz: each unit's settings in force and its latest
// update, stamped with the settings epoch it ran under and a running count), and controls
// for one unit at a time (chosen in the select, or by clicking its row), built as the other
// controls are (controls.js: SI units, ranges, the daemon's refusal shown under the field),
// and the chosen unit's error and output against simulated time, one point per status
// message (the latest update each carries), over the last TRACE points. A unit drives one
// of OUTPUTS: the surface distance, or the drive (its frequency: a unit on the phase of
// harmonic 1 is then a PLL, its lock and frequency shift Δf in the table; or its amplitude),
// or the same two of the second excitation (drive2_*: on the phase of harmonic 1 of
// oscillator "drive2", mode 2's PLL of bimodal AM-FM, its Δf₂ from /drive2/frequency); a
// unit reads harmonic k of its oscillator (drive, or drive2 through a low-pass of its input
// bandwidth); the outputs a loop holds away from their nodes (status's `pid_held`) are
// named in the foot.

import { Control } from "./controls.js";
import { Plot, StickyRange } from "./plot.js";
import { si } from "./units.js";

export const PID_COUNT = 4;
/** What a unit can drive (/pids/N/output), and the unit of each one's values. */
export const OUTPUTS = {
  surface_distance: "m", drive_frequency: "Hz", drive_amplitude: "m", drive2_frequency: "Hz", drive2_amplitude: "m",
};
const ITEMS = [
  { key: "enable", label: "Enabled" },
  { key: "input", label: "Input", options: ["r", "phase", "x", "y", "frequency_shift", "mean_deflection"] },
  { key: "harmonic", label: "Harmonic k" },
  { key: "oscillator", label: "Oscillator", options: ["drive", "drive2"] },
  { key: "input_bandwidth", label: "Input bandwidth (on drive2)" },
  { key: "output", label: "Output", options: Object.keys(OUTPUTS) },
  { key: "setpoint", label: "Set-point" },
  { key: "p", label: "Proportional gain P" },
  { key: "i", label: "Integral gain I" },
  { key: "d", label: "Derivative gain D" },
  { key: "d_bandwidth", label: "Derivative bandwidth" },
  { key: "output_min", label: "Output min" },
  { key: "output_max", label: "Output max" },
  { key: "rate", label: "Rate limit (0: none)" },
];
const POLL_MS = 2000;
/** Status messages' updates kept per unit for the strip chart (2 a second: 2 minutes). */
const TRACE = 240;

function esc(s) {
  return String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
}

/** The input's unit: rad for the phase, Hz for a PLL's frequency shift, else m (peak). */
const inputUnit = (input) => (input === "phase" ? "rad" : input === "frequency_shift" ? "Hz" : "m");

/** The output's unit: Hz for either drive frequency, else m. */
const outputUnit = (output) => OUTPUTS[output] ?? "m";

/** The unit a unit's node is in where `list` gives none (it depends on the input, or on the
 * output: m for the surface distance and either drive amplitude, Hz for either drive frequency):
 * values typed and shown with SI prefixes ("16.7 nm", "99.5 kHz"). */
function unitOf(node, nodes) {
  if (node.unit) return node.unit;
  const [, , n, key] = node.path.split("/");
  if (key === "setpoint") return inputUnit(nodes.get(`/pids/${n}/input`)?.value);
  const out = outputUnit(nodes.get(`/pids/${n}/output`)?.value);
  if (key === "output_min" || key === "output_max") return out;
  if (key === "rate") return `${out}/s`;
  return node.unit;
}

/** A PLL's lock as the table shows it ("–" for a unit that is no PLL, or before its first update). */
/** A PLL's lock, and its losses of lock since the daemon started where there were any. */
const lockText = (locked, losses) =>
  (locked === true ? "locked" : locked === false ? "unlocked" : "–") + (losses ? ` (${losses} lost)` : "");

export class PidsPanel {
  constructor(app) {
    this.app = app;
    this.table = document.getElementById("pids-table");
    this.root = document.getElementById("pid-controls");
    this.foot = document.getElementById("pids-foot");
    this.unit = 0;
    this.controls = [];
    this.built = false;
    this.pids = null; // the newest status message's `pids`
    this.held = []; // its `pid_held`: the outputs a loop holds away from their nodes
    this.shownUnits = ""; // the chosen unit's input and output its controls' units were set for
    this.t = null; // its simulated time (s)
    this.dirty = false;
    // Per unit, its latest updates as the status messages carried them, oldest first:
    // { t: the update's simulated time (s), route: its input and output, error, output },
    // a new point per new update.
    this.traces = Array.from({ length: PID_COUNT }, () => []);
    const redraw = () => { this.dirty = true; };
    this.ePlot = new Plot(document.getElementById("pids-error"), {
      x: { label: "simulated time before the latest update", unit: "s" },
      y: { label: "error", unit: "m" },
      margin: { l: 62 },
    }, redraw);
    this.oPlot = new Plot(document.getElementById("pids-output"), {
      x: { label: "simulated time before the latest update", unit: "s" },
      y: { label: "output", unit: "m" },
      margin: { l: 62 },
    }, redraw);
    this.eRange = new StickyRange();
    this.oRange = new StickyRange();
    this.table.addEventListener("click", (e) => {
      const row = e.target.closest("tr[data-unit]");
      if (row) this.choose(Number(row.dataset.unit));
    });
    setInterval(() => this.poll(), POLL_MS);
  }

  onData(m) {
    if (!Array.isArray(m.pids)) return;
    this.pids = m.pids;
    this.held = Array.isArray(m.pid_held) ? m.pid_held : [];
    this.t = m.t;
    const rate = m.sample_rate || this.app.hello?.sample_rate || 0;
    for (const u of m.pids) {
      const l = u.latest, trace = this.traces[u.index];
      if (!l || !trace || !(rate > 0)) continue;
      const t = l.sample / rate;
      if (trace.length && trace[trace.length - 1].t >= t) continue; // no update since
      // A unit moved to another output (or input, or oscillator) starts a new trace: no
      // metres beside hertz, no mode 2's phase beside mode 1's.
      const route = `${u.input}|${u.oscillator ?? "drive"}|${u.output}`;
      if (trace.length && trace[trace.length - 1].route !== route) {
        trace.length = 0;
        if (u.index === this.unit) { this.eRange.reset(); this.oRange.reset(); }
      }
      trace.push({ t, route, error: l.error, output: l.output });
      if (trace.length > TRACE) trace.shift();
    }
    this.dirty = true;
  }

  /** Builds (first time) or refreshes the controls from a full `list`. */
  setNodes(nodes) {
    if (!this.built) this.build();
    this.shownUnits = this.unitsKey();
    for (const c of this.controls) {
      c.errEl.textContent = "";
      c.el.classList.remove("rejected");
      const n = nodes.get(c.path);
      if (n) c.setNode({ ...n, unit: unitOf(n, nodes) });
    }
  }

  build() {
    this.built = true;
    this.root.innerHTML = "";
    const fs = document.createElement("fieldset");
    fs.innerHTML = `<legend>PID unit</legend><div class="ctl"><div class="name"><span>Unit</span><code>/pids/N</code></div>` +
      `<div class="row"><select id="pid-select" title="Which PID unit the controls below change">` +
      Array.from({ length: PID_COUNT }, (_, i) => `<option value="${i}">${i}</option>`).join("") +
      `</select></div></div>`;
    this.select = fs.querySelector("#pid-select");
    this.select.addEventListener("change", () => this.choose(Number(this.select.value)));
    for (const item of ITEMS) {
      const c = new Control(this, item, `/pids/${this.unit}/${item.key}`);
      this.controls.push(c);
      fs.append(c.el);
    }
    this.root.append(fs);
  }

  /** The chosen unit's input and output as the node list has them (what its controls' units follow). */
  unitsKey() {
    const get = (key) => this.app.nodes.get(`/pids/${this.unit}/${key}`)?.value;
    return `${get("input")}|${get("output")}`;
  }

  /** Re-applies the controls' units after the chosen unit's input or output changed (a set
   * from the panel or a script): the set-point follows the input, the limits the output. */
  reunit() {
    const key = this.unitsKey();
    if (!this.built || key === this.shownUnits) return;
    this.shownUnits = key;
    for (const c of this.controls) {
      const n = this.app.nodes.get(c.path);
      if (n && !n.unit && !c.editing && !c.pending) c.setNode({ ...n, unit: unitOf(n, this.app.nodes) });
    }
  }

  /** Shows unit `i`'s controls. */
  choose(i) {
    if (!this.built || i === this.unit) return;
    this.unit = i;
    this.shownUnits = this.unitsKey();
    this.eRange.reset();
    this.oRange.reset();
    this.select.value = String(i);
    for (const c of this.controls) {
      c.path = `/pids/${i}/${c.spec.key}`;
      c.errEl.textContent = "";
      c.el.classList.remove("rejected");
      c.editing = false;
      const n = this.app.nodes.get(c.path);
      if (n) c.setNode({ ...n, unit: unitOf(n, this.app.nodes) });
      this.refresh(c);
    }
    this.dirty = true;
  }

  /** Re-reads one control's node (value and current range); a Control calls it after a refusal. */
  async refresh(c) {
    if (!this.app.conn.open) return;
    try {
      const r = await this.app.conn.request("list", { path: c.path });
      const n = r.nodes.find((x) => x.path === c.path);
      if (n) {
        this.app.nodes.set(n.path, n);
        if (!c.pending) c.setNode({ ...n, unit: unitOf(n, this.app.nodes) });
      }
    } catch (e) {
      if (e.code !== "disconnected") console.warn("ftafm: list", c.path, e.message);
    }
  }

  /** Keeps the controls true when something else (a script) changes a unit. */
  poll() {
    if (!this.built || !this.app.conn.open || document.hidden) return;
    for (const c of this.controls) if (!c.editing && !c.pending && document.activeElement !== c.input) this.refresh(c);
  }

  draw() {
    if (!this.dirty) return;
    this.dirty = false;
    const pids = this.pids;
    if (!pids) return;
    this.reunit();
    const head = `<tr><th>N</th><th>on</th><th>input → output</th><th>set-point</th><th>measured</th><th>error</th><th>output</th><th>limited</th><th title="a PLL (phase → drive_frequency or drive2_frequency): locked after 16 updates in a row within 0.1 rad and not limited, unlocked at the first that is not; its losses of lock since the daemon started, each counted however brief">lock</th><th title="a unit on an excitation's frequency: its output less /drive/frequency (drive2_frequency: less /drive2/frequency, Δf₂)">Δf</th><th>epoch</th><th>updates</th></tr>`;
    const keys = ["index", "enable", "route", "setpoint", "measurement", "error", "output", "limited", "locked", "frequency_shift", "epoch", "updates"];
    const rows = pids.map((u) => {
      const l = u.latest;
      const unit = inputUnit(u.input);
      const out = outputUnit(u.output);
      const cells = [
        u.index,
        u.enable ? "on" : "off",
        // "phase H1 → drive_frequency"; on the second excitation "phase H1 of drive2 → …".
        `${esc(u.input)}${u.input === "mean_deflection" ? "" : ` H${u.harmonic}`}${u.oscillator && u.oscillator !== "drive" ? ` of ${esc(u.oscillator)}` : ""} → ${esc(u.output)}`,
        si(u.setpoint, unit),
        l ? si(l.measurement, unit) : "–",
        l ? si(l.error, unit) : "–",
        // A frequency to eight digits (99.999678 kHz: a millihertz), a distance to four.
        l ? si(l.output, out, out === "Hz" ? 8 : 4) : "–",
        l ? (l.limited ? "limited" : "no") : "–",
        lockText(u.locked, u.lock_losses),
        u.frequency_shift == null ? "–" : si(u.frequency_shift, "Hz", 6), // six digits: a kHz shift to 10 mHz
        l ? l.epoch : "–",
        l ? l.updates : "–",
      ];
      const warn = { limited: l?.limited, locked: u.locked === false };
      const cls = [u.index === this.unit ? "chosen" : "", u.enable ? "on" : "", l?.limited ? "limited" : ""].filter(Boolean).join(" ");
      return `<tr data-unit="${u.index}" class="${cls}" title="click to change /pids/${u.index}">` +
        cells.map((c, k) => `<td data-key="${keys[k]}"${warn[keys[k]] ? ' class="warn"' : ""}>${c}</td>`).join("") + "</tr>";
    });
    this.table.innerHTML = head + rows.join("");
    const on = pids.filter((u) => u.enable).length;
    const held = this.held.length
      ? ` · <span id="pids-held" title="outputs a loop holds away from their nodes until the node is set again">held by a loop: ${this.held.map(esc).join(", ")}</span>`
      : "";
    this.foot.innerHTML = `${on} of ${pids.length} running${held} · status at t = ${this.t == null ? "–" : this.t.toFixed(2) + " s"}`;
    const unit = pids[this.unit];
    const y = inputUnit(unit?.input);
    this.ePlot.opts.y.unit = y;
    this.oPlot.opts.y.unit = outputUnit(unit?.output);
    this.drawTrace(this.ePlot, this.eRange, "error", "#0b62a4", `/pids/${this.unit} error (${y})`);
    this.drawTrace(this.oPlot, this.oRange, "output", "#d55e00", `/pids/${this.unit} output`);
    this.app.stats.draws.pids++;
  }

  /** The chosen unit's `key` over its trace, x the time before its latest update (s). */
  drawTrace(p, range, key, color, title) {
    const trace = this.traces[this.unit];
    const n = trace.length;
    if (n) {
      let lo = Infinity, hi = -Infinity;
      for (const q of trace) if (isFinite(q[key])) { lo = Math.min(lo, q[key]); hi = Math.max(hi, q[key]); }
      const pad = hi > lo ? 0.08 * (hi - lo) : Math.abs(hi) * 0.01 || 1e-12;
      if (hi >= lo) range.update(lo - pad, hi + pad);
    }
    const tEnd = n ? trace[n - 1].t : 0;
    const span = n > 1 ? Math.max(tEnd - trace[0].t, 1e-3) : 1;
    p.begin([-span, 0], range.r ?? [-1, 1]);
    if (n) {
      if (key === "error") p.hline(0, "#9aa0a9");
      p.line(n, (j) => trace[j].t - tEnd, (j) => trace[j][key], color, 1.6);
      p.label(p.left + 6, p.top + 4, title, "#4a4f57");
    } else {
      p.message(`/pids/${this.unit} has made no update yet`);
    }
    p.end();
  }

  /** For tests and the console: the units as the last status message gave them. */
  values() {
    return { unit: this.unit, t: this.t, pids: this.pids, held: this.held, trace: this.traces[this.unit].length };
  }
}
