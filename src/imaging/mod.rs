//! Scan images: joins the synthesiser's per-pixel topography and the DSP's per-pixel
//! harmonics into image lines and frames, with the FT-AFM channels (contact time, peak force,
//! modulus per pixel, by the live inversion's estimator), and writes them as files
//! ([`export`]). Used by the daemon's `image` stream and by `ftafm scan`.

pub mod export;

use std::collections::{BTreeMap, VecDeque};

pub use export::ImageChannel;

use rustfft::num_complex::Complex64;

use crate::config::{PidInput, PidTarget, Settings};
use crate::instrument::bimodal::BimodalSetup;
use crate::inversion::ForceEstimator;
use crate::pipeline::PixelHarmonics;
use crate::synth::{PixelTopography, Raster};
use crate::timebase::PREDECIMATION;

/// One finished trace line, as the `image` stream sends it.
#[derive(Clone, Debug)]
pub struct ImageLine {
    /// Simulated time of the line's last sample (s).
    pub t: f64,
    /// Unix time (ns) at which that sample was synthesised.
    pub t_synth_ns: u64,
    /// Raster generation (a new one: a new image).
    pub generation: u32,
    /// Frame number within the generation.
    pub frame: u64,
    /// Line, 0 at the top.
    pub line: u32,
    /// Pixels per line (and lines per frame).
    pub pixels: u32,
    /// Side of the scan area (m).
    pub size: f64,
    /// Lines per second as realised (Hz).
    pub line_rate: f64,
    /// Channel name, unit, values (NaN: missing).
    pub channels: Vec<(String, &'static str, Vec<f64>)>,
    /// The settings epoch the assembler (its FT-AFM estimator) was configured for (set by
    /// the daemon; 0 offline).
    pub epoch: u64,
    /// True when newer settings wait to be taken up: the line's FT-AFM channels come from
    /// the old settings' estimator (set by the daemon).
    pub stale: bool,
}

/// A finished frame, every channel.
#[derive(Clone, Debug)]
pub struct ImageFrame {
    pub generation: u32,
    pub frame: u64,
    pub pixels: u32,
    pub size: f64,
    /// Lower-left corner of the scan area (m), for the file's offsets.
    pub origin: (f64, f64),
    pub channels: Vec<ImageChannel>,
    /// The instrument's settings when the frame finished (the files' metadata).
    pub settings: std::sync::Arc<Settings>,
}

/// The frame being filled.
struct Frame {
    /// The raster its pixels come from: generation and geometry.
    raster: Raster,
    frame: u64,
    /// Per channel: name, unit, pixels² values.
    channels: Vec<(String, &'static str, Vec<f64>)>,
    lines_done: u32,
    /// The line being filled, its last time stamps.
    open_line: Option<u32>,
    t: f64,
    t_synth_ns: u64,
}

/// Builds lines and frames from pixels (topography first, then harmonics, per pixel). Each
/// pixel is placed by the geometry of its own raster, which it carries, so pixels in flight
/// across a change of `/scan/...` land in the image they were scanned for.
pub struct Assembler {
    /// Pixels per line of the configured scan: sizes the bounds of the waiting queues.
    pixels: u32,
    /// The most topographies kept waiting for their harmonics.
    topography_bound: usize,
    sample_rate: f64,
    estimator: Option<ForceEstimator>,
    /// The settings `estimator` was built for.
    estimator_settings: Option<Settings>,
    topography: BTreeMap<(u32, u64), PixelTopography>,
    /// Newest topography key seen.
    latest_topography: Option<(u32, u64)>,
    /// Harmonics waiting for their pixel's topography: the synthesiser closes a pixel's
    /// feedback average at the end of the drive period that straddles the pixel's end, which
    /// can come after the DSP has handed out the pixel's harmonics.
    pending: VecDeque<PixelHarmonics>,
    /// The settings in force, for the finished frames' metadata.
    settings: std::sync::Arc<Settings>,
    /// The free lever's reading at the settings in force: the reference of each pixel's
    /// regime (`crate::sweep::regime`).
    free: Option<crate::sweep::ApproachPoint>,
    current: Option<Frame>,
    finished: Option<ImageFrame>,
    /// The bimodal expressions' calibration, while the second excitation drives and mode
    /// 2's PLL runs (else no bimodal channels but Δf₂).
    bimodal: Option<BimodalSetup>,
    /// Pixels whose inversion failed (their FT-AFM channels are NaN).
    pub inversion_failed: u64,
    /// Pixels outside their own raster (none are expected), dropped.
    pub misplaced: u64,
}

impl Assembler {
    /// An assembler for the scan of `settings`.
    pub fn new(settings: &Settings) -> Self {
        let mut a = Self {
            pixels: 0,
            topography_bound: 0,
            sample_rate: 0.0,
            estimator: None,
            estimator_settings: None,
            topography: BTreeMap::new(),
            latest_topography: None,
            pending: VecDeque::new(),
            settings: std::sync::Arc::new(settings.clone()),
            free: None,
            current: None,
            finished: None,
            bimodal: None,
            inversion_failed: 0,
            misplaced: 0,
        };
        a.configure(settings);
        a
    }

    /// Follows new settings (the estimator, the frames' metadata, the queues' bounds).
    pub fn configure(&mut self, settings: &Settings) {
        self.pixels = settings.scan.pixels;
        self.sample_rate = settings.synth.sample_rate;
        // The synthesiser hands a pixel's topography out as much as the sample ring's
        // length before the DSP hands out its harmonics (more than a frame of a small,
        // fast scan), and a consumer short of CPU may take the harmonics as much as their
        // queue later still: two frames, twice the pixels the ring holds and the queue.
        let raster = Raster::new(
            &settings.scan,
            self.sample_rate,
            settings.drive.frequency,
            0,
            0,
        );
        let in_ring = crate::pipeline::ring_samples(self.sample_rate) as u64
            / raster.samples_per_pixel.max(1);
        self.topography_bound = 4 * (self.pixels.max(8) as usize).pow(2)
            + 2 * in_ring as usize
            + crate::pipeline::PIXEL_QUEUE;
        self.settings = std::sync::Arc::new(settings.clone());
        // In contact mode (a unit on the mean deflection holds the surface) the lever is
        // pressed on the sample, not tapping: no pixel is on a tapping branch.
        let contact = !settings.feedback.enable
            && settings.pids.iter().any(|p| {
                p.enable
                    && p.input == PidInput::MeanDeflection
                    && p.output == PidTarget::SurfaceDistance
            });
        self.free = if contact {
            None
        } else {
            crate::sweep::free_point(settings)
        };
        self.bimodal = (settings.scan.enable && settings.drive2.enable)
            .then(|| BimodalSetup::of(settings).ok())
            .flatten();
        // One estimate per pixel, whatever the live stream averages.
        let mut s = settings.clone();
        s.inversion.averaging = 1;
        // No scan, no pixels to invert: the estimator is built when a scan starts (else every
        // point of a sweep would cost a second build beside the force stream's). Pixels still
        // on their way from a scan just stopped were made under the settings the estimator
        // was built for.
        if !settings.scan.enable {
            return;
        }
        // A change of the scan or the sample keeps the estimator (a coupled engine's table
        // takes seconds to build) unless a modulus moved out of its table's dense nodes.
        if self
            .estimator_settings
            .as_ref()
            .is_none_or(|built| !ForceEstimator::covers(built, &s))
        {
            let seed = self.estimator.as_ref().and_then(ForceEstimator::seed);
            self.estimator = ForceEstimator::seeded(&s, seed).ok().flatten();
            self.estimator_settings = Some(s);
        }
    }

    /// Takes a pixel's topography.
    pub fn topography(&mut self, t: PixelTopography) {
        let key = (t.generation, t.pixel.serial);
        self.latest_topography = self.latest_topography.max(Some(key));
        self.topography.insert(key, t);
        // Its harmonics come later (the DSP runs behind the synthesiser, and its consumer
        // may lag further); entries are removed as the harmonics pass them. A bound for a
        // consumer that never takes harmonics.
        while self.topography.len() > self.topography_bound {
            self.topography.pop_first();
        }
    }

    /// Takes a pixel; returns the line it finishes, if any.
    /// Takes a pixel's harmonics; returns the lines finished by it or by pixels that were
    /// waiting for their topography (usually none or one).
    pub fn pixel(&mut self, p: &PixelHarmonics) -> Vec<ImageLine> {
        self.pending.push_back(*p);
        let mut lines = Vec::new();
        while let Some(front) = self.pending.front() {
            let key = (front.raster.generation, front.pixel.serial);
            let ready = self.topography.contains_key(&key)
                || self.latest_topography.is_some_and(|k| k > key)
                // Topography stopped coming (dropped, or a scan without it): go on.
                || self.pending.len() > 2 * self.pixels.max(8) as usize;
            if !ready {
                break;
            }
            let front = self.pending.pop_front().expect("front exists");
            lines.extend(self.place(&front));
        }
        lines
    }

    /// Puts one pixel into the frame; returns the line it finishes, if any.
    fn place(&mut self, p: &PixelHarmonics) -> Option<ImageLine> {
        let id = p.pixel;
        let raster = p.raster;
        // This pixel's topography, and none older: those pixels' harmonics were lost.
        let mut rest = self.topography.split_off(&(raster.generation, id.serial));
        let topo = rest.remove(&(raster.generation, id.serial));
        self.topography = rest;
        if id.retrace {
            return None;
        }
        if id.line >= raster.pixels || id.column >= raster.pixels {
            self.misplaced += 1;
            return None;
        }
        let n = raster.pixels as usize;
        // A new raster is a new image, even where it kept the generation's frame number.
        let fresh = self
            .current
            .as_ref()
            .is_none_or(|f| f.raster != raster || f.frame != id.frame);
        if fresh {
            self.current = Some(Frame {
                raster,
                frame: id.frame,
                channels: Vec::new(),
                lines_done: 0,
                open_line: None,
                t: 0.0,
                t_synth_ns: 0,
            });
        }
        let mut values: Vec<(String, &'static str, f64)> = Vec::with_capacity(40);
        values.push(("height".into(), "m", topo.map_or(f64::NAN, |t| t.height)));
        // The channels are the tapping's: values on /drive2 are no harmonics of it.
        let on_drive = || p.frame.values().iter().filter(|v| v.on_drive());
        let fundamental = on_drive().find(|v| v.harmonic == 1);
        values.push((
            "amplitude".into(),
            "m",
            fundamental.map_or(f64::NAN, |v| v.r()),
        ));
        values.push((
            "phase".into(),
            "rad",
            fundamental.map_or(f64::NAN, |v| v.phase()),
        ));
        // The branch the tip is on at this pixel, as an approach names it: where an
        // attractive and a repulsive orbit coexist, the feedback can hold the set-point on
        // either, and a contrast between pixels on two branches compares two orbits.
        let regime = fundamental.zip(self.free).map_or(f64::NAN, |(h1, free)| {
            let point = crate::sweep::ApproachPoint {
                r: h1.r(),
                phase: crate::sweep::phase_to_drive(h1.phase()),
                mean: on_drive().find(|v| v.harmonic == 0).map(|v| v.x),
            };
            crate::sweep::regime(
                point,
                free,
                crate::sweep::FREE_DROP,
                crate::sweep::FREE_TWIST,
                crate::sweep::MEAN_FLOOR,
            )
            .code()
        });
        values.push(("regime".into(), "1", regime));
        let mut harmonics: Vec<_> = on_drive().filter(|v| v.harmonic >= 2).collect();
        harmonics.sort_by_key(|v| v.harmonic);
        harmonics.dedup_by_key(|v| v.harmonic);
        for v in harmonics {
            values.push((format!("h{}", v.harmonic), "m", v.r()));
        }
        if let Some(e) = &self.estimator {
            // The boxcar over the pixel's decimated samples: bandwidth 1/(2T).
            let bandwidth =
                self.sample_rate / (2.0 * PREDECIMATION as f64 * f64::from(p.samples.max(1)));
            let (tau, force, modulus) = match e.estimate_frame(&p.frame, bandwidth) {
                Ok(est) => (est.contact_time_ratio, est.max_force, est.youngs_modulus),
                Err(_) => {
                    self.inversion_failed += 1;
                    (f64::NAN, f64::NAN, f64::NAN)
                }
            };
            values.push(("contact_time_ratio".into(), "1", tau));
            values.push(("max_force".into(), "N", force));
            values.push(("youngs_modulus".into(), "Pa", modulus));
        }
        // Bimodal AM-FM: mode 2's frequency over the pixel against the free resonance, and
        // the bimodal expressions on it with mode 1's phasor.
        if let Some(f2) = topo.and_then(|t| t.frequency2) {
            let shift = f2 - self.settings.drive2.frequency;
            values.push(("frequency_shift2".into(), "Hz", shift));
            if let Some(setup) = &self.bimodal {
                let values_of = fundamental
                    .map(|h1| setup.reading(Complex64::new(h1.x, h1.y), f2))
                    .and_then(|reading| setup.values(&reading).ok());
                values.push((
                    "indentation".into(),
                    "m",
                    values_of.map_or(f64::NAN, |v| v.estimate.indentation),
                ));
                values.push((
                    "bimodal_modulus".into(),
                    "Pa",
                    values_of.and_then(|v| v.youngs_modulus).unwrap_or(f64::NAN),
                ));
            }
        }

        let frame = self.current.as_mut().expect("a frame is open");
        let mut finished = None;
        if frame.open_line.is_some_and(|l| l != id.line) {
            // The previous line lost its last pixels: send what it has.
            finished = frame.open_line.take();
        }
        for (name, unit, value) in values {
            let slot = match frame.channels.iter().position(|(n, _, _)| *n == name) {
                Some(i) => i,
                None => {
                    frame.channels.push((name, unit, vec![f64::NAN; n * n]));
                    frame.channels.len() - 1
                }
            };
            let index = id.line as usize * n + id.column as usize;
            if let Some(cell) = frame.channels[slot].2.get_mut(index) {
                *cell = value;
            }
        }
        frame.open_line = Some(id.line);
        frame.t = p.frame.t;
        frame.t_synth_ns = p.frame.t_synth_ns;
        if id.column + 1 == raster.pixels {
            finished = frame.open_line.take();
        }
        let line = finished?;
        let out = ImageLine {
            t: frame.t,
            t_synth_ns: frame.t_synth_ns,
            generation: raster.generation,
            frame: frame.frame,
            line,
            pixels: raster.pixels,
            size: raster.size,
            line_rate: raster.line_rate(self.sample_rate),
            epoch: 0,
            stale: false,
            channels: frame
                .channels
                .iter()
                .map(|(name, unit, data)| {
                    (
                        name.clone(),
                        *unit,
                        data[line as usize * n..(line as usize + 1) * n].to_vec(),
                    )
                })
                .collect(),
        };
        frame.lines_done += 1;
        if line + 1 == raster.pixels {
            let done = ImageFrame {
                generation: raster.generation,
                frame: frame.frame,
                pixels: raster.pixels,
                size: raster.size,
                origin: (
                    raster.centre.0 - 0.5 * raster.size,
                    raster.centre.1 - 0.5 * raster.size,
                ),
                settings: self.settings.clone(),
                channels: frame
                    .channels
                    .iter()
                    .map(|(name, unit, data)| ImageChannel {
                        name: name.clone(),
                        unit,
                        data: data.clone(),
                    })
                    .collect(),
            };
            self.finished = Some(done);
        }
        Some(out)
    }
}

impl Assembler {
    /// The frame the last line finished, once.
    pub fn take_finished(&mut self) -> Option<ImageFrame> {
        self.finished.take()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::DemodFrame;

    /// Every pixel of one frame of `raster`: its topography and its harmonics (H1 only,
    /// its amplitude the pixel's serial).
    fn frame_of(raster: Raster) -> Vec<(PixelTopography, PixelHarmonics)> {
        let per_frame = 2 * u64::from(raster.pixels).pow(2);
        (0..per_frame)
            .map(|serial| {
                let pixel = raster.pixel(serial);
                let mut frame = DemodFrame::empty();
                frame.values[0].harmonic = 1;
                frame.values[0].x = serial as f64;
                frame.len = 1;
                (
                    PixelTopography {
                        generation: raster.generation,
                        pixel,
                        height: 0.0,
                        amplitude: 0.0,
                        frequency2: None,
                        periods: 10,
                    },
                    PixelHarmonics {
                        raster,
                        pixel,
                        samples: 4,
                        frame,
                    },
                )
            })
            .collect()
    }

    #[test]
    fn pixels_are_placed_by_their_own_raster_not_by_settings_that_lag() {
        // The assembler still has the 128-pixel settings when a 16-pixel raster's pixels
        // arrive (the settings reach its thread on another path): before, they were put
        // into a 128-pixel frame and no line of them ever finished.
        let mut settings = crate::config::default_settings();
        settings.scan.enable = true;
        let mut assembler = Assembler::new(&settings);
        settings.scan.pixels = 16;
        let raster = Raster::new(&settings.scan, 10e6, 100e3, 0, 2);
        assert_eq!(raster.pixels, 16);
        let mut lines = Vec::new();
        for (topography, harmonics) in frame_of(raster) {
            assembler.topography(topography);
            lines.extend(assembler.pixel(&harmonics));
        }
        assert_eq!(lines.len(), 16);
        for (i, line) in lines.iter().enumerate() {
            assert_eq!((line.line, line.pixels, line.generation), (i as u32, 16, 2));
            assert_eq!(line.line_rate, raster.line_rate(10e6));
            let amplitude = &line.channels.iter().find(|c| c.0 == "amplitude").unwrap().2;
            // Trace pixels of line i are serials 32·i … 32·i + 15.
            let want: Vec<f64> = (0..16).map(|c| (32 * i + c) as f64).collect();
            assert_eq!(amplitude, &want);
        }
        let frame = assembler.take_finished().expect("the frame finished");
        assert_eq!((frame.pixels, frame.generation), (16, 2));
        assert_eq!(assembler.misplaced, 0);
    }

    /// The synthesiser hands topography out up to the sample ring's length ahead of the
    /// harmonics, and a consumer short of CPU takes the harmonics up to their queue later:
    /// for a small, fast scan that is many frames (here 8 × 8 pixels of 0.2 ms, 25.6 ms a
    /// frame, against the ring's 0.5 s and the queue's 32768 pixels), and every pixel still
    /// finds its height.
    #[test]
    fn topography_a_ring_ahead_of_the_harmonics_is_kept() {
        let mut settings = crate::config::default_settings();
        settings.scan.enable = true;
        settings.scan.pixels = 8;
        settings.scan.line_rate = 1.0 / (2.0 * 8.0 * 0.2e-3);
        let fs = settings.synth.sample_rate;
        let raster = Raster::new(&settings.scan, fs, settings.drive.frequency, 0, 1);
        let mut assembler = Assembler::new(&settings);
        let ahead = crate::pipeline::ring_samples(fs) as u64 / raster.samples_per_pixel;
        assert!(ahead > 10 * 2 * 64, "the ring holds {ahead} pixels");
        let frame = frame_of(raster);
        for (topography, _) in &frame {
            assembler.topography(*topography);
        }
        for serial in frame.len() as u64..ahead + crate::pipeline::PIXEL_QUEUE as u64 {
            assembler.topography(PixelTopography {
                generation: raster.generation,
                pixel: raster.pixel(serial),
                periods: 10,
                ..PixelTopography::default()
            });
        }
        let mut lines = Vec::new();
        for (_, harmonics) in &frame {
            lines.extend(assembler.pixel(harmonics));
        }
        assert_eq!(lines.len(), 8);
        for line in &lines {
            let height = &line.channels.iter().find(|c| c.0 == "height").unwrap().2;
            assert!(
                height.iter().all(|h| h.is_finite()),
                "line {}: {height:?}",
                line.line
            );
        }
    }
}
