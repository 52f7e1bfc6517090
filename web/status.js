// Pipeline health from the status stream (2 Hz), plus what this page itself sees: messages
// lost on the way (seq gaps), the latency from synthesis to this page, and its frame rate.

import { ns, si } from "./units.js";

function escapeHtml(text) {
  return String(text).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
}

function group(n) {
  return n == null ? "–" : Number(n).toLocaleString("en-US").replace(/,/g, "\u202f");
}

/** Large counts compactly: 4096, 2.10 M. */
function compact(n) {
  if (n == null) return "–";
  if (Math.abs(n) < 1e4) return String(n);
  const e = Math.min(18, Math.floor(Math.log10(Math.abs(n)) / 3) * 3);
  return `${(n / 10 ** e).toPrecision(3)} ${{ 3: "k", 6: "M", 9: "G", 12: "T", 15: "P", 18: "E" }[e]}`;
}

function pct(sorted, q) {
  if (!sorted.length) return null;
  return sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))];
}

export class StatusPanel {
  constructor(app) {
    this.app = app;
    this.el = document.getElementById("status");
    this.s = null;
    this.dirty = false;
    this.last = 0;
  }

  onData(m) {
    this.s = m;
    this.dirty = true;
  }

  draw(now) {
    // re-render on new status, and once a second for the page's own figures
    if (!this.dirty && now - this.last < 1000) return;
    this.dirty = false;
    this.last = now;
    const s = this.s, st = this.app.stats;
    const rows = [];
    const add = (k, v, cls = "", title = "") => rows.push(`<dt class="${cls.includes("wide") ? "wide" : ""}"${title ? ` title="${title}"` : ""}>${k}</dt><dd class="${cls}" data-key="${k}">${v}</dd>`);
    if (s) {
      const c = s.counters || {};
      add("sample rate", si(s.sample_rate, "Hz", 4));
      add("real-time factor", s.realtime_factor == null ? "–" : s.realtime_factor.toFixed(4) + (s.realtime ? "" : " (free-running)"),
        s.realtime && s.realtime_factor < 0.98 ? "bad" : "", "samples processed per wall-clock second / sample rate");
      const fill = s.ring_capacity ? (100 * s.ring_fill) / s.ring_capacity : 0;
      add("ring fill", `${compact(s.ring_fill)} / ${compact(s.ring_capacity)} (${fill.toFixed(fill < 1 ? 2 : 1)} %)`, fill > 50 ? "warn" : "",
        `samples waiting between synthesiser and DSP: ${group(s.ring_fill)} of ${group(s.ring_capacity)}`);
      add("overruns", c.overrun_samples > 0 ? `${compact(c.overrun_samples)} samples (${group(c.overrun_blocks)} blocks)` : "0", c.overrun_samples > 0 ? "bad" : "",
        "samples the DSP could not take in time, since start");
      add("dropped msgs", group(s.messages_dropped), s.messages_dropped > 0 ? "warn" : "", "data messages dropped for slow clients since start (server, all clients)");
      add("clients", group(s.clients));
      if (s.source === "stream") {
        // A client's samples, not the synthesiser's: what came, what the writer skipped and
        // what the feed had no room for (both jumped by the chain), and what waits.
        add("source", "stream", "", "the chain runs on samples a client streams in (/source/kind): the synthesiser's nodes shape nothing");
        const lost = (c.stream_gap_samples || 0) + (c.stream_dropped_samples || 0);
        add("streamed", `${compact(c.stream_samples || 0)} samples, ${compact(c.stream_gap_samples || 0)} skipped, ${compact(c.stream_dropped_samples || 0)} dropped; ${compact(s.stream_fill || 0)} waiting`,
          lost > 0 ? "warn" : "",
          `samples taken into the chain (${group(c.stream_samples || 0)} in ${group(c.stream_frames || 0)} frames), skipped by the writer's frames (a gap in their indices), dropped for want of room in the feed (the chain behind the writer), and waiting in the feed now (of ${group(s.stream_capacity || 0)})`);
      }
      if (s.regime) add("regime", s.regime, "", "the tapping regime the live orbit is in (the branch it is on): the sign of the mean tip–sample force, read from harmonic 1's amplitude and phase against the free lever's (and the mean deflection where a demodulator measures harmonic 0)");
      const l = s.latency_synth_to_send || {};
      add("latency p50/p99", `${ns(l.p50)} / ${ns(l.p99)}`, "", "synthesis → handed to a client's socket (server's view)");
      if (c.clipped_samples > 0) add("clipped samples", group(c.clipped_samples), "warn", "samples beyond ±/noise/adc_range");
      // The operating point in words (out-of-band demodulators, clipping, …), as the server says it.
      // A whole row each, wrapped: a long warning must not widen the panel (nor the page).
      for (const w of s.warnings || []) add("warning", escapeHtml(w), "warn wide");
    }
    const lat = st.latency.slice(0, Math.min(st.latencyCount, st.latency.length)).sort();
    const p50 = pct(lat, 0.5), p99 = pct(lat, 0.99);
    add("to page p50/p99", p50 == null ? "–" : `${si(p50 * 1e-3, "s", 3)} / ${si(p99 * 1e-3, "s", 3)}`, "",
      "synthesis → this page received the lock-in time point (same machine clocks); the points come 20 to a message, so this includes up to 20 output periods of waiting for the message to fill");
    const gaps = st.gaps.demods + st.gaps.spectrum + st.gaps.scope + st.gaps.status;
    add("lost here", group(gaps), gaps > 0 ? "warn" : "", "seq gaps seen by this page");
    const slowed = st.behind ? " (behind: drawing slowed)" : st.strained ? " (the daemon is behind real time: drawing less)" : "";
    add("display", `${st.fps.toFixed(0)} fps${slowed}`, st.behind || st.strained || (st.fps > 0 && st.fps < 15) ? "warn" : "",
      "frames drawn per second by this page; behind its messages (handled 0.5 s later than at best in the last 10 s) it draws at most twice a second and at most a fifth of the time, so that reading keeps up; while the daemon reports falling behind real time (real-time factor below 0.98, or its sample ring over 5 % full) it draws at most 10 times a second, until 5 s after the last such report, to give a machine it shares with the daemon back its CPU");
    this.el.innerHTML = rows.join("");
  }
}
