// A scrolling time plot's line, summarised as it arrives: one history channel cut into bins
// of the plot's pixel width in time (first, least, greatest and last value of each), kept from
// frame to frame. A frame then maps a few hundred bins to pixels instead of every point in
// the window (10 000 at 1 kHz over 10 s), and new points only extend the newest bin. The bins
// sit on absolute simulated time, so a bin's content never changes once time has passed it,
// and it slides left smoothly as time goes on.

export class Strip {
  constructor() {
    this.key = "";
    this.cap = 0;
    this.reset(NaN, 0);
  }

  reset(dt, done) {
    this.dt = dt; // bin width (s)
    this.done = done; // history entries (its `total`) taken in so far
    this.n = 0; // bins held, oldest first
    this.gap = true; // a non-finite value came since the last bin
  }

  grow(n) {
    if (n <= this.cap) return;
    const cap = Math.max(n, 2 * this.cap, 1024);
    const f = () => new Float64Array(cap);
    const keep = (old, a) => { if (old) a.set(old.subarray(0, this.n)); return a; };
    this.bin = keep(this.bin, f());
    this.tf = keep(this.tf, f()); // time of the bin's first value
    this.first = keep(this.first, f());
    this.lo = keep(this.lo, f());
    this.hi = keep(this.hi, f());
    this.last = keep(this.last, f());
    this.count = keep(this.count, f());
    this.brk = keep(this.brk, new Uint8Array(cap));
    this.cap = cap;
  }

  /**
   * Takes in the history's new entries of `values` (one of its per-channel arrays, channel
   * `channel`), as bins of `dt` seconds over at least the last `span` seconds. `finite(v)`
   * says whether a value can be drawn (e.g. > 0 on a log axis).
   */
  sync(hist, channel, values, dt, span, finite) {
    const key = `${hist.epoch}/${hist.channelEpoch[channel]}/${dt}`;
    const oldest = hist.total - hist.len; // the oldest entry still in the ring
    if (key !== this.key || this.done < oldest) {
      this.key = key;
      const from = hist.len ? hist.firstSince(hist.tNow - span - 2 * dt) : 0;
      this.reset(dt, oldest + from);
    }
    const cap = hist.cap;
    for (let a = this.done; a < hist.total; a++) {
      const k = a % cap;
      const v = values[k];
      if (!finite(v)) {
        this.gap = true;
        continue;
      }
      const t = hist.t[k];
      const b = Math.floor(t / dt);
      const m = this.n - 1;
      if (m >= 0 && this.bin[m] === b && !this.gap) {
        if (v < this.lo[m]) this.lo[m] = v;
        if (v > this.hi[m]) this.hi[m] = v;
        this.last[m] = v;
        this.count[m]++;
        continue;
      }
      this.grow(this.n + 1);
      const j = this.n++;
      this.bin[j] = b;
      this.tf[j] = t;
      this.first[j] = this.lo[j] = this.hi[j] = this.last[j] = v;
      this.count[j] = 1;
      this.brk[j] = this.gap ? 1 : 0;
      this.gap = false;
    }
    this.done = hist.total;
    // Forget the bins that have left the span (in one move, when they are half the store).
    const keepFrom = Math.floor((hist.tNow - span) / dt) - 2;
    let drop = 0;
    while (drop < this.n && this.bin[drop] < keepFrom) drop++;
    if (drop > 0 && drop >= this.n / 2) {
      for (const a of [this.bin, this.tf, this.first, this.lo, this.hi, this.last, this.count, this.brk]) a.copyWithin(0, drop, this.n);
      this.n -= drop;
      this.brk[0] = 1;
    }
  }

  /** Least and greatest value over the bins that end after `t0` (s): [lo, hi], or null. */
  range(t0) {
    let lo = Infinity, hi = -Infinity;
    const b0 = Math.floor(t0 / this.dt);
    for (let j = this.n - 1; j >= 0 && this.bin[j] >= b0; j--) {
      if (this.lo[j] < lo) lo = this.lo[j];
      if (this.hi[j] > hi) hi = this.hi[j];
    }
    return lo <= hi ? [lo, hi] : null;
  }

  /**
   * Draws the line on `plot` (x: time relative to `tNow`, s; y: the values times `scale`)
   * from the bins after `t0`, as `Plot.line` would draw the points they hold.
   */
  draw(plot, tNow, t0, color, scale = 1) {
    const X = plot.X, Y = scale === 1 ? plot.Y : (v) => plot.Y(v * scale);
    const C = plot.columnBuffer(this.n + 8);
    const b0 = Math.floor(t0 / this.dt);
    let j = this.n;
    while (j > 0 && this.bin[j - 1] >= b0) j--;
    let m = 0, pts = 0;
    for (; j < this.n; j++) {
      const fx = X(this.tf[j] - tNow);
      const x = Math.round(X((this.bin[j] + 0.5) * this.dt - tNow));
      const a = Y(this.lo[j]), b = Y(this.hi[j]);
      C.x[m] = x;
      C.fx[m] = fx;
      C.first[m] = Y(this.first[j]);
      C.last[m] = Y(this.last[j]);
      C.lo[m] = Math.min(a, b);
      C.hi[m] = Math.max(a, b);
      C.brk[m] = m === 0 ? 1 : this.brk[j];
      pts += this.count[j];
      m++;
    }
    plot.drawColumns(m, pts, color);
  }
}
