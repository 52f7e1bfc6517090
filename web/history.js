// History of the lock-in outputs: one ring per demodulator index (0 … 31) of x, y, r and
// phase, with a shared time axis (simulated time t of each demods message). At the default
// 1 kHz it holds the last 30 s; a demodulator whose harmonic changes starts afresh, and so
// does one whose oscillator changes (/demods/N/oscillator: the stream does not carry it, the
// page sets it from the node, setOscillator).

export const DEMODS = 32;

export class DemodHistory {
  constructor(capacity = 30000) {
    this.cap = capacity;
    this.t = new Float64Array(capacity);
    this.x = []; this.y = []; this.r = []; this.p = [];
    for (let i = 0; i < DEMODS; i++) {
      for (const a of [this.x, this.y, this.r, this.p]) a.push(new Float32Array(capacity).fill(NaN));
    }
    this.harmonic = new Int32Array(DEMODS).fill(-1); // -1: not in the latest message (disabled)
    this.oscillator = new Array(DEMODS).fill("drive"); // whose harmonic each reads: "drive" or "drive2"
    this.latest = new Array(DEMODS).fill(null);
    this.head = 0; // next write position
    this.len = 0;
    this.tNow = NaN;
    this.version = 0; // bumps on every push; panels redraw when it changed
    this.total = 0; // pushes since the last clear: entry a (0, 1, …) is at ring position a % cap
    this.epoch = 0; // bumps on every clear
    this.channelEpoch = new Uint32Array(DEMODS); // per channel: bumps when it is cleared
  }

  clear() {
    this.head = 0;
    this.len = 0;
    this.total = 0;
    this.epoch++;
    this.tNow = NaN;
    for (let i = 0; i < DEMODS; i++) this.clearChannel(i);
    this.version++;
  }

  clearChannel(i) {
    this.channelEpoch[i]++;
    this.x[i].fill(NaN); this.y[i].fill(NaN); this.r[i].fill(NaN); this.p[i].fill(NaN);
  }

  /** Demodulator i reads the harmonics of `osc` (its /demods/N/oscillator node) from now on;
   * true when that changed (its history then starts afresh). */
  setOscillator(i, osc) {
    if (i < 0 || i >= DEMODS || typeof osc !== "string" || this.oscillator[i] === osc) return false;
    this.oscillator[i] = osc;
    this.clearChannel(i);
    this.version++;
    return true;
  }

  /** Whether demodulator i reads a harmonic of the drive (not of the second excitation). */
  onDrive(i) {
    return this.oscillator[i] === "drive";
  }

  /** Adds one demods message. */
  push(t, demods) {
    if (t < this.tNow) this.clear(); // the daemon restarted: simulated time began again
    const k = this.head;
    this.t[k] = t;
    const seen = new Uint8Array(DEMODS);
    for (const d of demods) {
      const i = d.index;
      if (i >= DEMODS) continue;
      if (this.harmonic[i] !== d.harmonic) {
        if (this.harmonic[i] !== -1) this.clearChannel(i);
        this.harmonic[i] = d.harmonic;
      }
      seen[i] = 1;
      this.x[i][k] = d.x; this.y[i][k] = d.y; this.r[i][k] = d.r; this.p[i][k] = d.phase;
      this.latest[i] = d;
    }
    for (let i = 0; i < DEMODS; i++) {
      if (!seen[i]) {
        this.x[i][k] = this.y[i][k] = this.r[i][k] = this.p[i][k] = NaN;
        this.harmonic[i] = -1;
        this.latest[i] = null;
      }
    }
    this.head = (k + 1) % this.cap;
    this.total++;
    if (this.len < this.cap) this.len++;
    this.tNow = t;
    this.version++;
  }

  /** Ring position of the i-th oldest entry. */
  pos(i) {
    return (this.head - this.len + i + this.cap) % this.cap;
  }

  /** Index (into the oldest-first order) of the first entry with t ≥ t0. */
  firstSince(t0) {
    let lo = 0, hi = this.len;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (this.t[this.pos(mid)] < t0) lo = mid + 1; else hi = mid;
    }
    return lo;
  }

  /**
   * Mean over the last `span` seconds of demodulator i: amplitude (mean of r), and the
   * phase of the mean phasor (x, y). null when there is nothing.
   */
  mean(i, span = 0.2) {
    if (!this.len || this.harmonic[i] < 0) return null;
    const from = this.firstSince(this.tNow - span);
    let n = 0, sr = 0, sx = 0, sy = 0;
    const R = this.r[i], X = this.x[i], Y = this.y[i];
    for (let j = from; j < this.len; j++) {
      const k = this.pos(j);
      const r = R[k];
      if (r === r) { sr += r; sx += X[k]; sy += Y[k]; n++; }
    }
    if (!n) return null;
    return { r: sr / n, x: sx / n, y: sy / n, phase: Math.atan2(sy, sx), n, harmonic: this.harmonic[i] };
  }

  /** Demodulator index measuring harmonic k of the drive (the lowest index), or -1. */
  indexOf(k) {
    for (let i = 0; i < DEMODS; i++) if (this.harmonic[i] === k && this.onDrive(i)) return i;
    return -1;
  }
}
