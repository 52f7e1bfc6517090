//! The DSP thread: takes blocks from the sample ring, finishes their samples (the ADC's
//! FIRs, detector noise and quantiser), keeps the lock-in's reference locked to the
//! synthesiser's drive phase, and emits demodulator and spectrum frames.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use ringbuf::traits::{Consumer, Observer, Producer};
use ringbuf::{HeapCons, HeapProd};

use super::block::{BlockHeader, unix_ns};
use super::counters::{Counters, monotonic_ns};
use super::dsp_plan::{DspPlan, DspSink};
use super::dsp_team::DspTeam;
use super::frames::{DemodFrame, DemodValue, PixelHarmonics, ScopeBuffer, SpectrumBuffer};
use crate::config::Oscillator;
use crate::synth::noise_pages::PageFactory;
use crate::synth::{Digitiser, WindowSample};

/// Longest the DSP thread sleeps when the ring is empty. The synthesiser wakes it as each
/// block lands, so this only bounds how late it notices a stop or a new plan.
const IDLE: Duration = Duration::from_millis(1);

/// Samples waiting in the ring above which this thread is behind and leaves the noise
/// deviates to the synthesiser: two blocks.
const NOISE_BACKLOG: usize = 2 * super::BLOCK_SAMPLES;

pub(crate) struct DspWorker {
    pub plan: Box<DspPlan>,
    /// The signal through the ADC's window, finished here ([`Digitiser`]).
    pub samples: HeapCons<WindowSample>,
    /// The ADC's FIRs, detector noise and quantiser.
    pub digitiser: Digitiser,
    /// The block's samples, finished.
    pub finished: Vec<f64>,
    pub headers: HeapCons<BlockHeader>,
    /// Changes of the lock-in's reference, `header.references` of them per block.
    pub references: HeapCons<crate::synth::ReferenceChange>,
    pub plans_in: HeapCons<Box<DspPlan>>,
    pub plans_out: HeapProd<Box<DspPlan>>,
    pub demods: HeapProd<DemodFrame>,
    pub spectra: HeapProd<SpectrumBuffer>,
    pub free_spectra: HeapCons<SpectrumBuffer>,
    pub counters: Arc<Counters>,
    pub stop: Arc<AtomicBool>,
    /// A spectrum buffer the consumer's queue refused, kept for the next frame so it is
    /// never freed here. (With the queue as long as the pool this cannot happen today; the
    /// slot keeps it true whatever the two sizes become.)
    pub spare: Option<SpectrumBuffer>,
    pub scopes: HeapProd<ScopeBuffer>,
    pub free_scopes: HeapCons<ScopeBuffer>,
    /// The scope trace being filled.
    pub scope_current: Option<ScopeBuffer>,
    /// A scope buffer not in use (a trace abandoned at a gap), used before the pool.
    pub scope_spare: Option<ScopeBuffer>,
    /// Scan pixels' harmonics, to the consumer.
    pub pixels: HeapProd<PixelHarmonics>,
    /// The pixel whose boxcar is being integrated: (raster generation, serial).
    pub pixel_open: Option<(u32, u64)>,
    /// The pixel that should open next, after the last one opened: a later one means the
    /// ones between were skipped by a gap in the stream, and are counted as dropped.
    pub pixel_next: Option<(u32, u64)>,
    /// Holds this thread idle while set (a fault to inject: see [`super::Pipeline::hold_dsp`]).
    pub hold: Arc<AtomicBool>,
    /// Scratch for a pixel's values.
    pub pixel_frame: DemodFrame,
    /// Wakes the consumer after a block that produced demodulator frames.
    pub signal: Option<Arc<super::FrameSignal>>,
    /// A plan taken from the queue whose epoch has not reached the stream yet: it is taken
    /// up with the first block of its epoch, where the synthesis changed too.
    pub pending: Option<Box<DspPlan>>,
    /// Where each plan was taken up, for the control side.
    pub epochs: Arc<super::Epochs>,
    /// Worker threads for the lock-in bank's shards; stopped and joined with this thread.
    pub team: DspTeam,
    /// Draws the synthesiser's pages of noise deviates ahead while this thread waits for
    /// blocks, which balances the two threads' work.
    pub noise: PageFactory,
}

/// Stream samples `lo..hi` of a block held in the ring as two slices.
fn slice_range<'a>(first: &'a [f64], second: &'a [f64], lo: usize, hi: usize) -> [&'a [f64]; 2] {
    let split = first.len();
    let a = &first[lo.min(split)..hi.min(split)];
    let b = &second[lo.saturating_sub(split)..hi.saturating_sub(split)];
    [a, b]
}

/// Pixels lost when pixel `key` (generation, serial) opens: the one still open, if it is of
/// the same raster (its end never came), and those between the one expected next and `key`
/// (a gap skipped them whole). A new raster's pixels continue nothing.
fn pixels_lost(open: Option<(u32, u64)>, next: Option<(u32, u64)>, key: (u32, u64)) -> u64 {
    let abandoned = u64::from(open.is_some_and(|(generation, _)| generation == key.0));
    let skipped = match next {
        Some((generation, serial)) if generation == key.0 => key.1.saturating_sub(serial),
        _ => 0,
    };
    abandoned + skipped
}

impl DspWorker {
    pub fn run(mut self) {
        let mut expected: Option<u64> = None;
        loop {
            if self.stop.load(Ordering::Relaxed) {
                // What is left is reported, not processed: the caller asked to stop.
                self.counters
                    .ring_fill
                    .store(self.samples.occupied_len() as u64, Ordering::Relaxed);
                return;
            }
            if self.hold.load(Ordering::Relaxed) || super::HOLD_ALL_DSP.load(Ordering::Relaxed) {
                std::thread::park_timeout(IDLE);
                continue;
            }
            let Some(header) = self.headers.try_pop() else {
                // Nothing to process: draw the synthesiser's next page of deviates, if it
                // needs one, else sleep until a block lands.
                if !self.draw_noise() {
                    std::thread::park_timeout(IDLE);
                }
                continue;
            };
            // Plans of this block's epoch (or earlier) take over from this block on. The
            // header was pushed after its epoch's plans were queued, so they are visible.
            let continuous = expected == Some(header.index);
            loop {
                if self.pending.is_none() {
                    self.pending = self.plans_in.try_pop();
                }
                match self.pending.take() {
                    Some(mut next) if next.epoch <= header.epoch => {
                        self.epochs.dsp_took_up(next.epoch, header.index);
                        // Only a continuous stream may carry the filters' state over.
                        if continuous {
                            next.inherit_bank(&mut self.plan);
                        }
                        let old = std::mem::replace(&mut self.plan, next);
                        // The control side keeps plans in flight (this pending one
                        // included) below the return queue's capacity.
                        let _ = self.plans_out.try_push(old);
                        // A new bank starts with this block.
                        expected = None;
                        Counters::add(&self.counters.dsp_plans_applied, 1);
                    }
                    later => {
                        self.pending = later;
                        break;
                    }
                }
            }
            let fill = self.samples.occupied_len() as u64;
            self.counters.ring_fill.store(fill, Ordering::Relaxed);
            self.counters
                .ring_fill_max
                .fetch_max(fill, Ordering::Relaxed);
            let restart = match expected {
                Some(index) if index != header.index => {
                    Counters::add(&self.counters.discontinuities, 1);
                    true
                }
                None => true,
                _ => false,
            };
            if restart {
                self.plan.restart(header.index);
                // A partial trace must not straddle the gap.
                if let Some(partial) = self.scope_current.take() {
                    self.scope_spare = Some(partial);
                }
            }
            let busy = Instant::now();
            let frames_before = self.counters.demod_frames.load(Ordering::Relaxed);
            self.plan.align(header.phase, header.frequency_word);
            // The second excitation's demodulators, from the header as the drive's; a
            // loop's reference changes below move either.
            self.plan
                .align_drive2(header.phase2, header.frequency_word2);
            let len = header.len as usize;
            let mut finished = std::mem::take(&mut self.finished);
            {
                let (a, b) = self.samples.as_slices();
                let first = len.min(a.len());
                let (a, b) = (&a[..first], &b[..len - first]);
                let out = &mut finished[..len];
                match &header.digitise {
                    Some(input) => {
                        let clipped = self.digitiser.finish(input, header.index, [a, b], out);
                        Counters::add(&self.counters.clipped_samples, clipped);
                    }
                    None => {
                        for (o, w) in out.iter_mut().zip(a.iter().chain(b)) {
                            *o = w.grid;
                        }
                    }
                }
            }
            // The ring's room is free again before the rest of the block's work.
            self.samples.skip(len);
            let (first, second) = (&finished[..len], &[][..]);
            let mut emit = Emitter {
                demods: &mut self.demods,
                spectra: &mut self.spectra,
                free_spectra: &mut self.free_spectra,
                spare: &mut self.spare,
                counters: &self.counters,
                header,
                frame: DemodFrame::empty(),
                sample_rate: self.plan.sample_rate,
            };
            // With a scan, the block is cut at pixel boundaries (shifted by the
            // pre-decimator's delay, so each decimated sample counts in the pixel its
            // window is centred in) and each pixel's boxcar demodulation is handed out.
            let base = header.index;
            let end = base + len as u64;
            let mut pos = base;
            let mut references = header.references;
            while pos < end {
                // A loop moved the drive's frequency: the reference follows at the sample
                // where the samples taken under the new frequency begin.
                while references > 0 {
                    match self.references.first() {
                        Some(change) if change.index <= pos => {
                            match change.oscillator {
                                Oscillator::Drive => self.plan.align(change.phase, change.word),
                                Oscillator::Drive2 => {
                                    self.plan.align_drive2(change.phase, change.word);
                                }
                            }
                            self.references.skip(1);
                            references -= 1;
                        }
                        _ => break,
                    }
                }
                let mut stop = end;
                if references > 0
                    && let Some(change) = self.references.first()
                {
                    stop = stop.min(change.index);
                }
                let mut finishes = None;
                if let Some(r) = header.raster {
                    let delay = self.plan.group_delay();
                    match r.pixel_at(pos.saturating_sub(delay)) {
                        None => {
                            stop = stop.min(r.start + delay);
                            self.pixel_open = None;
                        }
                        Some(id) => {
                            let key = (r.generation, id.serial);
                            if self.pixel_open != Some(key) {
                                // Samples from before this pixel: not part of any pixel.
                                self.plan.take_pixel(&mut self.pixel_frame);
                                let lost = pixels_lost(self.pixel_open, self.pixel_next, key);
                                if lost > 0 {
                                    Counters::add(&self.counters.pixels_dropped, lost);
                                }
                                self.pixel_open = Some(key);
                                self.pixel_next = Some((key.0, key.1 + 1));
                            }
                            let boundary = r.pixel_start(id.serial + 1) + delay;
                            if boundary <= end {
                                stop = boundary;
                                finishes = Some((r, id));
                            }
                        }
                    }
                }
                let (lo, hi) = ((pos - base) as usize, (stop - base) as usize);
                for part in slice_range(first, second, lo, hi) {
                    if !part.is_empty() {
                        self.plan.process(part, &mut self.team, &mut emit);
                    }
                }
                if let Some((raster, pixel)) = finishes {
                    let samples = self.plan.take_pixel(&mut self.pixel_frame);
                    let frame = &mut self.pixel_frame;
                    frame.sample_index = stop - 1;
                    frame.t = frame.sample_index as f64 / self.plan.sample_rate;
                    frame.t_synth_ns = header.t_synth_ns;
                    frame.t_dsp_ns = unix_ns();
                    let record = PixelHarmonics {
                        raster,
                        pixel,
                        samples,
                        frame: *frame,
                    };
                    // A pixel entered just before its end after a gap may hold no decimated
                    // sample: it has no harmonics, so it is lost like the ones in the gap.
                    if samples > 0 && self.pixels.try_push(record).is_ok() {
                        Counters::add(&self.counters.pixels, 1);
                    } else {
                        Counters::add(&self.counters.pixels_dropped, 1);
                    }
                    self.pixel_open = None;
                }
                pos = stop;
            }
            // Each of the block's changes falls inside it; none is left over, but the
            // ring's order must not depend on that.
            self.references.skip(references as usize);
            if header.raster.is_none() {
                // Keep the integrators from growing without a scan.
                self.plan.take_pixel(&mut self.pixel_frame);
                self.pixel_open = None;
            }
            emit.flush();
            if let Some(signal) = &self.signal
                && self.counters.demod_frames.load(Ordering::Relaxed) != frames_before
            {
                signal.notify();
            }
            if let Some(scope) = &mut self.plan.scope {
                let counters = &self.counters;
                let (spare, free, out) = (
                    &mut self.scope_spare,
                    &mut self.free_scopes,
                    &mut self.scopes,
                );
                let mut take = || {
                    let buf = spare.take().or_else(|| free.try_pop());
                    if buf.is_none() {
                        Counters::add(&counters.scope_frames_dropped, 1);
                    }
                    buf
                };
                let mut rejected = None;
                let mut give = |mut buf: ScopeBuffer| {
                    buf.t_dsp_ns = unix_ns();
                    match out.try_push(buf) {
                        Ok(()) => Counters::add(&counters.scope_frames, 1),
                        Err(buf) => {
                            Counters::add(&counters.scope_frames_dropped, 1);
                            rejected = Some(buf);
                        }
                    }
                };
                let fs = self.plan.sample_rate;
                scope.feed(
                    &header,
                    header.index,
                    first,
                    fs,
                    &mut self.scope_current,
                    &mut take,
                    &mut give,
                );
                if !second.is_empty() {
                    let at = header.index + first.len() as u64;
                    scope.feed(
                        &header,
                        at,
                        second,
                        fs,
                        &mut self.scope_current,
                        &mut take,
                        &mut give,
                    );
                }
                if let Some(buf) = rejected {
                    self.scope_spare = Some(buf);
                }
            }
            self.finished = finished;
            self.counters
                .dsp_beat_ns
                .store(monotonic_ns(), Ordering::Relaxed);
            Counters::add(&self.counters.dsp_busy_ns, busy.elapsed().as_nanos() as u64);
            Counters::add(&self.counters.samples_processed, len as u64);
            expected = Some(header.index + len as u64);
            self.draw_noise();
        }
    }

    /// Draws the synthesiser's next pages of noise deviates, as many as it lacks, unless
    /// this thread is behind (then the synthesiser draws them itself, which is the same
    /// bits). Returns whether it drew any.
    fn draw_noise(&mut self) -> bool {
        let drawing = Instant::now();
        let mut drawn = 0;
        while self.samples.occupied_len() <= NOISE_BACKLOG && self.noise.work() {
            drawn += 1;
        }
        if drawn > 0 {
            Counters::add(&self.counters.noise_pages_drawn_ahead, drawn);
            Counters::add(
                &self.counters.dsp_busy_ns,
                drawing.elapsed().as_nanos() as u64,
            );
        }
        drawn > 0
    }
}

/// Collects the bank's outputs into frames and hands frames to the output rings.
pub(crate) struct Emitter<'a> {
    demods: &'a mut HeapProd<DemodFrame>,
    spectra: &'a mut HeapProd<SpectrumBuffer>,
    free_spectra: &'a mut HeapCons<SpectrumBuffer>,
    spare: &'a mut Option<SpectrumBuffer>,
    counters: &'a Counters,
    header: BlockHeader,
    frame: DemodFrame,
    sample_rate: f64,
}

impl DspSink for Emitter<'_> {
    fn demod(&mut self, index: u64, value: DemodValue) {
        Emitter::demod(self, index, value);
    }

    fn spectrum<I: ExactSizeIterator<Item = f64>>(&mut self, index: u64, bin_width: f64, bins: I) {
        Emitter::spectrum(self, index, bin_width, bins);
    }
}

impl Emitter<'_> {
    /// One demodulator output at stream sample `index`.
    pub fn demod(&mut self, index: u64, value: DemodValue) {
        if self.frame.len > 0 && self.frame.sample_index != index {
            self.flush();
        }
        if self.frame.len == 0 {
            self.frame.sample_index = index;
        }
        if self.frame.len < self.frame.values.len() {
            self.frame.values[self.frame.len] = value;
            self.frame.len += 1;
        }
    }

    /// Sends the frame being collected, if any.
    pub fn flush(&mut self) {
        if self.frame.len == 0 {
            return;
        }
        self.frame.t = self.frame.sample_index as f64 / self.sample_rate;
        self.frame.t_synth_ns = self.header.t_synth_ns;
        self.frame.t_dsp_ns = unix_ns();
        self.frame.pids = self.header.pids;
        if self.demods.try_push(self.frame).is_ok() {
            Counters::add(&self.counters.demod_frames, 1);
        } else {
            Counters::add(&self.counters.demod_frames_dropped, 1);
        }
        self.frame.len = 0;
    }

    /// One spectrum ending at stream sample `index`: magnitudes from `bins`.
    pub fn spectrum(
        &mut self,
        index: u64,
        bin_width: f64,
        bins: impl ExactSizeIterator<Item = f64>,
    ) {
        let Some(mut buffer) = self.spare.take().or_else(|| self.free_spectra.try_pop()) else {
            Counters::add(&self.counters.spectrum_frames_dropped, 1);
            return;
        };
        buffer.magnitudes.clear();
        // The pool's buffers were allocated for this size; `extend` stays within capacity.
        buffer
            .magnitudes
            .extend(bins.take(buffer.magnitudes.capacity()).map(|m| m as f32));
        buffer.sample_index = index;
        buffer.t = index as f64 / self.sample_rate;
        buffer.t_synth_ns = self.header.t_synth_ns;
        buffer.bin_width = bin_width;
        buffer.t_dsp_ns = unix_ns();
        match self.spectra.try_push(buffer) {
            Ok(()) => Counters::add(&self.counters.spectrum_frames, 1),
            Err(buffer) => {
                Counters::add(&self.counters.spectrum_frames_dropped, 1);
                *self.spare = Some(buffer);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::pixels_lost;

    #[test]
    fn lost_pixels_are_the_abandoned_one_and_the_skipped_ones() {
        // In order: nothing lost.
        assert_eq!(pixels_lost(None, Some((1, 5)), (1, 5)), 0);
        // Pixel 5 was open when a gap jumped to pixel 9: 5 abandoned, 6, 7, 8 skipped.
        assert_eq!(pixels_lost(Some((1, 5)), Some((1, 6)), (1, 9)), 4);
        // A gap inside the pixel after 5 finished: 6, 7 skipped.
        assert_eq!(pixels_lost(None, Some((1, 6)), (1, 8)), 2);
        // A new raster continues nothing.
        assert_eq!(pixels_lost(Some((1, 5)), Some((1, 6)), (2, 0)), 0);
        assert_eq!(pixels_lost(None, None, (1, 0)), 0);
    }
}
