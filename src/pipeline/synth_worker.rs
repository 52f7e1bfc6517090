//! The synthesiser thread: fills blocks with the signal through the ADC's window (a scan's
//! with finished samples), hands them to the sample ring, paces itself to the wall clock
//! (or runs free), and swaps in new plans between blocks.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use ringbuf::traits::{Consumer, Observer, Producer};
use ringbuf::{HeapCons, HeapProd};

use super::block::{BlockHeader, unix_ns};
use super::counters::Counters;
use super::epochs::Epochs;
use super::feed::{FeedReader, Piece};
use crate::config::SourceKind;
use crate::synth::{
    PidReading, PidRuntime, PixelTopography, ReferenceChange, ScanLoops, ScanRuntime, SynthPlan,
    SynthState, WindowSample,
};

/// Samples per block: 0.41 ms at 10 MS/s, short against the 1 ms output period.
pub const BLOCK_SAMPLES: usize = 4096;
/// How long the thread sleeps when a streamed source has nothing for it (a writer's frames
/// come every few milliseconds; the feed holds half a second).
const STREAM_WAIT: Duration = Duration::from_micros(500);

pub(crate) struct SynthWorker {
    pub plan: Box<SynthPlan>,
    pub state: SynthState,
    pub scan: ScanRuntime,
    /// The PID units' controllers and demodulators.
    pub pids: PidRuntime,
    /// Finished pixels' topography, to the consumer.
    pub topography: HeapProd<PixelTopography>,
    /// Every PID update, while the `pids` stream has subscribers.
    pub pid_events: HeapProd<super::PidEvent>,
    /// The block's PID updates for the `pids` stream, queued with the block's synthesis
    /// time once it is done (capacity [`super::PID_EVENTS_PER_BLOCK`], reserved off the
    /// real-time path).
    pub block_pid_readings: Vec<PidReading>,
    /// The signal through the ADC's window, which the DSP thread finishes.
    pub samples: HeapProd<WindowSample>,
    pub headers: HeapProd<BlockHeader>,
    /// Changes of the lock-in's reference (a loop moving the drive frequency), each
    /// counted in the header of the block it falls in.
    pub references: HeapProd<ReferenceChange>,
    /// Changes made and not yet handed on, in order (capacity for a block's and those
    /// pending past it, reserved off the real-time path).
    pub reference_changes: Vec<ReferenceChange>,
    pub plans_in: HeapCons<Box<SynthPlan>>,
    pub plans_out: HeapProd<Box<SynthPlan>>,
    pub counters: Arc<Counters>,
    pub stop: Arc<AtomicBool>,
    pub realtime: Arc<AtomicBool>,
    /// The DSP thread, woken when a block is ready so that it can sleep until then instead
    /// of polling (`unpark` is a flag and, only if the thread sleeps, one futex wake).
    pub consumer: Option<std::thread::Thread>,
    /// The newest settings epoch the control side has published (its plans are queued
    /// before it is), and where each epoch took effect.
    pub epochs: Arc<Epochs>,
    /// A plan taken from the queue whose epoch is not published yet.
    pub pending: Option<Box<SynthPlan>>,
    /// Samples streamed in (`/source/kind = "stream"`).
    pub feed: FeedReader,
}

impl SynthWorker {
    pub fn run(mut self) {
        let mut block = vec![WindowSample::default(); BLOCK_SAMPLES];
        // A scan's samples, finished here for its feedback.
        let mut finished = vec![0.0; BLOCK_SAMPLES];
        // Pacing reference: wall time at which sample `paced_index` was due.
        let mut paced_from = Instant::now();
        let mut paced_index = self.state.sample_index();
        let mut was_realtime = self.realtime.load(Ordering::Relaxed);
        // A scan configured from the start begins at the first sample.
        self.scan
            .retarget(&self.plan, &self.plan, self.state.sample_index());
        let index = self.state.sample_index();
        self.pids
            .retarget(&self.plan, &self.plan, index, &mut self.state);
        self.counters.pids.set_held(self.pids.held_outputs());
        // The epoch the starting plan reflects, not the newest published: a change applied
        // before this thread got here is then stamped with its first block like any other.
        let mut stamped = self.plan.epoch;
        while !self.stop.load(Ordering::Relaxed) {
            // Read before the plans: every plan of this epoch was queued before it was
            // published, so all of them are taken up with this block.
            let epoch = self.epochs.requested.load(Ordering::Acquire);
            loop {
                if self.pending.is_none() {
                    self.pending = self.plans_in.try_pop();
                }
                // A plan queued for an epoch not yet published waits for it, so that no
                // block runs a plan under an earlier epoch's stamp.
                let next = match self.pending.take() {
                    Some(next) if next.epoch <= epoch => next,
                    later => {
                        self.pending = later;
                        break;
                    }
                };
                if self.plan.source == SourceKind::Stream && next.source != SourceKind::Stream {
                    // What the writer sent and the chain never took is not the new
                    // source's: gone, and counted.
                    Counters::add(&self.counters.stream_discarded_samples, self.feed.discard());
                }
                // The modes under the plan's own drive first, which the change moves
                // from; the loops then take up theirs again.
                self.pids.release_drive(&self.plan, &mut self.state);
                self.state.retarget(&self.plan, &next);
                let index = self.state.sample_index();
                self.scan.retarget(&self.plan, &next, index);
                self.pids
                    .retarget(&self.plan, &next, index, &mut self.state);
                self.counters.pids.set_held(self.pids.held_outputs());
                // Changes the old drive made and the stream has not reached are void.
                self.reference_changes.clear();
                let old = std::mem::replace(&mut self.plan, next);
                // The control side keeps plans in flight (a held one included) within the
                // return queue's capacity, so this has room; the old plan is freed there.
                let _ = self.plans_out.try_push(old);
                Counters::add(&self.counters.synth_plans_applied, 1);
            }
            let realtime = self.realtime.load(Ordering::Relaxed);
            if realtime && !was_realtime {
                paced_from = Instant::now();
                paced_index = self.state.sample_index();
            }
            was_realtime = realtime;

            if self.plan.source == SourceKind::Stream {
                self.pids.pause();
                if !self.pass_stream(&mut block, &mut finished, epoch, &mut stamped) {
                    // Nothing has come: the next sample is where this epoch takes effect.
                    if epoch != stamped {
                        self.epochs.took_effect(epoch, self.state.sample_index());
                        stamped = epoch;
                    }
                    self.counters
                        .synth_beat_ns
                        .store(super::counters::monotonic_ns(), Ordering::Relaxed);
                    std::thread::park_timeout(STREAM_WAIT);
                }
                continue;
            }
            let header_index = self.state.sample_index();
            if epoch != stamped {
                self.epochs.took_effect(epoch, header_index);
                stamped = epoch;
            }
            // The drive phase at which the block's first sample was taken: behind the
            // synthesis by the ADC filter's delay, so the lock-in sees no shift from it;
            // under the loops, their drive's (a PLL moves it).
            // A scan runs them beside it (with its own feedback on, only the second
            // excitation's, which the settings allow then).
            let loops = self.pids.active(&self.plan);
            let [(phase, frequency_word), (phase2, frequency_word2)] = if loops {
                self.pids.begin(&self.plan, &self.state)
            } else {
                [
                    (
                        self.plan.output_phase(self.state.phase()),
                        self.plan.frequency_word,
                    ),
                    (
                        self.plan
                            .output_phase_at(self.state.phase2(), self.plan.frequency_word2),
                        self.plan.frequency_word2,
                    ),
                ]
            };
            let clipped_before = self.state.counters.clipped;
            let (refined_before, over_before) =
                (self.state.counters.refined, self.state.counters.over_budget);
            let pages_before = self.state.noise_pages();
            let busy = Instant::now();
            // The loops' updates and the lock-in's reference changes they make.
            let board = &self.counters.pids;
            let (changes, counters) = (&mut self.reference_changes, &self.counters);
            let held = &mut self.block_pid_readings;
            held.clear();
            let streaming = board.streaming();
            let mut reading = |r: PidReading| {
                board.publish(&r, epoch);
                // Held to the block's end, when its synthesis time is known; the capacity
                // reserved holds a block's, so this never grows the vector.
                if streaming {
                    if held.len() < held.capacity() {
                        held.push(r);
                    } else {
                        Counters::add(&counters.pid_updates_dropped, 1);
                    }
                }
            };
            let mut reference = |c: ReferenceChange| {
                // A change per update, the updates a period (at least two samples) apart:
                // a block's and the ⌈D⌉ samples' past it fit the capacity reserved, so
                // this never grows the vector. Were one lost, the DSP's reference would
                // jump: counted as such.
                if changes.len() < changes.capacity() {
                    changes.push(c);
                } else {
                    Counters::add(&counters.discontinuities, 1);
                }
            };
            let digitise = if self.plan.scan.is_some() {
                let loops = if loops {
                    Some(ScanLoops {
                        runtime: &mut self.pids,
                        reading: &mut reading,
                        reference: &mut reference,
                    })
                } else {
                    self.pids.pause();
                    None
                };
                let out = &mut self.topography;
                self.plan.process_scan(
                    &mut self.state,
                    &mut self.scan,
                    loops,
                    &mut finished,
                    &mut |p| {
                        if out.try_push(p).is_ok() {
                            Counters::add(&counters.topography_pixels, 1);
                        } else {
                            Counters::add(&counters.topography_pixels_dropped, 1);
                        }
                    },
                );
                None
            } else if loops {
                // The loops read the finished samples, so they are finished here.
                self.plan.process_pids(
                    &mut self.state,
                    &mut self.pids,
                    &mut finished,
                    &mut reading,
                    &mut reference,
                );
                None
            } else {
                self.pids.pause();
                // The ADC's FIRs, detector noise and quantiser run on the DSP thread.
                Some(self.plan.process_window(&mut self.state, &mut block))
            };
            if digitise.is_none() {
                // Finished here (a scan's or the loops' samples): into the block as they
                // are, and their clipped samples counted.
                for (w, &s) in block.iter_mut().zip(&finished) {
                    w.grid = s;
                }
                Counters::add(
                    &self.counters.clipped_samples,
                    self.state.counters.clipped - clipped_before,
                );
            }
            Counters::add(
                &self.counters.synth_busy_ns,
                busy.elapsed().as_nanos() as u64,
            );
            Counters::add(
                &self.counters.refined_samples,
                self.state.counters.refined - refined_before,
            );
            Counters::add(
                &self.counters.over_budget_samples,
                self.state.counters.over_budget - over_before,
            );
            let pages = self.state.noise_pages();
            Counters::add(
                &self.counters.noise_pages_taken,
                pages.taken - pages_before.taken,
            );
            Counters::add(
                &self.counters.noise_pages_drawn_inline,
                pages.drawn - pages_before.drawn,
            );
            Counters::add(
                &self.counters.noise_pages_discarded,
                pages.discarded - pages_before.discarded,
            );
            Counters::add(&self.counters.samples_synthesized, BLOCK_SAMPLES as u64);
            self.counters
                .synth_beat_ns
                .store(super::counters::monotonic_ns(), Ordering::Relaxed);
            let t_synth_ns = unix_ns();
            self.queue_pid_events(epoch, t_synth_ns);
            let end = header_index + BLOCK_SAMPLES as u64;
            let references = self
                .reference_changes
                .iter()
                .take_while(|c| c.index < end)
                .count();
            let header = BlockHeader {
                index: header_index,
                len: BLOCK_SAMPLES as u32,
                phase,
                frequency_word,
                phase2,
                frequency_word2,
                t_synth_ns: unix_ns(),
                raster: self.plan.scan.as_ref().and(self.scan.raster),
                epoch,
                digitise,
                references: references as u32,
                pids: self.pids.sums(),
            };
            let pushed = self.push(&block, header, realtime);
            // The block's changes went with it, or are gone with it (the DSP restarts on
            // the next block's header, which carries the reference there).
            self.reference_changes.drain(..references);
            if !pushed {
                Counters::add(&self.counters.overrun_samples, BLOCK_SAMPLES as u64);
                Counters::add(&self.counters.overrun_blocks, 1);
            }
            if realtime {
                self.pace(&mut paced_from, &mut paced_index);
            }
        }
    }

    /// Passes the next piece of a streamed source on: a gap moves the stream on (the DSP
    /// restarts at the jump), samples go to the DSP as a finished block at the drive phase
    /// of their index. Whether there was anything to pass.
    fn pass_stream(
        &mut self,
        block: &mut [WindowSample],
        finished: &mut [f64],
        epoch: u64,
        stamped: &mut u64,
    ) -> bool {
        let n = match self.feed.next(BLOCK_SAMPLES) {
            None => return false,
            Some(Piece::Skip(n)) => {
                self.state.skip(&self.plan, n);
                return true;
            }
            Some(Piece::Start(index)) => {
                self.state.start_stream(&self.plan, index);
                return true;
            }
            Some(Piece::Samples(n)) => n,
        };
        let header_index = self.state.sample_index();
        if epoch != *stamped {
            self.epochs.took_effect(epoch, header_index);
            *stamped = epoch;
        }
        // A streamed sample is taken when it is: no ADC filter delays it.
        let (phase, phase2) = (self.state.phase(), self.state.phase2());
        self.feed.take(&mut finished[..n]);
        for (w, &x) in block.iter_mut().zip(&finished[..n]) {
            w.grid = x;
        }
        self.state.skip(&self.plan, n as u64);
        Counters::add(&self.counters.samples_synthesized, n as u64);
        self.counters
            .synth_beat_ns
            .store(super::counters::monotonic_ns(), Ordering::Relaxed);
        let header = BlockHeader {
            index: header_index,
            len: n as u32,
            phase,
            frequency_word: self.plan.frequency_word,
            phase2,
            frequency_word2: self.plan.frequency_word2,
            t_synth_ns: unix_ns(),
            raster: None,
            epoch,
            digitise: None,
            references: 0,
            pids: self.pids.sums(),
        };
        let realtime = self.realtime.load(Ordering::Relaxed);
        if !self.push(&block[..n], header, realtime) {
            Counters::add(&self.counters.overrun_samples, n as u64);
            Counters::add(&self.counters.overrun_blocks, 1);
        }
        true
    }

    /// Queues the block's PID updates for the `pids` stream, each stamped with the
    /// block's synthesis time `t_synth_ns` and settings epoch `epoch`; a full queue drops
    /// them, counted.
    fn queue_pid_events(&mut self, epoch: u64, t_synth_ns: u64) {
        for &reading in &self.block_pid_readings {
            let event = super::PidEvent {
                reading,
                epoch,
                t_synth_ns,
            };
            if self.pid_events.try_push(event).is_ok() {
                Counters::add(&self.counters.pid_updates, 1);
            } else {
                Counters::add(&self.counters.pid_updates_dropped, 1);
            }
        }
        self.block_pid_readings.clear();
    }

    /// Hands a block to the DSP. In real time a full ring drops the block (the caller counts
    /// it); free-running waits for room, since nothing is due by the clock.
    fn push(&mut self, block: &[WindowSample], header: BlockHeader, realtime: bool) -> bool {
        loop {
            let references = header.references as usize;
            if self.samples.vacant_len() >= block.len()
                && self.headers.vacant_len() >= 1
                && self.references.vacant_len() >= references
            {
                self.samples.push_slice(block);
                self.references
                    .push_slice(&self.reference_changes[..references]);
                let _ = self.headers.try_push(header);
                if let Some(consumer) = &self.consumer {
                    consumer.unpark();
                }
                return true;
            }
            if realtime || self.stop.load(Ordering::Relaxed) {
                return false;
            }
            std::thread::yield_now();
        }
    }

    /// Sleeps until the next block is due by the wall clock.
    fn pace(&mut self, paced_from: &mut Instant, paced_index: &mut u64) {
        let ahead = (self.state.sample_index() - *paced_index) as f64 / self.plan.sample_rate;
        let due = *paced_from + Duration::from_secs_f64(ahead);
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        } else if now - due > Duration::from_millis(100) {
            // Hopelessly behind (a stall): start pacing afresh instead of racing to catch up.
            Counters::add(&self.counters.late_blocks, 1);
            *paced_from = now;
            *paced_index = self.state.sample_index();
        }
    }
}
