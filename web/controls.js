// Controls for the main nodes, built from the daemon's `list` (unit, range, description).
// Numbers are typed with SI prefixes in the node's unit ("116.1 GPa", "20 nm"); Enter (or
// leaving the field) sends `set`. A refused value shows the server's message under the
// control, its numbers in the node's unit with SI prefixes, and the control returns to the
// server's value. The range beside each field shows which ends are allowed ("0 < E ≤ 10 TPa").

import { inUserUnits, parseSI, rangeText, siShort } from "./units.js";

const GROUPS = [
  { legend: "Sample and surface", items: [
    { path: "/sample/youngs_modulus", label: "Young's modulus E", sym: "E" },
    { path: "/surface/distance", label: "Surface distance A_set", sym: "d" },
  ] },
  { legend: "Drive", items: [
    { path: "/drive/free_amplitude", label: "Free amplitude A₀", sym: "A₀" },
    { path: "/drive/frequency", label: "Drive frequency", sym: "f" },
  ] },
  // bimodal AFM: a second base excitation; a demodulator reads it with oscillator "drive2"
  { legend: "Second drive (bimodal)", items: [
    { path: "/drive2/enable", label: "Second excitation" },
    { path: "/drive2/free_amplitude", label: "Free amplitude A₂", sym: "A₂" },
    { path: "/drive2/frequency", label: "Frequency f₂", sym: "f₂" },
  ] },
  { legend: "Synthesis", items: [
    { path: "/noise/enable", label: "Noise" },
    { path: "/synth/engine", label: "Tip-force engine", options: ["paper", "coupled"] },
  ] },
  // shown in the force panel's neighbour (#inversion-controls) rather than in #controls
  { legend: "FT-AFM inversion", target: "inversion-controls", items: [
    { path: "/inversion/enable", label: "Force reconstruction" },
    { path: "/inversion/method", label: "Method", options: ["full", "two_harmonic"] },
    { path: "/inversion/harmonic_a", label: "Harmonic a" },
    { path: "/inversion/harmonic_b", label: "Harmonic b" },
    { path: "/inversion/averaging", label: "Averaging (frames per estimate)" },
  ] },
  // shown in the scan panel (#scan-controls); Start/Stop is the panel's button (image.js)
  { legend: "Raster scan", target: "scan-controls", items: [
    { path: "/scan/pixels", label: "Pixels per line (and lines)" },
    { path: "/scan/line_rate", label: "Line rate" },
    { path: "/scan/size", label: "Scan size" },
    { path: "/scan/x", label: "Centre x" },
    { path: "/scan/y", label: "Centre y" },
  ] },
  { legend: "Amplitude feedback", target: "scan-controls", items: [
    { path: "/feedback/enable", label: "Feedback" },
    { path: "/feedback/setpoint", label: "Setpoint (0: automatic)" },
    { path: "/feedback/proportional", label: "Proportional gain" },
    { path: "/feedback/integral", label: "Integral gain" },
  ] },
];
const DEMOD_ITEMS = [
  { key: "enable", label: "Enabled" },
  { key: "harmonic", label: "Harmonic k" },
  { key: "oscillator", label: "Oscillator", options: ["drive", "drive2"] },
  { key: "order", label: "Filter order" },
  { key: "timeconstant", label: "Time constant" },
];
const POLL_MS = 2000;

function esc(s) {
  return String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
}

/** One control bound to one node path; `panel` gives `app` and `refresh(control)` (a re-read
 * of its node after a refusal). */
export class Control {
  constructor(panel, spec, path) {
    this.panel = panel;
    this.spec = spec;
    this.path = path;
    this.node = null;
    this.editing = false;
    this.pending = false;
    this.el = document.createElement("div");
    this.el.className = "ctl";
    this.el.innerHTML = `<div class="name"><span></span><code></code></div><div class="row"></div><div class="error" role="alert"></div>`;
    this.nameEl = this.el.querySelector(".name span");
    this.pathEl = this.el.querySelector(".name code");
    this.row = this.el.querySelector(".row");
    this.errEl = this.el.querySelector(".error");
    this.nameEl.textContent = spec.label;
    this.input = null;
  }

  /** Applies a node from `list` (value, unit, range, description); builds the input on first use. */
  setNode(node) {
    this.node = node;
    this.pathEl.textContent = this.path;
    this.el.title = node.description || "";
    this.el.dataset.path = this.path;
    if (!this.input) this.build();
    this.input.dataset.path = this.path;
    this.errEl.dataset.for = this.path;
    if (this.rangeEl) this.rangeEl.textContent = this.rangeEl.title = rangeText(node, this.spec.sym);
    if (!this.editing && !this.pending) this.show();
  }

  kind() {
    const v = this.node.value;
    return typeof v === "boolean" ? "bool" : typeof v === "string" ? "text" : "number";
  }

  build() {
    const kind = this.kind();
    this.el.classList.toggle("flag", kind === "bool");
    if (kind === "bool") {
      const label = document.createElement("label");
      this.input = document.createElement("input");
      this.input.type = "checkbox";
      label.append(this.input, document.createTextNode(" on"));
      this.row.append(label);
      this.input.addEventListener("change", () => this.commit(this.input.checked));
    } else if (kind === "text") {
      this.input = document.createElement("select");
      this.row.append(this.input);
      this.input.addEventListener("change", () => this.commit(this.input.value));
    } else {
      this.input = document.createElement("input");
      this.input.type = "text";
      this.input.spellcheck = false;
      this.input.autocomplete = "off";
      this.rangeEl = document.createElement("span");
      this.rangeEl.className = "range";
      this.row.append(this.input, this.rangeEl);
      this.input.addEventListener("input", () => { this.editing = true; });
      this.input.addEventListener("keydown", (e) => {
        if (e.key === "Enter") { e.preventDefault(); this.commitText(); }
        if (e.key === "Escape") { this.editing = false; this.show(); this.input.select(); }
      });
      this.input.addEventListener("change", () => this.commitText());
      this.input.addEventListener("blur", () => { if (!this.pending) { this.editing = false; this.show(); } });
    }
  }

  /** Shows the server's value. */
  show() {
    const n = this.node;
    if (!n || !this.input) return;
    const kind = this.kind();
    if (kind === "bool") this.input.checked = !!n.value;
    else if (kind === "text") {
      const opts = [...new Set([n.value, ...(n.allowed || this.spec.options || [])])];
      if (this.input.options.length !== opts.length || this.input.dataset.opts !== opts.join("|")) {
        this.input.innerHTML = opts.map((o) => `<option value="${esc(o)}">${esc(o)}</option>`).join("");
        this.input.dataset.opts = opts.join("|");
      }
      this.input.value = n.value;
    } else {
      this.input.value = siShort(n.value, n.unit);
    }
  }

  commitText() {
    if (this.pending || !this.editing) return;
    let value;
    try {
      value = parseSI(this.input.value, this.node.unit);
    } catch (e) {
      this.reject(e.message);
      return;
    }
    this.commit(value);
  }

  async commit(value) {
    this.pending = true;
    this.el.classList.add("pending");
    const conn = this.panel.app.conn;
    try {
      let reply;
      for (let attempt = 0; ; attempt++) {
        try {
          reply = await conn.request("set", { path: this.path, value });
          break;
        } catch (e) {
          // "busy": the previous change has not reached the signal chain yet; try again shortly
          if (e.code === "busy" && attempt < 20) await new Promise((r) => setTimeout(r, 50));
          else throw e;
        }
      }
      this.node.value = reply.value;
      this.panel.app.nodes.set(this.path, this.node);
      this.errEl.textContent = "";
      this.el.classList.remove("rejected");
      this.panel.app.onSet(this.path, reply.value, reply.t ?? null);
      this.panel.app.stats.sets++;
    } catch (e) {
      this.reject(inUserUnits(e.message, this.node.unit));
      this.panel.refresh(this);
    } finally {
      this.pending = false;
      this.editing = false;
      this.el.classList.remove("pending");
      this.show();
    }
  }

  reject(message) {
    this.errEl.textContent = message;
    this.el.classList.add("rejected");
    this.editing = false;
    this.show();
    this.panel.app.stats.rejects++;
  }
}

export class ControlsPanel {
  constructor(app) {
    this.app = app;
    this.root = document.getElementById("controls");
    this.controls = [];
    this.demodControls = [];
    this.demod = 0;
    this.built = false;
    setInterval(() => this.poll(), POLL_MS);
  }

  /** Builds (first time) or refreshes the controls from a full `list`. */
  setNodes(nodes) {
    if (!this.built) this.build();
    for (const c of [...this.controls, ...this.demodControls]) {
      const n = nodes.get(c.path);
      c.errEl.textContent = ""; // messages of an earlier connection no longer apply
      c.el.classList.remove("rejected");
      if (n) c.setNode({ ...n });
    }
    this.updateDemodOptions();
  }

  build() {
    this.built = true;
    this.root.innerHTML = "";
    const cleared = new Set();
    for (const g of GROUPS) {
      const root = (g.target && document.getElementById(g.target)) || this.root;
      if (root !== this.root && !cleared.has(root)) { cleared.add(root); root.innerHTML = ""; }
      const fs = document.createElement("fieldset");
      fs.innerHTML = `<legend>${esc(g.legend)}</legend>`;
      for (const item of g.items) {
        const c = new Control(this, item, item.path);
        this.controls.push(c);
        fs.append(c.el);
      }
      root.append(fs);
    }
    const fs = document.createElement("fieldset");
    fs.innerHTML = `<legend>Demodulator</legend><div class="ctl"><div class="name"><span>Demodulator</span><code>/demods/N</code></div>` +
      `<div class="row"><select id="demod-select" title="Which demodulator the controls below change"></select></div></div>`;
    this.select = fs.querySelector("#demod-select");
    this.select.addEventListener("change", () => this.chooseDemod(Number(this.select.value)));
    for (const item of DEMOD_ITEMS) {
      const c = new Control(this, item, `/demods/${this.demod}/${item.key}`);
      this.demodControls.push(c);
      fs.append(c.el);
    }
    this.root.append(fs);
  }

  updateDemodOptions() {
    if (!this.select) return;
    const parts = [];
    for (let i = 0; i < 32; i++) {
      const h = this.app.nodes.get(`/demods/${i}/harmonic`)?.value;
      const on = this.app.nodes.get(`/demods/${i}/enable`)?.value;
      const osc = this.app.nodes.get(`/demods/${i}/oscillator`)?.value;
      const of = osc && osc !== "drive" ? ` of ${esc(osc)}` : "";
      parts.push(`<option value="${i}">${i} — harmonic ${h ?? "?"}${of}${on === false ? " (off)" : ""}</option>`);
    }
    const html = parts.join("");
    if (html !== this.optionsHtml) {
      this.optionsHtml = html;
      this.select.innerHTML = html;
    }
    this.select.value = String(this.demod);
  }

  chooseDemod(i) {
    this.demod = i;
    for (const c of this.demodControls) {
      c.path = `/demods/${i}/${c.spec.key}`;
      c.errEl.textContent = "";
      c.el.classList.remove("rejected");
      c.editing = false;
      const n = this.app.nodes.get(c.path);
      if (n) c.setNode({ ...n });
      this.refresh(c);
    }
  }

  /** Re-reads one control's node (value and current range). */
  async refresh(c) {
    if (!this.app.conn.open) return;
    try {
      const r = await this.app.conn.request("list", { path: c.path });
      const n = r.nodes.find((x) => x.path === c.path);
      if (n) {
        this.app.nodes.set(n.path, n);
        if (!c.pending) c.setNode({ ...n });
      }
    } catch (e) {
      if (e.code !== "disconnected") console.warn("ftafm: list", c.path, e.message);
    }
  }

  /** Keeps the controls true when something else (a script) changes the instrument. */
  poll() {
    if (!this.built || !this.app.conn.open || document.hidden) return;
    for (const c of [...this.controls, ...this.demodControls]) if (!c.editing && !c.pending && document.activeElement !== c.input) this.refresh(c);
    this.updateDemodOptions();
  }
}
