// Plain-canvas plots: axes with SI-prefixed ticks (linear or log), decimated lines (at most
// four points per pixel column, so a 16k-bin spectrum or 30k-point history draws as fast as
// a few hundred points and looks the same), bars and markers. No library.

import { niceTicks, prefixExponent, prefixSymbol, prefixable } from "./units.js";

export const COLORS = ["#0b62a4", "#d55e00", "#009e73", "#b0459b", "#e69f00", "#56b4e9", "#5d5d5d", "#8c564b"];
const FONT = "11px system-ui, -apple-system, 'Segoe UI', Roboto, sans-serif";
const AXIS = "#4a4f57";
const GRID = "#e7e9ee";
const MINOR = "#f2f3f6";

/** One canvas with a plot area. Resizes its backing store to the element's CSS size × DPR. */
export class Plot {
  /**
   * opts.x / opts.y: { label, unit, log } ; opts.margin: { l, r, t, b } in CSS px.
   * onResize: called after the canvas changed size (redraw then).
   */
  constructor(canvas, opts = {}, onResize = null) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d", { alpha: false });
    this.opts = opts;
    this.margin = { l: 62, r: 14, t: 12, b: 34, ...(opts.margin || {}) };
    this.w = 0;
    this.h = 0;
    this.hover = null; // {x, y} in CSS px while the mouse is over the canvas
    this.onResize = onResize;
    this.resize();
    new ResizeObserver(() => {
      if (this.resize() && this.onResize) this.onResize();
    }).observe(canvas);
    if (opts.hover) {
      canvas.addEventListener("mousemove", (e) => {
        const r = canvas.getBoundingClientRect();
        this.hover = { x: e.clientX - r.left, y: e.clientY - r.top };
        if (this.onResize) this.onResize();
      });
      canvas.addEventListener("mouseleave", () => {
        this.hover = null;
        if (this.onResize) this.onResize();
      });
    }
  }

  /** Matches the backing store to the displayed size; true if it changed. */
  resize() {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(60, Math.round(this.canvas.clientWidth));
    const h = Math.max(40, Math.round(this.canvas.clientHeight));
    if (w === this.w && h === this.h && dpr === this.dpr) return false;
    this.w = w;
    this.h = h;
    this.dpr = dpr;
    this.canvas.width = Math.round(w * dpr);
    this.canvas.height = Math.round(h * dpr);
    return true;
  }

  get left() { return this.margin.l; }
  get right() { return this.w - this.margin.r; }
  get top() { return this.margin.t; }
  get bottom() { return this.h - this.margin.b; }

  /** Starts a frame: clears, sets the ranges, draws grid and axes. */
  begin(xRange, yRange) {
    const { ctx } = this;
    ctx.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    ctx.fillStyle = "#ffffff";
    ctx.fillRect(0, 0, this.w, this.h);
    this.xr = xRange;
    this.yr = yRange;
    const xl = !!this.opts.x?.log, yl = !!this.opts.y?.log;
    const map = (log, lo, hi, a, b) => {
      if (log) {
        const l0 = Math.log10(lo), k = (b - a) / (Math.log10(hi) - l0);
        return (v) => (v > 0 ? a + (Math.log10(v) - l0) * k : NaN);
      }
      const k = (b - a) / (hi - lo || 1);
      return (v) => a + (v - lo) * k;
    };
    this.X = map(xl, xRange[0], xRange[1], this.left, this.right);
    this.Y = map(yl, yRange[0], yRange[1], this.bottom, this.top);
    this.axis("x");
    this.axis("y");
    return this;
  }

  /** Data x of a pixel column (linear axes). */
  invX(px) {
    const [lo, hi] = this.xr;
    return lo + ((px - this.left) / (this.right - this.left)) * (hi - lo);
  }

  axis(which) {
    const { ctx } = this;
    const o = this.opts[which] || {};
    const [lo, hi] = which === "x" ? this.xr : this.yr;
    const isX = which === "x";
    const len = isX ? this.right - this.left : this.bottom - this.top;
    const P = isX ? this.X : this.Y;
    ctx.font = FONT;
    ctx.lineWidth = 1;
    let ticks = [], labels = [], minor = [], title = o.label || "";
    if (o.log) {
      const d0 = Math.floor(Math.log10(lo) + 1e-9), d1 = Math.ceil(Math.log10(hi) - 1e-9);
      const decades = Math.max(1, d1 - d0);
      const every = Math.max(1, Math.ceil(decades / Math.max(1, Math.floor(len / (isX ? 60 : 22)))));
      for (let d = d0; d <= d1; d++) {
        const v = 10 ** d;
        if (v >= lo * 0.999 && v <= hi * 1.001 && (d - d0) % every === 0) {
          ticks.push(v);
          labels.push(decadeLabel(v, o.unit));
        }
        if (decades <= 6) for (let m = 2; m < 10; m++) if (v * m > lo && v * m < hi) minor.push(v * m);
      }
    } else {
      const n = Math.max(2, Math.floor(len / (isX ? 80 : 36)));
      const t = o.ticks ? o.ticks.filter((v) => v >= lo && v <= hi) : niceTicks(lo, hi, n).ticks;
      const e = prefixable(o.unit) ? prefixExponent(Math.max(Math.abs(lo), Math.abs(hi))) : 0;
      const scale = 10 ** e;
      const decimals = t.length > 1 ? Math.max(0, -Math.floor(Math.log10((t[1] - t[0]) / scale) + 1e-9)) : 0;
      for (const v of t) {
        ticks.push(v);
        labels.push((v / scale).toFixed(Math.min(6, decimals)).replace("-", "−"));
      }
      const u = o.unit && o.unit !== "1" ? `${prefixSymbol(e)}${o.unit}` : "";
      if (u) title = title ? `${title} (${u})` : u;
      if (o.title === false) title = "";
    }
    // grid
    ctx.strokeStyle = MINOR;
    ctx.beginPath();
    for (const v of minor) {
      const p = Math.round(P(v)) + 0.5;
      if (isX) { ctx.moveTo(p, this.top); ctx.lineTo(p, this.bottom); } else { ctx.moveTo(this.left, p); ctx.lineTo(this.right, p); }
    }
    ctx.stroke();
    ctx.strokeStyle = GRID;
    ctx.beginPath();
    for (const v of ticks) {
      const p = Math.round(P(v)) + 0.5;
      if (isX) { ctx.moveTo(p, this.top); ctx.lineTo(p, this.bottom); } else { ctx.moveTo(this.left, p); ctx.lineTo(this.right, p); }
    }
    ctx.stroke();
    // labels
    ctx.fillStyle = AXIS;
    if (isX) {
      ctx.textAlign = "center";
      ctx.textBaseline = "top";
      ticks.forEach((v, i) => ctx.fillText(labels[i], P(v), this.bottom + 4));
      if (title) {
        ctx.textBaseline = "bottom";
        ctx.fillText(title, (this.left + this.right) / 2, this.h - 2);
      }
    } else {
      ctx.textAlign = "right";
      ctx.textBaseline = "middle";
      ticks.forEach((v, i) => ctx.fillText(labels[i], this.left - 5, P(v)));
      if (title) {
        ctx.save();
        ctx.translate(11, (this.top + this.bottom) / 2);
        ctx.rotate(-Math.PI / 2);
        ctx.textAlign = "center";
        ctx.textBaseline = "middle";
        ctx.fillText(title, 0, 0);
        ctx.restore();
      }
    }
  }

  /** Frame around the plot area; call last. */
  end() {
    const { ctx } = this;
    ctx.strokeStyle = "#b8bcc6";
    ctx.lineWidth = 1;
    ctx.strokeRect(this.left + 0.5, this.top + 0.5, this.right - this.left - 1, this.bottom - this.top - 1);
  }

  clip(fn) {
    const { ctx } = this;
    ctx.save();
    ctx.beginPath();
    ctx.rect(this.left, this.top, this.right - this.left, this.bottom - this.top);
    ctx.clip();
    fn(ctx);
    ctx.restore();
  }

  /**
   * A line through n points (xAt(i), yAt(i)), i ascending in x. Points are summarised per
   * pixel column (first, lowest, highest, last: M4), so it looks exactly like the full line.
   * Where there are several points per column (a 16k-bin spectrum, a noisy trace) the
   * columns' ranges are filled as one band: one fill instead of thousands of zig-zag strokes,
   * which keeps software rendering cheap. Non-finite points (NaN, or ≤ 0 on a log axis)
   * break the line.
   */
  line(n, xAt, yAt, color, width = 1.25) {
    const { X, Y } = this;
    const C = this.columnBuffer(n + 8);
    let m = -1, col = NaN, brk = 1, pts = 0;
    const xmin = this.left - 2, xmax = this.right + 2;
    for (let i = 0; i < n; i++) {
      const px = X(xAt(i));
      const py = Y(yAt(i));
      if (!(py === py) || !(px === px) || py === Infinity || py === -Infinity) { brk = 1; col = NaN; continue; }
      if (px < xmin && i + 1 < n && X(xAt(i + 1)) < xmin) continue;
      const c = Math.round(px);
      pts++;
      if (c !== col) {
        m++;
        col = c;
        C.x[m] = c; C.fx[m] = px; C.first[m] = C.lo[m] = C.hi[m] = C.last[m] = py; C.brk[m] = brk;
        brk = 0;
      } else {
        if (py < C.lo[m]) C.lo[m] = py;
        if (py > C.hi[m]) C.hi[m] = py;
        C.last[m] = py;
      }
      if (px > xmax) break;
    }
    this.drawColumns(m + 1, pts, color, width);
  }

  /**
   * Room for `cap` pixel columns, in pixels: x (the column), fx (the first point's exact x),
   * first and last (y of the column's first and last point), lo and hi (its least and
   * greatest y) and brk (1: the line breaks before the column).
   */
  columnBuffer(cap) {
    if (!this.cols || this.cols.cap < cap) {
      const c = Math.max(cap, 4096);
      this.cols = { cap: c, x: new Float64Array(c), fx: new Float64Array(c), first: new Float64Array(c), lo: new Float64Array(c), hi: new Float64Array(c), last: new Float64Array(c), brk: new Uint8Array(c) };
    }
    return this.cols;
  }

  /** Draws the first `count` columns of [`columnBuffer`], summarising `pts` points, as `line` does. */
  drawColumns(count, pts, color, width = 1.25) {
    const C = this.cols;
    if (!count) return;
    this.clip((ctx) => {
      ctx.beginPath();
      if (pts > 1.6 * count) {
        // dense: fill the band of each run of columns, joined to the previous column
        const half = width / 2;
        let s = 0;
        while (s < count) {
          let e = s + 1;
          while (e < count && !C.brk[e]) e++;
          for (let k = s; k < e; k++) {
            let top = C.lo[k];
            if (k > s && C.last[k - 1] < top) top = C.last[k - 1];
            let bot = C.hi[k];
            if (k > s && C.last[k - 1] > bot) bot = C.last[k - 1];
            top -= half;
            if (k === s) ctx.moveTo(C.x[k] - 0.5, top); else ctx.lineTo(C.x[k] - 0.5, top);
            ctx.lineTo(C.x[k] + 0.5, top);
            C.fx[k] = bot + half; // reuse: bottom edge
          }
          for (let k = e - 1; k >= s; k--) {
            ctx.lineTo(C.x[k] + 0.5, C.fx[k]);
            ctx.lineTo(C.x[k] - 0.5, C.fx[k]);
          }
          ctx.closePath();
          s = e;
        }
        ctx.fillStyle = color;
        ctx.fill();
      } else {
        for (let k = 0; k < count; k++) {
          if (C.brk[k]) ctx.moveTo(C.fx[k], C.first[k]); else ctx.lineTo(C.fx[k], C.first[k]);
          if (C.lo[k] !== C.hi[k]) {
            ctx.lineTo(C.x[k], C.lo[k]);
            ctx.lineTo(C.x[k], C.hi[k]);
            ctx.lineTo(C.x[k], C.last[k]);
          }
        }
        ctx.strokeStyle = color;
        ctx.lineWidth = width;
        ctx.stroke();
      }
    });
  }

  /** Vertical marker at data x; dash e.g. [4, 3]; label drawn at the top. */
  vline(x, color, dash = null, label = null, y0 = null) {
    const px = Math.round(this.X(x)) + 0.5;
    if (!(px >= this.left && px <= this.right)) return;
    const { ctx } = this;
    ctx.save();
    ctx.strokeStyle = color;
    ctx.lineWidth = 1;
    if (dash) ctx.setLineDash(dash);
    ctx.beginPath();
    ctx.moveTo(px, y0 ?? this.top);
    ctx.lineTo(px, this.bottom);
    ctx.stroke();
    ctx.restore();
    if (label) this.label(px + 3, (y0 ?? this.top) + 2, label, color, "left", "top");
  }

  hline(y, color, dash = null) {
    const py = Math.round(this.Y(y)) + 0.5;
    if (!(py >= this.top && py <= this.bottom)) return;
    const { ctx } = this;
    ctx.save();
    ctx.strokeStyle = color;
    ctx.lineWidth = 1;
    if (dash) ctx.setLineDash(dash);
    ctx.beginPath();
    ctx.moveTo(this.left, py);
    ctx.lineTo(this.right, py);
    ctx.stroke();
    ctx.restore();
  }

  /** Text with a translucent white backing so it stays readable over traces. */
  label(x, y, text, color = AXIS, align = "left", baseline = "top", bold = false) {
    const { ctx } = this;
    ctx.font = bold ? `600 ${FONT}` : FONT;
    ctx.textAlign = align;
    ctx.textBaseline = baseline;
    const w = ctx.measureText(text).width;
    const bx = align === "left" ? x - 2 : align === "right" ? x - w - 2 : x - w / 2 - 2;
    const by = baseline === "top" ? y - 1 : baseline === "bottom" ? y - 13 : y - 7;
    ctx.fillStyle = "rgba(255,255,255,0.82)";
    ctx.fillRect(bx, by, w + 4, 14);
    ctx.fillStyle = color;
    ctx.fillText(text, x, y);
  }

  /** A message in the middle of the plot area (no data yet, etc.). */
  message(text) {
    this.label((this.left + this.right) / 2, (this.top + this.bottom) / 2, text, "#80868f", "center", "middle");
  }
}

function decadeLabel(v, unit) {
  if (!prefixable(unit)) {
    const d = Math.round(Math.log10(v));
    return d >= -3 && d <= 4 ? String(Number(v.toPrecision(1))) : `1e${d}`;
  }
  const e = prefixExponent(v, 1);
  return `${Math.round(v / 10 ** e)} ${prefixSymbol(e)}${unit}`;
}

/** Decade-snapped log range around the finite positive values [lo, hi]. */
export function decadeRange(lo, hi, minDecades = 1, maxDecades = 9) {
  if (!(lo > 0) || !(hi > 0)) return [1e-12, 1e-7];
  let a = Math.floor(Math.log10(lo)), b = Math.ceil(Math.log10(hi));
  if (b - a < minDecades) a = b - minDecades;
  if (b - a > maxDecades) a = b - maxDecades;
  return [10 ** a, 10 ** b];
}

/**
 * A linear range that follows the data without jitter: it widens at once to contain
 * [lo, hi] (with a margin) and narrows only when the data have shrunk well inside it.
 */
export class StickyRange {
  constructor() { this.r = null; }
  update(lo, hi, symmetric = false) {
    if (!(hi >= lo) || !isFinite(lo) || !isFinite(hi)) return this.r || [-1, 1];
    if (symmetric) { const m = Math.max(Math.abs(lo), Math.abs(hi)); lo = -m; hi = m; }
    const span = hi - lo || Math.abs(hi) || 1e-12;
    const want = [lo - 0.08 * span, hi + 0.08 * span];
    const r = this.r;
    if (!r || want[0] < r[0] || want[1] > r[1] || (r[1] - r[0]) > 2.5 * (want[1] - want[0])) this.r = want;
    return this.r;
  }
  reset() { this.r = null; }
}
