//! The raster scan as a function of the sample index: where the tip is and which pixel it is
//! in. The synthesiser, the DSP thread and the image assembler all read the same [`Raster`]
//! (it travels in every block header), so they agree on every pixel boundary to the sample.
//!
//! Conventions (docs/configuration.md, `[scan]`): square frames of `pixels` lines of
//! `pixels` pixels; each line is a trace (x increasing) then a retrace (x decreasing) at
//! constant speed; the slow axis steps one pixel per line; line 0 is at the top (largest y).

use crate::config::ScanSettings;
use crate::timebase::PREDECIMATION;

/// Longest pixel the raster makes, in samples: 2^40, 30 hours at 10 MS/s (the slowest
/// scan the settings allow lasts far less per pixel).
const MAX_PIXEL_SAMPLES: f64 = (1u64 << 40) as f64;
/// Most candidate pixel lengths tried on either side of the requested one: whole drive
/// periods recur every period / 16 candidates, so this finds them for any drive above
/// f_s / 65536 and keeps the search bounded below.
const MAX_PIXEL_SEARCH: f64 = 4096.0;

/// One pixel of the raster.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PixelId {
    /// Pixels since the raster started (trace and retrace pixels both count).
    pub serial: u64,
    /// Frame number from 0.
    pub frame: u64,
    /// Line within the frame, 0 at the top.
    pub line: u32,
    /// Column within the image, 0 at the left (the same column on trace and retrace).
    pub column: u32,
    /// Whether the pixel belongs to the retrace.
    pub retrace: bool,
}

/// A raster started at a given sample. `Copy`, so it rides in block headers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Raster {
    /// Sample index at which frame 0, line 0, pixel 0 of the trace begins.
    pub start: u64,
    /// Samples per pixel: a multiple of the lock-in's pre-decimation, so pixel boundaries
    /// fall on its decimated samples.
    pub samples_per_pixel: u64,
    /// Pixels per line and lines per frame.
    pub pixels: u32,
    /// Side of the scan area (m).
    pub size: f64,
    /// Centre of the scan area in sample coordinates (m).
    pub centre: (f64, f64),
    /// Counts the rasters started since the daemon began, so consumers can tell a restarted
    /// scan from the one before.
    pub generation: u32,
}

impl Raster {
    /// The raster of `scan` at `sample_rate` (Hz) for a drive at `drive_frequency` (Hz),
    /// starting at sample `start`. A pixel lasts a multiple of the pre-decimation within 2 %
    /// of the requested time, chosen to hold as nearly as possible a whole number of drive
    /// periods (exactly, when the period is a whole number of samples): the boxcar then
    /// rejects the other harmonics, the large fundamental above all, completely.
    pub fn new(
        scan: &ScanSettings,
        sample_rate: f64,
        drive_frequency: f64,
        start: u64,
        generation: u32,
    ) -> Self {
        let d = PREDECIMATION as f64;
        // Clamped (a NaN too) so that what follows stays finite and the search short,
        // whatever the settings: this runs on the synthesiser's thread.
        let exact = (sample_rate / (2.0 * f64::from(scan.pixels) * scan.line_rate))
            .clamp(d, MAX_PIXEL_SAMPLES);
        let period = sample_rate / drive_frequency;
        let nearest = (exact / d).round().max(1.0);
        let spread = (0.02 * exact / d).floor().min(MAX_PIXEL_SEARCH);
        let misfit = |k: f64| {
            let periods = k * d / period;
            (periods - periods.round()).abs()
        };
        let mut best = nearest;
        let mut k = (nearest - spread).max(1.0);
        while k <= nearest + spread {
            // Prefer whole periods, then closeness to the requested time.
            if misfit(k) < misfit(best) - 1e-9
                || (misfit(k) <= misfit(best) + 1e-9
                    && (k - nearest).abs() < (best - nearest).abs())
            {
                best = k;
            }
            k += 1.0;
        }
        let samples_per_pixel = (best * d) as u64;
        Self {
            start,
            samples_per_pixel,
            pixels: scan.pixels,
            size: scan.size,
            centre: (scan.x, scan.y),
            generation,
        }
    }

    /// Lines per second as realised (samples per pixel are rounded to the pre-decimation).
    pub fn line_rate(&self, sample_rate: f64) -> f64 {
        sample_rate / (2 * u64::from(self.pixels) * self.samples_per_pixel) as f64
    }

    /// Duration of one frame (s).
    pub fn frame_time(&self, sample_rate: f64) -> f64 {
        f64::from(self.pixels) / self.line_rate(sample_rate)
    }

    /// Pixel side (m).
    pub fn pixel_size(&self) -> f64 {
        self.size / f64::from(self.pixels)
    }

    /// The pixel with this serial number.
    pub fn pixel(&self, serial: u64) -> PixelId {
        let p = u64::from(self.pixels);
        let per_line = 2 * p;
        let per_frame = per_line * p;
        let frame = serial / per_frame;
        let in_frame = serial % per_frame;
        let line = (in_frame / per_line) as u32;
        let along = in_frame % per_line;
        let retrace = along >= p;
        let column = if retrace { per_line - 1 - along } else { along } as u32;
        PixelId {
            serial,
            frame,
            line,
            column,
            retrace,
        }
    }

    /// The pixel the tip is in at sample `index`, `None` before the raster starts.
    pub fn pixel_at(&self, index: u64) -> Option<PixelId> {
        let offset = index.checked_sub(self.start)?;
        Some(self.pixel(offset / self.samples_per_pixel))
    }

    /// First sample index of pixel `serial`.
    pub fn pixel_start(&self, serial: u64) -> u64 {
        self.start + serial * self.samples_per_pixel
    }

    /// Tip position (x, y) in sample coordinates (m) at sample `index`: continuous along
    /// the fast axis, one pixel row per line on the slow axis. Before the start: the start.
    pub fn position(&self, index: u64) -> (f64, f64) {
        let offset = index.saturating_sub(self.start);
        let p = u64::from(self.pixels);
        let line_samples = 2 * p * self.samples_per_pixel;
        let trace_samples = p * self.samples_per_pixel;
        let line = (offset / line_samples) % p;
        let along = offset % line_samples;
        // Fraction of the width from the left edge.
        let u = if along < trace_samples {
            along as f64 / trace_samples as f64
        } else {
            (line_samples - along) as f64 / trace_samples as f64
        };
        let half = 0.5 * self.size;
        let x = self.centre.0 - half + u * self.size;
        let y = self.centre.1 + half - (line as f64 + 0.5) * self.pixel_size();
        (x, y)
    }

    /// Centre (x, y) of image pixel (`column`, `line`) in sample coordinates (m).
    pub fn pixel_centre(&self, column: u32, line: u32) -> (f64, f64) {
        let half = 0.5 * self.size;
        let s = self.pixel_size();
        (
            self.centre.0 - half + (f64::from(column) + 0.5) * s,
            self.centre.1 + half - (f64::from(line) + 0.5) * s,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raster() -> Raster {
        let scan = ScanSettings {
            enable: true,
            size: 1e-6,
            pixels: 4,
            line_rate: 1e6 / (2.0 * 4.0 * 160.0),
            x: 1e-6,
            y: 0.0,
        };
        Raster::new(&scan, 1e6, 1e6 / 32.0, 1000, 1)
    }

    #[test]
    fn pixels_hold_whole_drive_periods_when_they_can() {
        let scan = ScanSettings {
            enable: true,
            size: 1e-6,
            pixels: 128,
            line_rate: 2.0,
            x: 0.0,
            y: 0.0,
        };
        // 100 samples per period: 19 531 requested, 19 600 = 196 periods (1225 × 16).
        let r = Raster::new(&scan, 10e6, 100e3, 0, 1);
        assert_eq!(r.samples_per_pixel, 19_600);
        assert!((r.line_rate(10e6) - 1.993).abs() < 1e-3);
        // A period of 97.3 samples: whole periods are out of reach; within 2 % of the time.
        let r = Raster::new(&scan, 9.73e6, 100e3, 0, 1);
        assert_eq!(r.samples_per_pixel % 16, 0);
        let requested = 9.73e6 / (2.0 * 128.0 * 2.0);
        assert!((r.samples_per_pixel as f64 / requested - 1.0).abs() < 0.02);
        let periods = r.samples_per_pixel as f64 / 97.3;
        assert!((periods - periods.round()).abs() < 0.05, "{periods}");
    }

    /// Rates down to 5e-324 Hz (and a drive of 5e-324 Hz) give a raster at once, with
    /// pixels no longer than the longest and no shorter than one decimated sample.
    #[test]
    fn extreme_rates_give_a_bounded_raster_at_once() {
        for (line_rate, drive) in [(5e-324, 100e3), (1e-13, 100e3), (1e-3, 5e-324), (1e9, 1e8)] {
            let scan = ScanSettings {
                enable: true,
                size: 1e-6,
                pixels: 8,
                line_rate,
                x: 0.0,
                y: 0.0,
            };
            let r = Raster::new(&scan, 1e9, drive, 0, 1);
            assert!(r.samples_per_pixel >= 16, "{line_rate}");
            assert!(
                r.samples_per_pixel as f64 <= MAX_PIXEL_SAMPLES * 1.03,
                "{line_rate}"
            );
            assert!(r.pixel_at(u64::MAX / 2).is_some());
        }
    }

    #[test]
    fn pixels_run_trace_then_retrace_line_by_line() {
        let r = raster();
        assert_eq!(r.samples_per_pixel, 160);
        assert!(r.pixel_at(999).is_none());
        let ids: Vec<(u32, u32, bool)> = (0..10)
            .map(|s| {
                let p = r.pixel_at(1000 + s * 160 + 5).unwrap();
                (p.line, p.column, p.retrace)
            })
            .collect();
        assert_eq!(
            ids,
            [
                (0, 0, false),
                (0, 1, false),
                (0, 2, false),
                (0, 3, false),
                (0, 3, true),
                (0, 2, true),
                (0, 1, true),
                (0, 0, true),
                (1, 0, false),
                (1, 1, false)
            ]
        );
        let next_frame = r.pixel_at(1000 + 32 * 160).unwrap();
        assert_eq!(
            (next_frame.frame, next_frame.line, next_frame.column),
            (1, 0, 0)
        );
        assert_eq!(r.pixel_start(3), 1000 + 480);
    }

    #[test]
    fn the_tip_moves_continuously_and_pixel_centres_match_the_path() {
        let r = raster();
        // Left edge at the start, right edge at the end of the trace, back at the end.
        let (x0, y0) = r.position(1000);
        assert!((x0 - 0.5e-6).abs() < 1e-15 && (y0 - 0.375e-6).abs() < 1e-15);
        let (x1, _) = r.position(1000 + 4 * 160);
        assert!((x1 - 1.5e-6).abs() < 1e-15);
        let (x2, y2) = r.position(1000 + 8 * 160 - 1);
        assert!((x2 - 0.5e-6).abs() < 2e-9 && (y2 - 0.375e-6).abs() < 1e-15);
        // The middle of trace pixel 2 and of retrace pixel 2 are its centre.
        let (cx, cy) = r.pixel_centre(2, 0);
        let (tx, _) = r.position(1000 + 2 * 160 + 80);
        let (rx, _) = r.position(1000 + 5 * 160 + 80);
        assert!(
            (tx - cx).abs() < 1e-15 && (rx - cx).abs() < 1e-15,
            "{tx} {rx} {cx}"
        );
        assert!((cy - 0.375e-6).abs() < 1e-15);
        // Line 3 is the bottom row.
        let (_, y3) = r.position(1000 + 3 * 8 * 160);
        assert!((y3 + 0.375e-6).abs() < 1e-15);
    }
}
