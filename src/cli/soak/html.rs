//! The soak report as one self-contained HTML page: the summary table, the receive latency
//! histogram (logarithmic on both axes), the latency over time (per-second p50, p99 and
//! max, logarithmic) and the messages per second. Inline SVG, no script, no network; the
//! whole report is embedded as JSON (`<script type="application/json" id="soak-report">`)
//! so the figures can be redrawn elsewhere.

use std::fmt::Write as _;
use std::path::Path;

use super::SoakReport;

const WIDTH: f64 = 760.0;
const HEIGHT: f64 = 300.0;
const LEFT: f64 = 70.0;
const RIGHT: f64 = 20.0;
const TOP: f64 = 20.0;
const BOTTOM: f64 = 45.0;

/// Writes [`render`]`(report)` to `path`.
pub fn write(report: &SoakReport, path: &Path) -> std::io::Result<()> {
    std::fs::write(path, render(report))
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A latency in ns, readable: `850 µs`, `1.2 ms`, `3 s`.
fn duration(ns: f64) -> String {
    let (v, unit) = if ns >= 1e9 {
        (ns / 1e9, "s")
    } else if ns >= 1e6 {
        (ns / 1e6, "ms")
    } else if ns >= 1e3 {
        (ns / 1e3, "µs")
    } else {
        (ns, "ns")
    };
    if v >= 100.0 || v == v.round() {
        format!("{v:.0} {unit}")
    } else if v >= 10.0 {
        format!("{v:.1} {unit}")
    } else {
        format!("{v:.2} {unit}")
    }
}

/// A logarithmic axis from `lo` to `hi` (both > 0) onto pixels `a` … `b`.
#[derive(Clone, Copy)]
struct LogAxis {
    lo: f64,
    hi: f64,
    a: f64,
    b: f64,
}

impl LogAxis {
    fn new(lo: f64, hi: f64, a: f64, b: f64) -> Self {
        let lo = lo.max(1e-300);
        Self {
            lo,
            hi: hi.max(lo * 10.0),
            a,
            b,
        }
    }

    fn at(&self, v: f64) -> f64 {
        let f = (v.max(self.lo).ln() - self.lo.ln()) / (self.hi.ln() - self.lo.ln());
        self.a + f * (self.b - self.a)
    }

    /// Powers of ten within the range.
    fn decades(&self) -> Vec<f64> {
        let first = self.lo.log10().ceil() as i32;
        let last = self.hi.log10().floor() as i32;
        (first..=last).map(|e| 10f64.powi(e)).collect()
    }
}

/// A linear axis from `lo` to `hi` onto pixels `a` … `b`.
#[derive(Clone, Copy)]
struct LinAxis {
    lo: f64,
    hi: f64,
    a: f64,
    b: f64,
}

impl LinAxis {
    fn at(&self, v: f64) -> f64 {
        let span = if self.hi > self.lo {
            self.hi - self.lo
        } else {
            1.0
        };
        self.a + (v - self.lo) / span * (self.b - self.a)
    }

    /// About six round ticks.
    fn ticks(&self) -> Vec<f64> {
        let span = (self.hi - self.lo).max(1e-12);
        let raw = span / 6.0;
        let mag = 10f64.powf(raw.log10().floor());
        let step = [1.0, 2.0, 5.0, 10.0]
            .into_iter()
            .map(|m| m * mag)
            .find(|s| *s >= raw)
            .unwrap_or(10.0 * mag);
        let mut t = (self.lo / step).ceil() * step;
        let mut out = Vec::new();
        while t <= self.hi + step * 1e-9 {
            out.push(t);
            t += step;
        }
        out
    }
}

fn svg_open(out: &mut String, id: &str, title: &str) {
    let _ = write!(
        out,
        "<figure><figcaption>{}</figcaption>\n<svg id=\"{id}\" xmlns=\"http://www.w3.org/2000/svg\" \
         viewBox=\"0 0 {WIDTH} {HEIGHT}\" width=\"{WIDTH}\" height=\"{HEIGHT}\" role=\"img\">\n\
         <rect x=\"{LEFT}\" y=\"{TOP}\" width=\"{}\" height=\"{}\" class=\"plot\"/>\n",
        escape(title),
        WIDTH - LEFT - RIGHT,
        HEIGHT - TOP - BOTTOM
    );
}

fn x_tick(out: &mut String, x: f64, label: &str) {
    let y0 = HEIGHT - BOTTOM;
    let _ = writeln!(
        out,
        "<line x1=\"{x:.1}\" y1=\"{TOP}\" x2=\"{x:.1}\" y2=\"{y0}\" class=\"grid\"/>\
         <text x=\"{x:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
        y0 + 16.0,
        escape(label)
    );
}

fn y_tick(out: &mut String, y: f64, label: &str) {
    let _ = writeln!(
        out,
        "<line x1=\"{LEFT}\" y1=\"{y:.1}\" x2=\"{}\" y2=\"{y:.1}\" class=\"grid\"/>\
         <text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>",
        WIDTH - RIGHT,
        LEFT - 6.0,
        y + 4.0,
        escape(label)
    );
}

fn axis_labels(out: &mut String, x: &str, y: &str) {
    let _ = writeln!(
        out,
        "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\" class=\"label\">{}</text>\
         <text transform=\"translate(16 {:.1}) rotate(-90)\" text-anchor=\"middle\" class=\"label\">{}</text>",
        (LEFT + WIDTH - RIGHT) / 2.0,
        HEIGHT - 6.0,
        escape(x),
        (TOP + HEIGHT - BOTTOM) / 2.0,
        escape(y)
    );
}

fn empty(out: &mut String) {
    let _ = writeln!(
        out,
        "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">no data</text>",
        WIDTH / 2.0,
        HEIGHT / 2.0
    );
}

/// Counts per latency bin, both axes logarithmic, with the p50, p99 and max marked.
fn histogram(out: &mut String, r: &SoakReport) {
    svg_open(
        out,
        "latency-histogram",
        "Receive latency histogram (messages per bin, 10 bins per decade; both axes logarithmic)",
    );
    let bins = &r.latency_histogram;
    if bins.is_empty() {
        empty(out);
    } else {
        let lo = bins[0].lo_ns.max(1_000) as f64;
        let hi = bins[bins.len() - 1].hi_ns as f64;
        let x = LogAxis::new(
            10f64.powf(lo.log10().floor()),
            10f64.powf(hi.log10().ceil()),
            LEFT,
            WIDTH - RIGHT,
        );
        let top = bins.iter().map(|b| b.count).max().unwrap_or(1) as f64;
        let y = LogAxis::new(
            0.5,
            10f64.powf(top.log10().ceil()).max(10.0),
            HEIGHT - BOTTOM,
            TOP,
        );
        for d in x.decades() {
            x_tick(out, x.at(d), &duration(d));
        }
        for d in y.decades() {
            y_tick(out, y.at(d), &format!("{d}"));
        }
        for b in bins.iter().filter(|b| b.count > 0) {
            let (x0, x1) = (x.at(b.lo_ns.max(1_000) as f64), x.at(b.hi_ns as f64));
            let y0 = y.at(b.count as f64);
            let _ = writeln!(
                out,
                "<rect class=\"bar\" x=\"{x0:.1}\" y=\"{y0:.1}\" width=\"{:.1}\" height=\"{:.1}\">\
                 <title>{} – {}: {} messages</title></rect>",
                (x1 - x0 - 0.5).max(0.5),
                (HEIGHT - BOTTOM - y0).max(0.0),
                duration(b.lo_ns as f64),
                duration(b.hi_ns as f64),
                b.count
            );
        }
        let l = &r.latency_ns;
        for (name, v, class) in [
            ("p50", l.p50, "p50"),
            ("p99", l.p99, "p99"),
            ("max", l.max, "max"),
        ] {
            let xv = x.at(v as f64);
            let _ = writeln!(
                out,
                "<line class=\"{class}\" x1=\"{xv:.1}\" y1=\"{TOP}\" x2=\"{xv:.1}\" y2=\"{}\"/>\
                 <text class=\"{class}\" x=\"{:.1}\" y=\"{:.1}\">{name} {}</text>",
                HEIGHT - BOTTOM,
                xv + 3.0,
                TOP + 12.0 + if name == "p99" { 14.0 } else { 0.0 },
                duration(v as f64)
            );
        }
    }
    axis_labels(out, "latency (receipt − t_synth_ns)", "messages");
    out.push_str("</svg></figure>\n");
}

/// Per-second p50, p99 and max against time, latency logarithmic.
fn timeline(out: &mut String, r: &SoakReport) {
    svg_open(
        out,
        "latency-timeline",
        "Receive latency over time: p50, p99 and max of each second, and the longest stall in it \
         of this machine and of the daemon's (logarithmic)",
    );
    let points: Vec<_> = r.timeline.iter().filter(|p| p.messages > 0).collect();
    if points.is_empty() {
        empty(out);
    } else {
        let lo = points
            .iter()
            .map(|p| p.p50_ns)
            .min()
            .unwrap_or(1_000)
            .max(1_000) as f64;
        let hi = points
            .iter()
            .map(|p| p.max_ns.max(p.stall_max_ns).max(p.daemon_stall_max_ns))
            .max()
            .unwrap_or(1_000)
            .max(1_000) as f64;
        let y = LogAxis::new(
            10f64.powf(lo.log10().floor()),
            10f64.powf(hi.log10().ceil()),
            HEIGHT - BOTTOM,
            TOP,
        );
        let x = LinAxis {
            lo: 0.0,
            hi: r.seconds.max(1.0),
            a: LEFT,
            b: WIDTH - RIGHT,
        };
        for t in x.ticks() {
            x_tick(out, x.at(t), &format!("{t} s"));
        }
        for d in y.decades() {
            y_tick(out, y.at(d), &duration(d));
        }
        for (class, f) in [
            (
                "max",
                (|p: &super::TimelinePoint| p.max_ns) as fn(&_) -> u64,
            ),
            ("p99", |p| p.p99_ns),
            ("p50", |p| p.p50_ns),
            ("stall", |p| p.stall_max_ns),
            ("daemon-stall", |p| p.daemon_stall_max_ns),
        ] {
            let pts: Vec<String> = points
                .iter()
                .map(|p| format!("{:.1},{:.1}", x.at(p.t), y.at(f(p) as f64)))
                .collect();
            let _ = writeln!(
                out,
                "<polyline class=\"{class}\" fill=\"none\" points=\"{}\"/>",
                pts.join(" ")
            );
        }
        let _ = writeln!(
            out,
            "<text class=\"max\" x=\"{0:.1}\" y=\"{1:.1}\">max</text>\
             <text class=\"p99\" x=\"{0:.1}\" y=\"{2:.1}\">p99</text>\
             <text class=\"p50\" x=\"{0:.1}\" y=\"{3:.1}\">p50</text>\
             <text class=\"stall\" x=\"{0:.1}\" y=\"{4:.1}\">machine stall</text>\
             <text class=\"daemon-stall\" x=\"{0:.1}\" y=\"{5:.1}\">daemon's stall</text>",
            WIDTH - RIGHT - 80.0,
            TOP + 14.0,
            TOP + 28.0,
            TOP + 42.0,
            TOP + 56.0,
            TOP + 70.0
        );
    }
    axis_labels(out, "time since the measurement started", "latency");
    out.push_str("</svg></figure>\n");
}

/// Messages received per second against time, with the seconds that had gaps marked.
fn rate(out: &mut String, r: &SoakReport) {
    svg_open(
        out,
        "message-rate",
        "Messages received per second (all clients); red marks: seconds with seq gaps",
    );
    let mut t0 = 0.0;
    let points: Vec<(f64, f64, u64)> = r
        .timeline
        .iter()
        .map(|p| {
            let dt = (p.t - t0).max(1e-3);
            t0 = p.t;
            (p.t, p.messages as f64 / dt, p.gaps)
        })
        .collect();
    if points.is_empty() {
        empty(out);
    } else {
        let top = points.iter().map(|p| p.1).fold(0.0, f64::max).max(1.0) * 1.1;
        let x = LinAxis {
            lo: 0.0,
            hi: r.seconds.max(1.0),
            a: LEFT,
            b: WIDTH - RIGHT,
        };
        let y = LinAxis {
            lo: 0.0,
            hi: top,
            a: HEIGHT - BOTTOM,
            b: TOP,
        };
        for t in x.ticks() {
            x_tick(out, x.at(t), &format!("{t} s"));
        }
        for v in y.ticks() {
            y_tick(out, y.at(v), &format!("{v}"));
        }
        let pts: Vec<String> = points
            .iter()
            .map(|p| format!("{:.1},{:.1}", x.at(p.0), y.at(p.1)))
            .collect();
        let _ = writeln!(
            out,
            "<polyline class=\"p50\" fill=\"none\" points=\"{}\"/>",
            pts.join(" ")
        );
        for p in points.iter().filter(|p| p.2 > 0) {
            let _ = writeln!(
                out,
                "<circle class=\"gap\" cx=\"{:.1}\" cy=\"{:.1}\" r=\"3\"><title>{} missing</title></circle>",
                x.at(p.0),
                y.at(p.1),
                p.2
            );
        }
    }
    axis_labels(out, "time since the measurement started", "messages / s");
    out.push_str("</svg></figure>\n");
}

fn summary(out: &mut String, r: &SoakReport) {
    let l = &r.latency_ns;
    let s = &r.server;
    let mib = |b: Option<u64>| {
        b.map(|b| format!("{:.1} MiB", b as f64 / 1048576.0))
            .unwrap_or_else(|| "unavailable".into())
    };
    let rows: Vec<(&str, String)> = vec![
        ("daemon", r.url.clone()),
        (
            "clients' CPU",
            if r.cpu.is_empty() {
                "not recorded".to_owned()
            } else {
                r.cpu.clone()
            },
        ),
        (
            "clients × streams",
            format!("{} × {}", r.clients, r.streams.join(", ")),
        ),
        ("measured", format!("{:.1} s", r.seconds)),
        (
            "messages",
            format!("{} ({:.0}/s)", r.messages, r.messages_per_s),
        ),
        (
            "bytes",
            format!("{} ({:.2} MB/s)", r.bytes, r.bytes_per_s / 1e6),
        ),
        ("seq gaps (missing messages)", r.gaps.to_string()),
        ("disconnects", r.disconnects.to_string()),
        (
            "latency p50 / p90 / p99 / p99.9 / max",
            format!(
                "{} / {} / {} / {} / {}",
                duration(l.p50 as f64),
                duration(l.p90 as f64),
                duration(l.p99 as f64),
                duration(l.p999 as f64),
                duration(l.max as f64)
            ),
        ),
        (
            "server overruns",
            format!("{} samples in {} blocks", s.overruns, s.overrun_blocks),
        ),
        (
            "messages dropped for slow clients",
            s.messages_dropped.to_string(),
        ),
        ("frames dropped by the DSP", s.frames_dropped.to_string()),
        (
            "clients (server's view) during / after",
            format!("{} / {}", s.clients_during, s.clients_after),
        ),
        ("clients stalled", s.clients_stalled.to_string()),
        (
            "daemon memory before / after / peak",
            format!(
                "{} / {} / {}",
                mib(s.rss_bytes_before),
                mib(s.rss_bytes_after),
                mib(s.rss_peak_bytes)
            ),
        ),
        (
            "this machine's stalls (1 ms naps) p99 / max, count over 5 ms",
            format!(
                "{} / {}, {}",
                duration(r.machine.stall_ns.p99 as f64),
                duration(r.machine.stall_ns.max as f64),
                r.machine.stalls_over_5ms
            ),
        ),
        (
            "the daemon's stalls p99 / max (since it started)",
            s.machine_stall_ns
                .map(|d| format!("{} / {}", duration(d.p99 as f64), duration(d.max as f64)))
                .unwrap_or_else(|| "not reported".into()),
        ),
        (
            "messages over 20 ms / in flight during a stall ≥ 10 ms of this machine",
            format!(
                "{} / {}",
                r.machine.slow_messages, r.machine.slow_messages_in_stalls
            ),
        ),
        (
            "seconds with a message over 20 ms / next to a stall ≥ 10 ms (this machine or the daemon's)",
            format!(
                "{} / {}",
                r.machine.slow_seconds, r.machine.slow_seconds_with_stall
            ),
        ),
        (
            "CPU time stolen by the hypervisor",
            r.machine
                .cpu_steal_s
                .map(|t| format!("{t:.2} s"))
                .unwrap_or_else(|| "unknown".into()),
        ),
        (
            "memory growth",
            s.memory_growth_bytes
                .map(|g| format!("{g} bytes ({:+.2} MiB)", g as f64 / 1048576.0))
                .unwrap_or_else(|| s.memory.clone()),
        ),
    ];
    out.push_str("<table id=\"summary\">\n");
    for (k, v) in rows {
        let _ = writeln!(
            out,
            "<tr><th>{}</th><td>{}</td></tr>",
            escape(k),
            escape(&v)
        );
    }
    out.push_str("</table>\n");
}

/// The page.
pub fn render(r: &SoakReport) -> String {
    let mut out = String::with_capacity(64 * 1024);
    let _ = write!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n\
         <title>ftafm soak: {} clients, {:.0} s</title>\n<style>\n\
         body {{ font: 14px system-ui, sans-serif; margin: 24px; color: #222; }}\n\
         table {{ border-collapse: collapse; margin-bottom: 24px; }}\n\
         th, td {{ text-align: left; padding: 3px 12px; border-bottom: 1px solid #ddd; }}\n\
         th {{ font-weight: 500; color: #555; }}\n\
         figure {{ margin: 0 0 24px 0; }} figcaption {{ font-weight: 600; margin-bottom: 4px; }}\n\
         svg text {{ font: 11px system-ui, sans-serif; fill: #444; }} svg .label {{ font-size: 12px; }}\n\
         .plot {{ fill: #fbfbfb; stroke: #999; }} .grid {{ stroke: #e4e4e4; }}\n\
         .bar {{ fill: #4a7fc1; }} .gap {{ fill: #d62728; }}\n\
         line.p50, polyline.p50 {{ stroke: #1f77b4; stroke-width: 1.5; }} text.p50 {{ fill: #1f77b4; }}\n\
         line.p99, polyline.p99 {{ stroke: #ff7f0e; stroke-width: 1.5; }} text.p99 {{ fill: #ff7f0e; }}\n\
         line.max, polyline.max {{ stroke: #d62728; stroke-width: 1; }} text.max {{ fill: #d62728; }}\n\
         polyline.stall {{ stroke: #7f7f7f; stroke-width: 1; stroke-dasharray: 3 2; }} text.stall {{ fill: #7f7f7f; }}\n\
         polyline.daemon-stall {{ stroke: #9467bd; stroke-width: 1; stroke-dasharray: 1 2; }} text.daemon-stall {{ fill: #9467bd; }}\n\
         </style></head><body>\n<h1>ftafm soak</h1>\n",
        r.clients, r.seconds
    );
    summary(&mut out, r);
    histogram(&mut out, r);
    timeline(&mut out, r);
    rate(&mut out, r);
    // The data of every figure, for redrawing elsewhere; `</` cannot end the script early.
    let json = serde_json::to_string(r)
        .unwrap_or_default()
        .replace("</", "<\\/");
    let _ = write!(
        out,
        "<script type=\"application/json\" id=\"soak-report\">{json}</script>\n</body></html>\n"
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::soak::{HistogramBin, TimelinePoint};

    #[test]
    fn axes_and_durations() {
        let a = LogAxis::new(1e3, 1e6, 0.0, 300.0);
        assert!((a.at(1e3) - 0.0).abs() < 1e-9 && (a.at(1e6) - 300.0).abs() < 1e-9);
        assert_eq!(a.decades(), vec![1e3, 1e4, 1e5, 1e6]);
        let l = LinAxis {
            lo: 0.0,
            hi: 600.0,
            a: 0.0,
            b: 1.0,
        };
        assert_eq!(l.ticks().first(), Some(&0.0));
        assert_eq!(l.ticks().last(), Some(&600.0));
        assert_eq!(duration(1_500_000.0), "1.50 ms");
        assert_eq!(duration(850_000.0), "850 µs");
        assert_eq!(escape("<a&\"b\">"), "&lt;a&amp;&quot;b&quot;&gt;");
    }

    #[test]
    fn an_empty_report_still_renders() {
        let r = SoakReport {
            url: "ws://h:1/ws".into(),
            cpu: String::new(),
            clients: 1,
            streams: vec!["demods".into()],
            seconds: 1.0,
            messages: 0,
            gaps: 0,
            disconnects: 0,
            bytes: 0,
            messages_per_s: 0.0,
            bytes_per_s: 0.0,
            latency_ns: Default::default(),
            per_stream: Default::default(),
            server: Default::default(),
            latency_histogram: Vec::new(),
            timeline: Vec::new(),
            machine: Default::default(),
        };
        let page = render(&r);
        assert_eq!(page.matches("no data").count(), 3);
        let mut r = r;
        r.latency_histogram = vec![HistogramBin {
            lo_ns: 1_000_000,
            hi_ns: 1_258_925,
            count: 7,
        }];
        r.timeline = vec![TimelinePoint {
            t: 1.0,
            messages: 7,
            gaps: 1,
            p50_ns: 1_000_000,
            p99_ns: 1_100_000,
            max_ns: 1_200_000,
            stall_max_ns: 30_000_000,
            daemon_stall_max_ns: 2_000_000,
        }];
        let page = render(&r);
        assert!(page.contains("<title>1 ms – 1.26 ms: 7 messages</title>"));
        assert!(page.contains("class=\"gap\""));
        // The stall (30 ms) sets the top of the timeline's axis: 100 ms.
        assert!(page.contains("polyline class=\"stall\""));
        assert!(page.contains("polyline class=\"daemon-stall\""));
        assert!(page.contains(">100 ms</text>"));
    }
}
