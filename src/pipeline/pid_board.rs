//! The PID units' latest updates, from the synthesiser thread to anyone: per unit a
//! sequence lock over atomics. The writer (the synthesiser, once per drive period) never
//! waits, locks or allocates; a reader retries while a write is in progress and takes a
//! consistent copy of one update: its measurement, error, output, limit flag, sample and
//! the settings epoch it ran under.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering, fence};

use serde::Serialize;

use crate::config::{PID_COUNT, PidTarget};
use crate::synth::PidReading;

/// How often a reader retries a unit being written before it gives up on it for now (the
/// writer holds a slot for a few stores, so one retry nearly always does).
const READ_TRIES: usize = 64;

/// One unit's slot.
#[derive(Debug, Default)]
struct Slot {
    /// Odd while the synthesiser writes; the number of writes × 2 otherwise.
    sequence: AtomicU64,
    sample: AtomicU64,
    epoch: AtomicU64,
    measurement: AtomicU64,
    error: AtomicU64,
    output: AtomicU64,
    limited: AtomicU64,
    /// A PLL's lock: 0 none (not a PLL), 1 unlocked, 2 locked.
    locked: AtomicU64,
    lock_losses: AtomicU64,
    updates: AtomicU64,
}

/// The latest update of each PID unit.
#[derive(Debug, Default)]
pub struct PidBoard {
    slots: [Slot; PID_COUNT],
    /// The outputs a loop holds away from their nodes, [`PidTarget::bit`] each.
    held: AtomicU64,
    /// Whether the `pids` stream has subscribers: the synthesiser then queues every update.
    streaming: AtomicBool,
}

/// Updates the `pids` stream's queue holds (0.16 s of four units at 100 kHz).
pub const PID_EVENT_QUEUE: usize = 1 << 16;

/// Updates of all units one block of samples can hold: a unit updates at most every other
/// sample (a period is at least two), so a block holds at most `BLOCK_SAMPLES / 2 + 1` of
/// each. The synthesiser keeps a block's updates in a buffer of this capacity, reserved
/// off the real-time path, until the block's synthesis time is known.
pub const PID_EVENTS_PER_BLOCK: usize = PID_COUNT * (super::BLOCK_SAMPLES / 2 + 1);

/// One update of one unit as the `pids` stream carries it: the reading, the settings
/// epoch the synthesiser ran under and when it synthesised the update's block.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PidEvent {
    /// The update.
    pub reading: PidReading,
    /// The settings epoch it was made under.
    pub epoch: u64,
    /// Unix time (ns) at which the synthesiser finished the block of samples the update was
    /// made in: the block header's `t_synth_ns`, which the demodulator frames of that block
    /// carry too.
    pub t_synth_ns: u64,
}

/// A unit's latest update as the board holds it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PidUpdate {
    /// Index of the sample from which the output took effect; its time is sample /
    /// sample rate.
    pub sample: u64,
    /// The settings epoch the synthesiser ran under when it made it.
    pub epoch: u64,
    /// The input its demodulator read (the input's unit: m, or rad for the phase).
    pub measurement: f64,
    /// Set-point minus measurement (the input's unit).
    pub error: f64,
    /// The output (the output's unit: m for the surface distance).
    pub output: f64,
    /// Whether a limit held the output: `/pids/N/output_min`, `output_max` or `rate`.
    pub limited: bool,
    /// A PLL's lock after this update ([`PidReading::locked`]); `None` for other units.
    pub locked: Option<bool>,
    /// A PLL's losses of lock since the pipeline started, every one counted however brief
    /// (0 for other units).
    pub lock_losses: u64,
    /// Updates of this unit since the pipeline started.
    pub updates: u64,
}

impl PidBoard {
    /// Records `reading`, made under settings epoch `epoch`. For the synthesiser thread
    /// only (one writer): lock-free, allocation-free.
    #[inline]
    pub(crate) fn publish(&self, reading: &PidReading, epoch: u64) {
        let Some(slot) = self.slots.get(reading.unit) else {
            return;
        };
        let sequence = slot.sequence.load(Ordering::Relaxed);
        slot.sequence
            .store(sequence.wrapping_add(1), Ordering::Relaxed);
        // The odd sequence is visible before any field changes.
        fence(Ordering::Release);
        slot.sample.store(reading.sample, Ordering::Relaxed);
        slot.epoch.store(epoch, Ordering::Relaxed);
        slot.measurement
            .store(reading.measurement.to_bits(), Ordering::Relaxed);
        slot.error.store(reading.error.to_bits(), Ordering::Relaxed);
        slot.output
            .store(reading.output.to_bits(), Ordering::Relaxed);
        slot.limited
            .store(u64::from(reading.limited), Ordering::Relaxed);
        let locked = reading.locked.map_or(0, |l| 1 + u64::from(l));
        slot.locked.store(locked, Ordering::Relaxed);
        slot.lock_losses
            .store(reading.lock_losses, Ordering::Relaxed);
        let updates = slot.updates.load(Ordering::Relaxed);
        slot.updates.store(updates + 1, Ordering::Relaxed);
        slot.sequence
            .store(sequence.wrapping_add(2), Ordering::Release);
    }

    /// Whether the synthesiser should queue every update for the `pids` stream.
    #[inline]
    pub(crate) fn streaming(&self) -> bool {
        self.streaming.load(Ordering::Relaxed)
    }

    /// Turns the queueing of every update on or off (the hub, as the `pids` stream gains
    /// or loses its subscribers).
    pub fn set_streaming(&self, on: bool) {
        self.streaming.store(on, Ordering::Relaxed);
    }

    /// The outputs the loops hold, [`PidTarget::bit`] each.
    pub fn held_mask(&self) -> u64 {
        self.held.load(Ordering::Relaxed)
    }

    /// Records which outputs the loops hold ([`crate::synth::PidRuntime::held_outputs`]).
    /// For the synthesiser thread: lock-free, allocation-free.
    #[inline]
    pub(crate) fn set_held(&self, mask: u64) {
        self.held.store(mask, Ordering::Relaxed);
    }

    /// The outputs a loop holds away from their nodes: one running on it, or one that
    /// ran and left it where it put it.
    pub fn held(&self) -> Vec<PidTarget> {
        let mask = self.held_mask();
        PidTarget::ALL
            .iter()
            .copied()
            .filter(|t| mask & t.bit() != 0)
            .collect()
    }

    /// Unit `unit`'s latest update; `None` before its first, for an index past the units,
    /// or (rarely) when the writer kept it busy through every try.
    pub fn latest(&self, unit: usize) -> Option<PidUpdate> {
        let slot = self.slots.get(unit)?;
        for _ in 0..READ_TRIES {
            let before = slot.sequence.load(Ordering::Acquire);
            if before % 2 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let f = |a: &AtomicU64| f64::from_bits(a.load(Ordering::Relaxed));
            let update = PidUpdate {
                sample: slot.sample.load(Ordering::Relaxed),
                epoch: slot.epoch.load(Ordering::Relaxed),
                measurement: f(&slot.measurement),
                error: f(&slot.error),
                output: f(&slot.output),
                limited: slot.limited.load(Ordering::Relaxed) != 0,
                locked: match slot.locked.load(Ordering::Relaxed) {
                    0 => None,
                    l => Some(l == 2),
                },
                lock_losses: slot.lock_losses.load(Ordering::Relaxed),
                updates: slot.updates.load(Ordering::Relaxed),
            };
            // The fields are read before the sequence is read again.
            fence(Ordering::Acquire);
            if slot.sequence.load(Ordering::Relaxed) == before {
                return (update.updates > 0).then_some(update);
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reader_sees_whole_updates_while_the_writer_runs() {
        let board = std::sync::Arc::new(PidBoard::default());
        assert_eq!(board.latest(0), None);
        let writer = {
            let board = board.clone();
            std::thread::spawn(move || {
                for n in 0..200_000u64 {
                    let x = n as f64;
                    board.publish(
                        &PidReading {
                            unit: 1,
                            sample: n,
                            measurement: x,
                            error: -x,
                            output: 2.0 * x,
                            limited: n % 2 == 1,
                            locked: (n % 3 != 0).then_some(n % 3 == 2),
                            lock_losses: n / 7,
                        },
                        n,
                    );
                }
            })
        };
        let mut seen = 0;
        while !writer.is_finished() || seen == 0 {
            if let Some(u) = board.latest(1) {
                // Every field from the same update.
                let n = u.sample;
                assert_eq!(u.epoch, n);
                assert_eq!(u.measurement, n as f64);
                assert_eq!(u.error, -(n as f64));
                assert_eq!(u.output, 2.0 * n as f64);
                assert_eq!(u.limited, n % 2 == 1);
                assert_eq!(u.locked, (n % 3 != 0).then_some(n % 3 == 2));
                assert_eq!(u.lock_losses, n / 7);
                assert_eq!(u.updates, n + 1);
                seen += 1;
            }
        }
        writer.join().unwrap();
        assert_eq!(board.latest(1).unwrap().updates, 200_000);
        assert_eq!(board.latest(0), None);
        assert_eq!(board.latest(PID_COUNT), None);
    }
}
