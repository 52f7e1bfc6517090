// The WebSocket connection to the daemon (docs/protocol.md): requests with ids and their
// replies as promises, data messages (JSON or the binary layout) to a handler, and
// reconnection by itself, with back-off, whenever the socket closes or goes silent.

const STREAM_CODES = { 1: "demods", 2: "spectrum", 3: "scope", 4: "status", 5: "force" };
const MAGIC = 0x46415446; // "FTAF" read as a little-endian u32
const utf8 = new TextDecoder();

/** A failed request: `code` is the protocol's error code, `message` the server's text. */
export class RequestError extends Error {
  constructor(code, message) {
    super(message);
    this.code = code;
  }
}

/** Decodes one binary data frame (40-byte little-endian header, then the payload). */
export function decodeBinary(buf) {
  const dv = new DataView(buf);
  if (buf.byteLength < 40 || dv.getUint32(0, true) !== MAGIC) throw new Error("binary frame without the FTAF magic");
  const version = dv.getUint16(4, true);
  if (version !== 1) throw new Error(`binary layout version ${version}, this page reads 1`);
  const stream = STREAM_CODES[dv.getUint8(6)];
  const m = {
    stream,
    seq: Number(dv.getBigUint64(8, true)),
    t: dv.getFloat64(16, true),
    t_synth_ns: dv.getBigUint64(24, true),
  };
  const count = dv.getUint32(32, true);
  if (stream === "demods" && dv.getUint8(7) === 1) {
    // batched: `count` time points of `records` records each, every point with its own
    // seq, t and t_synth_ns (24 bytes) before its records
    const records = dv.getUint32(36, true);
    const size = 24 + 40 * records;
    if (buf.byteLength !== 40 + count * size) throw new Error("batched demods frame of the wrong length");
    m.batched = new Array(count);
    for (let i = 0, o = 40; i < count; i++, o += size) {
      m.batched[i] = {
        stream,
        seq: Number(dv.getBigUint64(o, true)),
        t: dv.getFloat64(o + 8, true),
        t_synth_ns: dv.getBigUint64(o + 16, true),
        demods: demodRecords(dv, o + 24, records),
      };
    }
    return m;
  }
  switch (stream) {
    case "demods":
      m.demods = demodRecords(dv, 40, count);
      break;
    case "spectrum":
      m.bin_width = dv.getFloat64(40, true);
      m.magnitudes = new Float32Array(buf, 48, count);
      break;
    case "scope":
      m.dt = dv.getFloat64(40, true);
      m.start_phase = dv.getFloat64(48, true);
      m.phase_step = dv.getFloat64(56, true);
      m.samples = new Float32Array(buf, 64, count);
      break;
    case "status":
      return { ...JSON.parse(utf8.decode(new Uint8Array(buf, 40, count))), t_synth_ns: m.t_synth_ns };
    case "force":
      return { ...parseForce(utf8.decode(new Uint8Array(buf, 40, count))), t_synth_ns: m.t_synth_ns };
    default:
      throw new Error(`binary frame of unknown stream code ${dv.getUint8(6)}`);
  }
  return m;
}

/** `count` demodulator records of 40 bytes from byte `at`. */
function demodRecords(dv, at, count) {
  const d = new Array(count);
  for (let i = 0, o = at; i < count; i++, o += 40) {
    d[i] = {
      index: dv.getUint32(o, true),
      harmonic: dv.getUint32(o + 4, true),
      x: dv.getFloat64(o + 8, true),
      y: dv.getFloat64(o + 16, true),
      r: dv.getFloat64(o + 24, true),
      phase: dv.getFloat64(o + 32, true),
    };
  }
  return d;
}

const WAVEFORM = ',"waveform":';

/**
 * A force message (1 kHz by default) with its waveform left unparsed: the waveform (most of
 * the payload) is only needed for the message that gets drawn, so it stays text in
 * `waveformText` until `forceWaveform(m)` parses it. The fields around it (before and after)
 * are parsed; an array of numbers holds no `]` of its own. Falls back to a full parse.
 */
export function parseForce(text) {
  const i = text.lastIndexOf(WAVEFORM);
  const start = i + WAVEFORM.length;
  const end = i > 0 && text[start] === "[" ? text.indexOf("]", start) : -1;
  if (end > 0) {
    try {
      const m = JSON.parse(text.slice(0, i) + text.slice(end + 1));
      m.waveformText = text.slice(start, end + 1);
      return m;
    } catch {
      // not the expected layout: parse it all
    }
  }
  return JSON.parse(text);
}

/** The waveform of a force message (array of N values, null for NaN), parsed on first use. */
export function forceWaveform(m) {
  if (!m) return null;
  if (!m.waveform && typeof m.waveformText === "string") {
    m.waveform = JSON.parse(m.waveformText);
    m.waveformText = undefined;
  }
  return Array.isArray(m.waveform) ? m.waveform : null;
}

/**
 * handlers: onState(state, detail) with state "connecting" | "open" | "closed";
 * onOpen(conn) after the socket opened (subscribe there); onData(message, receivedMs).
 */
export class Connection {
  constructor(url, handlers) {
    this.url = url;
    this.h = handlers;
    this.ws = null;
    this.nextId = 1;
    this.pending = new Map();
    this.attempt = 0;
    this.state = "closed";
    this.lastRx = 0;
    this.connects = 0;
    this.timer = null;
    setInterval(() => this.watchdog(), 1000);
  }

  start() {
    clearTimeout(this.timer);
    this.setState("connecting", this.attempt ? `attempt ${this.attempt + 1}` : "");
    let ws;
    try {
      ws = new WebSocket(this.url);
    } catch (e) {
      this.retry(String(e));
      return;
    }
    ws.binaryType = "arraybuffer";
    this.ws = ws;
    this.openedAt = performance.now();
    ws.onopen = () => {
      if (ws !== this.ws) return;
      this.attempt = 0;
      this.connects++;
      this.lastRx = performance.now();
      this.setState("open", "");
      this.h.onOpen?.(this);
    };
    ws.onmessage = (ev) => {
      if (ws !== this.ws) return;
      const now = performance.timeOrigin + performance.now();
      this.lastRx = performance.now();
      let m;
      try {
        m = typeof ev.data === "string" ? JSON.parse(ev.data) : decodeBinary(ev.data);
      } catch (e) {
        console.warn("ftafm: unreadable message", e);
        return;
      }
      if ("ok" in m) {
        const p = this.pending.get(m.id);
        if (p) {
          this.pending.delete(m.id);
          if (m.ok) p.resolve(m);
          else p.reject(new RequestError(m.error?.code ?? "internal", m.error?.message ?? "request failed"));
        }
        return;
      }
      this.h.onData?.(m, now);
    };
    ws.onclose = (ev) => {
      if (ws !== this.ws) return;
      this.ws = null;
      this.failPending("the connection closed");
      const why = ev.code === 1001 ? "daemon shut down" : ev.code === 1006 ? "connection lost" : `closed (${ev.code}${ev.reason ? " " + ev.reason : ""})`;
      this.retry(why);
    };
    // A refused connection fires "error" then "close"; nothing to do here. Browsers log
    // failed connection attempts themselves.
    ws.onerror = () => {};
  }

  retry(why) {
    this.attempt++;
    const delay = Math.min(2000, 250 * 2 ** Math.min(this.attempt - 1, 3));
    this.setState("closed", `${why} — reconnecting in ${(delay / 1000).toFixed(delay < 1000 ? 2 : 0)} s`);
    clearTimeout(this.timer);
    this.timer = setTimeout(() => this.start(), delay);
  }

  /**
   * A socket that has said nothing for 5 s (status comes twice a second) is dead: reopen;
   * so is one that has not opened in 10 s. Time the page itself did not run (a tab in the
   * background, a machine too busy to schedule it) does not count: the socket's messages
   * wait behind the frozen page, and it would otherwise be closed the moment it resumes.
   */
  watchdog() {
    const now = performance.now();
    const frozen = this.lastTick !== undefined && now - this.lastTick > 2000;
    this.lastTick = now;
    const ws = this.ws;
    if (!ws) return;
    if (frozen) {
      this.lastRx = now;
      this.openedAt = now;
      return;
    }
    if (ws.readyState === WebSocket.OPEN && now - this.lastRx > 5000) {
      this.ws = null;
      ws.close();
      this.failPending("the connection went silent");
      this.retry("no data for 5 s");
    } else if (ws.readyState === WebSocket.CONNECTING && now - this.openedAt > 10000) {
      this.ws = null;
      ws.close();
      this.retry("no answer");
    }
  }

  failPending(why) {
    for (const p of this.pending.values()) p.reject(new RequestError("disconnected", why));
    this.pending.clear();
  }

  setState(state, detail) {
    this.state = state;
    this.h.onState?.(state, detail);
  }

  get open() {
    return !!this.ws && this.ws.readyState === WebSocket.OPEN;
  }

  /** Sends {id, op, ...fields}; resolves with the reply, rejects with a RequestError. */
  request(op, fields = {}) {
    if (!this.open) return Promise.reject(new RequestError("disconnected", "not connected to the daemon"));
    const id = this.nextId++;
    return new Promise((resolve, reject) => {
      this.pending.set(id, { resolve, reject });
      this.ws.send(JSON.stringify({ id, op, ...fields }));
    });
  }
}
