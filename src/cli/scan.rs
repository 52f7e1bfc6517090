//! `ftafm scan`: records scan frames without the daemon, free-running (as fast as the
//! machine goes) or paced, writes each channel as `.gsf` and `.npy`, and reports per channel
//! the contrast and contrast-to-noise ratio of each inclusion against the base material.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use ringbuf::traits::Consumer;
use serde::Serialize;

use super::{ConfigArg, EXIT_USAGE, load, print_report};
use crate::config::Settings;
use crate::imaging::{Assembler, ImageFrame, export};
use crate::pipeline::{CountersSnapshot, Pipeline, PipelineError};
use crate::sweep::Regime;
use crate::synth::{Raster, sample_map};

/// How a region of the image compares with the base material in one channel.
#[derive(Clone, Debug, Serialize)]
pub struct RegionContrast {
    /// Region index: 1 + the index among enabled inclusions.
    pub region: usize,
    /// Interior pixels (all four corners in the region) averaged.
    pub pixels: usize,
    /// Mean over the region (channel unit).
    pub mean: f64,
    /// Standard deviation over the region (channel unit).
    pub std: f64,
    /// The paper's relative contrast `1 − mean_base/mean_region` (1); meaningless where the
    /// channel's zero is arbitrary (the height): see `step`.
    pub contrast: f64,
    /// `mean_region − mean_base` (channel unit): the height step for the height.
    pub step: f64,
    /// `|mean_base − mean_region| / √((std_base² + std_region²)/2)` (1).
    pub cnr: f64,
}

/// The branch the tip was on over one region's interior pixels (the frame's `regime`
/// channel, `crate::sweep::regime`): where an attractive and a repulsive orbit coexist, a
/// region can be imaged on the other branch from the base, and its contrast then compares
/// two orbits, not two materials.
#[derive(Clone, Debug, Serialize)]
pub struct RegionBranch {
    /// Region index: 0 the base material, 1 + the index among enabled inclusions.
    pub region: usize,
    /// The regime of most of its pixels (`"free"`, `"attractive"`, `"repulsive"`), `None`
    /// where no pixel has one.
    pub regime: Option<&'static str>,
    /// The share of its pixels with a regime that are in `regime` (1).
    pub share: f64,
    /// `regime` differs from the base's: this region's contrasts compare two branches.
    pub across_branches: bool,
}

/// One channel of a recorded frame.
#[derive(Clone, Debug, Serialize)]
pub struct ChannelReport {
    pub name: String,
    pub unit: &'static str,
    /// Mean and standard deviation over the base material's interior pixels.
    pub base_mean: f64,
    pub base_std: f64,
    pub base_pixels: usize,
    pub regions: Vec<RegionContrast>,
}

/// What `ftafm scan` reports; `--json` prints it as one object.
#[derive(Clone, Debug, Serialize)]
pub struct ScanReport {
    pub pixels: u32,
    /// Side of the scan area (m).
    pub size: f64,
    /// Lines per second as realised (Hz).
    pub line_rate: f64,
    /// Simulated time one frame takes (s): the instrument's scan time.
    pub frame_time: f64,
    /// Wall-clock time the recording took (s).
    pub wall_seconds: f64,
    /// Frames recorded.
    pub frames: usize,
    /// Files written.
    pub files: Vec<PathBuf>,
    /// Per channel, of the last frame.
    pub channels: Vec<ChannelReport>,
    /// Per region (the base first), the branch its pixels were imaged on, of the last frame.
    pub branches: Vec<RegionBranch>,
    /// Pixels whose inversion failed.
    pub inversion_failed: u64,
    /// The pipeline's counters at the end (overruns, pixels dropped, ...).
    pub counters: CountersSnapshot,
}

/// Why a scan could not be recorded.
#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    #[error("cannot write {0}: {1}")]
    Write(PathBuf, std::io::Error),
}

/// Records `frames` frames of the scan `settings` describe (`/scan/enable` is forced on);
/// free-running unless `settings.synth.realtime`. Writes `<out>/<channel>[-fN].{gsf,npy}`
/// when `out` is given. `progress` is called about five times a second.
pub fn run(
    settings: &Settings,
    frames: usize,
    out: Option<&Path>,
    mut progress: impl FnMut(Progress),
) -> Result<ScanReport, ScanError> {
    let mut settings = settings.clone();
    settings.scan.enable = true;
    // The images need neither spectra nor traces.
    settings.spectrum.enable = false;
    settings.scope.enable = false;
    let fs = settings.synth.sample_rate;
    let raster = Raster::new(&settings.scan, fs, settings.drive.frequency, 0, 0);
    let (pipeline, mut output) = Pipeline::start(&settings)?;
    let mut assembler = Assembler::new(&settings);
    let start = Instant::now();
    let mut next_progress = PROGRESS_PERIOD;
    let mut recorded: Vec<ImageFrame> = Vec::new();
    let mut last_line = (0, 0);
    let mut lines_done: u64 = 0;
    let lines_total = frames as u64 * u64::from(raster.pixels);
    while recorded.len() < frames {
        let mut idle = true;
        while let Some(t) = output.topography.try_pop() {
            assembler.topography(t);
            idle = false;
        }
        // In bounded batches, so topography keeps being taken while the DSP races ahead.
        for _ in 0..256 {
            let Some(p) = output.pixels.try_pop() else {
                break;
            };
            idle = false;
            for line in assembler.pixel(&p) {
                last_line = (line.line, line.frame);
                lines_done += 1;
                if let Some(frame) = assembler.take_finished() {
                    recorded.push(frame);
                }
            }
            if recorded.len() >= frames {
                break;
            }
        }
        output.demods.skip(usize::MAX);
        let wall = start.elapsed().as_secs_f64();
        if wall >= next_progress {
            progress(Progress {
                line: last_line.0 + 1,
                lines: raster.pixels,
                frame: last_line.1,
                lines_done: lines_done.min(lines_total),
                lines_total,
                wall,
            });
            next_progress = wall + PROGRESS_PERIOD;
        }
        if idle {
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
    }
    let wall_seconds = start.elapsed().as_secs_f64();
    let counters = pipeline.stop();
    let mut files = Vec::new();
    if let Some(dir) = out {
        std::fs::create_dir_all(dir).map_err(|e| ScanError::Write(dir.to_owned(), e))?;
        for (i, frame) in recorded.iter().enumerate() {
            let suffix = if frames > 1 {
                format!("-f{i}")
            } else {
                String::new()
            };
            let meta = export::Metadata::of(frame, std::time::SystemTime::now());
            for c in &frame.channels {
                for (ext, bytes) in [
                    (
                        "gsf",
                        export::gsf(c, frame.pixels, frame.size, frame.origin, &meta),
                    ),
                    ("npy", export::npy(c, frame.pixels)),
                    (
                        "json",
                        export::npy_companion(c, frame.pixels, frame.size, frame.origin, &meta)
                            .into_bytes(),
                    ),
                ] {
                    let path = dir.join(format!("{}{suffix}.{ext}", c.name));
                    std::fs::write(&path, bytes).map_err(|e| ScanError::Write(path.clone(), e))?;
                    files.push(path);
                }
            }
        }
    }
    let last = recorded.last().expect("at least one frame");
    Ok(ScanReport {
        pixels: raster.pixels,
        size: raster.size,
        line_rate: raster.line_rate(fs),
        frame_time: raster.frame_time(fs),
        wall_seconds,
        frames: recorded.len(),
        files,
        channels: contrast(&settings, &raster, last),
        branches: branches(&settings, &raster, last),
        inversion_failed: assembler.inversion_failed,
        counters,
    })
}

/// Wall-clock seconds between two calls of `run`'s `progress`.
const PROGRESS_PERIOD: f64 = 0.2;

/// How far a recording is, as `run` reports it.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Lines finished in the current frame.
    pub line: u32,
    /// Lines of a frame.
    pub lines: u32,
    /// The current frame's number.
    pub frame: u64,
    /// Lines finished over all frames to record.
    pub lines_done: u64,
    /// Lines of all frames to record.
    pub lines_total: u64,
    /// Wall-clock time since the recording started (s).
    pub wall: f64,
}

/// Per channel: base statistics and each region's contrast and CNR, over interior pixels
/// (whose four corners lie in the same region), so edge pixels do not blur the numbers.
pub fn contrast(settings: &Settings, raster: &Raster, frame: &ImageFrame) -> Vec<ChannelReport> {
    let map = sample_map(settings);
    let region_of = interior_regions(settings, raster, frame.pixels);
    let stats = |data: &[f64], region: usize| -> (f64, f64, usize) {
        let v: Vec<f64> = data
            .iter()
            .zip(&region_of)
            .filter(|(x, r)| **r == Some(region) && x.is_finite())
            .map(|(x, _)| *x)
            .collect();
        let count = v.len();
        if count == 0 {
            return (f64::NAN, f64::NAN, 0);
        }
        let mean = v.iter().sum::<f64>() / count as f64;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (count.max(2) - 1) as f64;
        (mean, var.sqrt(), count)
    };
    frame
        .channels
        .iter()
        .map(|c| {
            let (base_mean, base_std, base_pixels) = stats(&c.data, 0);
            let regions = (1..map.regions().len())
                .map(|r| {
                    let (mean, std, pixels) = stats(&c.data, r);
                    RegionContrast {
                        region: r,
                        pixels,
                        mean,
                        std,
                        contrast: 1.0 - base_mean / mean,
                        step: mean - base_mean,
                        cnr: (base_mean - mean).abs()
                            / ((base_std.powi(2) + std.powi(2)) / 2.0).sqrt(),
                    }
                })
                .collect();
            ChannelReport {
                name: c.name.clone(),
                unit: c.unit,
                base_mean,
                base_std,
                base_pixels,
                regions,
            }
        })
        .collect()
}

/// Each pixel's region (row-major, `pixels²`) where its four corners lie in the same one,
/// else `None`: the pixels a region's statistics are taken over.
fn interior_regions(settings: &Settings, raster: &Raster, pixels: u32) -> Vec<Option<usize>> {
    let map = sample_map(settings);
    let n = pixels;
    let half = 0.5 * raster.pixel_size();
    let mut region_of = vec![None; (n * n) as usize];
    for line in 0..n {
        for column in 0..n {
            let (x, y) = raster.pixel_centre(column, line);
            let corners = [(-half, -half), (-half, half), (half, -half), (half, half)]
                .map(|(dx, dy)| map.region_at(x + dx, y + dy));
            if corners.iter().all(|&r| r == corners[0]) {
                region_of[(line * n + column) as usize] = Some(corners[0]);
            }
        }
    }
    region_of
}

/// Per region (the base first), the regime most of its interior pixels were imaged in, from
/// the frame's `regime` channel; empty if the frame has none, or no pixel a regime (contact
/// mode: no tapping branch).
pub fn branches(settings: &Settings, raster: &Raster, frame: &ImageFrame) -> Vec<RegionBranch> {
    let Some(channel) = frame.channels.iter().find(|c| c.name == "regime") else {
        return Vec::new();
    };
    if channel.data.iter().all(|v| v.is_nan()) {
        return Vec::new();
    }
    let region_of = interior_regions(settings, raster, frame.pixels);
    let regions = sample_map(settings).regions().len();
    let majority = |region: usize| -> (Option<Regime>, f64) {
        let mut counts = [0usize; 3];
        for (v, r) in channel.data.iter().zip(&region_of) {
            if *r == Some(region)
                && let Some(regime) = Regime::from_code(*v)
            {
                counts[(regime.code() + 1.0) as usize] += 1;
            }
        }
        let total: usize = counts.iter().sum();
        let (i, most) = counts
            .iter()
            .enumerate()
            .max_by_key(|(_, c)| **c)
            .expect("three counts");
        if total == 0 {
            return (None, f64::NAN);
        }
        (
            Regime::from_code(i as f64 - 1.0),
            *most as f64 / total as f64,
        )
    };
    let base = majority(0).0;
    (0..regions)
        .map(|region| {
            let (regime, share) = majority(region);
            RegionBranch {
                region,
                regime: regime.map(Regime::name),
                share,
                across_branches: region > 0 && regime.is_some() && base.is_some() && regime != base,
            }
        })
        .collect()
}

/// The report as text: the scan, then a table of channels.
pub fn render_text(r: &ScanReport) -> String {
    let mut s = format!(
        "scan: {} x {} pixels, {:.3} um square, {:.3} lines/s: {:.1} s per frame (simulated); recorded {} frame(s) in {:.1} s wall\n",
        r.pixels,
        r.pixels,
        r.size * 1e6,
        r.line_rate,
        r.frame_time,
        r.frames,
        r.wall_seconds
    );
    s += &format!(
        "overruns {} samples, pixels dropped {} (DSP) {} (topography), inversion failed on {} pixels\n\n",
        r.counters.overrun_samples,
        r.counters.pixels_dropped,
        r.counters.topography_pixels_dropped,
        r.inversion_failed
    );
    s += "channel              unit   base mean     base std      region  mean          contrast or step   CNR\n";
    for c in &r.channels {
        for reg in &c.regions {
            s += &format!(
                "{:<20} {:<5} {:>12.5e} {:>12.5e}  {:>6}  {:>12.5e} {:>17} {:>8.2}\n",
                c.name,
                c.unit,
                c.base_mean,
                c.base_std,
                reg.region,
                reg.mean,
                contrast_cell(c, reg),
                reg.cnr
            );
        }
    }
    s += &branches_text(&r.branches);
    for f in &r.files {
        s += &format!("wrote {}\n", f.display());
    }
    s
}

/// The branch of each region, and a warning for each region imaged on another branch than
/// the base: its contrasts compare two orbits.
fn branches_text(branches: &[RegionBranch]) -> String {
    if branches.is_empty() {
        return String::new();
    }
    let named = |b: &RegionBranch| match b.regime {
        Some(r) => format!("{r} ({:.0} % of its pixels)", b.share * 100.0),
        None => "unknown".to_owned(),
    };
    let list: Vec<String> = branches
        .iter()
        .map(|b| {
            let what = if b.region == 0 {
                "base".to_owned()
            } else {
                format!("region {}", b.region)
            };
            format!("{what} {}", named(b))
        })
        .collect();
    let mut s = format!("\nbranch: {}\n", list.join(", "));
    for b in branches.iter().filter(|b| b.across_branches) {
        s += &format!(
            "warning: region {} was imaged on the {} branch and the base on the {}: its contrasts compare two orbits, not two materials (an approach from farther, or another set-point, reaches one branch for both)\n",
            b.region,
            b.regime.unwrap_or("?"),
            branches[0].regime.unwrap_or("?"),
        );
    }
    s
}

/// The relative contrast, or for the height (whose zero is arbitrary: a contrast against a
/// near-zero base reads +99.8 %) the step in metres.
fn contrast_cell(channel: &ChannelReport, region: &RegionContrast) -> String {
    if channel.name == "height" {
        format!(
            "step {}",
            crate::config::quantity::quantity_rounded(region.step, "m", 3)
        )
    } else {
        format!("{:+.3} %", region.contrast * 100.0)
    }
}

/// Shows `run`'s progress on stderr: a bar with the ETA on a terminal, else a plain line
/// every [`PLAIN_PERIOD`] seconds (logs and pipes get no control characters).
struct ProgressView {
    bar: Option<indicatif::ProgressBar>,
    next_line: f64,
}

/// Seconds between two plain progress lines.
const PLAIN_PERIOD: f64 = 5.0;

impl ProgressView {
    fn new(lines_total: u64) -> Self {
        let bar = std::io::IsTerminal::is_terminal(&std::io::stderr()).then(|| {
            let bar = indicatif::ProgressBar::new(lines_total);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:40}] {pos}/{len} lines, {msg}, ETA {eta}",
                )
                .expect("a valid template")
                .progress_chars("=> "),
            );
            bar
        });
        ProgressView {
            bar,
            next_line: PLAIN_PERIOD,
        }
    }

    fn update(&mut self, p: Progress) {
        match &self.bar {
            Some(bar) => {
                bar.set_position(p.lines_done);
                bar.set_message(format!("frame {} line {}/{}", p.frame, p.line, p.lines));
            }
            None if p.wall >= self.next_line => {
                eprintln!("{}", plain_line(&p));
                self.next_line = p.wall + PLAIN_PERIOD;
            }
            None => {}
        }
    }

    fn finish(self) {
        if let Some(bar) = self.bar {
            bar.finish_and_clear();
        }
    }
}

/// A progress line for a log or a pipe: the time, the share done, where, and the time left
/// at the rate so far.
fn plain_line(p: &Progress) -> String {
    let percent = 100.0 * p.lines_done as f64 / p.lines_total.max(1) as f64;
    let eta = if p.lines_done > 0 {
        format!(
            ", about {:.0} s left",
            p.wall * p.lines_total.saturating_sub(p.lines_done) as f64 / p.lines_done as f64
        )
    } else {
        String::new()
    };
    format!(
        "[{:>5.0} s] {percent:>3.0} %: frame {}, line {}/{}{eta}",
        p.wall, p.frame, p.line, p.lines
    )
}

/// The command line.
pub fn command(
    config: &ConfigArg,
    frames: i64,
    out: Option<PathBuf>,
    realtime: bool,
    json: bool,
) -> Result<ExitCode, ExitCode> {
    if !(1..=1000).contains(&frames) {
        eprintln!("ftafm: --frames = {frames} is out of range: allowed 1 ≤ N ≤ 1000");
        return Err(ExitCode::from(EXIT_USAGE));
    }
    let mut settings = load(config)?;
    settings.synth.realtime = realtime;
    let lines = u64::try_from(frames).expect("1 ≤ frames") * u64::from(settings.scan.pixels);
    let mut view = ProgressView::new(lines);
    let report = crate::cli::scan::run(&settings, frames as usize, out.as_deref(), |p| {
        view.update(p)
    });
    view.finish();
    let report = report.map_err(|e| {
        eprintln!("ftafm: {e}");
        ExitCode::FAILURE
    })?;
    print_report(json, &report, crate::cli::scan::render_text);
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(name: &str, unit: &'static str, base_mean: f64, mean: f64) -> ChannelReport {
        ChannelReport {
            name: name.to_owned(),
            unit,
            base_mean,
            base_std: 1e-12,
            base_pixels: 100,
            regions: vec![RegionContrast {
                region: 1,
                pixels: 20,
                mean,
                std: 1e-12,
                contrast: 1.0 - base_mean / mean,
                step: mean - base_mean,
                cnr: 6.8,
            }],
        }
    }

    #[test]
    fn the_height_reports_a_step_in_metres_the_others_a_relative_contrast() {
        let report = ScanReport {
            pixels: 64,
            size: 1e-6,
            line_rate: 2.0,
            frame_time: 32.0,
            wall_seconds: 3.0,
            frames: 1,
            files: Vec::new(),
            // A base near zero: the relative contrast would read about +96 %.
            channels: vec![
                channel("height", "m", -4e-13, -1.05e-11),
                channel("h17", "m", 2.5e-11, 2.57e-11),
            ],
            branches: Vec::new(),
            inversion_failed: 0,
            counters: CountersSnapshot::default(),
        };
        let text = render_text(&report);
        let height = text.lines().find(|l| l.starts_with("height")).unwrap();
        assert!(height.contains("step -10.1 pm"), "{height}");
        assert!(!height.contains('%'), "{height}");
        let h17 = text.lines().find(|l| l.starts_with("h17")).unwrap();
        assert!(h17.contains("+2.724 %"), "{h17}");
    }

    /// A frame of the default scan whose `regime` channel holds `base` on the base material's
    /// pixels and `inclusion` elsewhere.
    fn regime_frame(base: f64, inclusion: f64) -> (Settings, Raster, ImageFrame) {
        let settings = crate::config::default_settings();
        let raster = Raster::new(
            &settings.scan,
            settings.synth.sample_rate,
            settings.drive.frequency,
            0,
            0,
        );
        let n = settings.scan.pixels;
        let data = interior_regions(&settings, &raster, n)
            .iter()
            .enumerate()
            // Every 7th pixel undecided (NaN), as where harmonic 1 was lost.
            .map(|(i, r)| match r {
                _ if i % 7 == 0 => f64::NAN,
                Some(0) => base,
                _ => inclusion,
            })
            .collect();
        let frame = ImageFrame {
            generation: 0,
            frame: 0,
            pixels: n,
            size: settings.scan.size,
            origin: (0.0, 0.0),
            channels: vec![crate::imaging::export::ImageChannel {
                name: "regime".to_owned(),
                unit: "1",
                data,
            }],
            settings: std::sync::Arc::new(settings.clone()),
        };
        (settings, raster, frame)
    }

    #[test]
    fn a_region_imaged_on_another_branch_than_the_base_is_named_and_warned() {
        let (settings, raster, frame) = regime_frame(1.0, -1.0);
        let b = branches(&settings, &raster, &frame);
        assert!(b.len() >= 2, "the default sample has inclusions: {b:?}");
        assert_eq!(b[0].regime, Some("repulsive"));
        assert_eq!(b[0].share, 1.0);
        assert!(!b[0].across_branches);
        for r in &b[1..] {
            assert_eq!(r.regime, Some("attractive"), "{r:?}");
            assert!(r.across_branches, "{r:?}");
        }
        let text = branches_text(&b);
        assert!(
            text.contains("warning: region 1 was imaged on the attractive branch and the base on the repulsive"),
            "{text}"
        );

        let (settings, raster, frame) = regime_frame(1.0, 1.0);
        let b = branches(&settings, &raster, &frame);
        assert!(
            b.iter()
                .all(|r| r.regime == Some("repulsive") && !r.across_branches)
        );
        assert!(!branches_text(&b).contains("warning"));
    }

    #[test]
    fn plain_progress_lines_say_the_share_done_and_the_time_left() {
        let p = Progress {
            line: 16,
            lines: 64,
            frame: 1,
            lines_done: 81,
            lines_total: 128,
            wall: 10.0,
        };
        assert_eq!(
            plain_line(&p),
            "[   10 s]  63 %: frame 1, line 16/64, about 6 s left"
        );
        let start = Progress { lines_done: 0, ..p };
        assert!(!plain_line(&start).contains("left"));
    }
}
