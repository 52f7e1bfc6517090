//! The CPU a rebuild worker (the force estimator's builder, the image worker) may spend on
//! rebuilds after settings changes: a bucket of build time that refills at [`BUILD_DUTY`]
//! seconds per second, up to [`BUILD_BURST`]. A change after a quiet spell is built at once;
//! a flood of changes averages at most a [`BUILD_DUTY`] share of a core, so it never takes a
//! core from the real-time threads.

use std::time::{Duration, Instant};

/// The share of a core rebuilds average under a flood of changes.
pub(crate) const BUILD_DUTY: f64 = 0.25;
/// Build time a worker may spend at once after a quiet spell, in s: a coupled estimator's
/// start-up build and the first change's build after it (0.5–2 s each at the defaults,
/// more on a busy machine) run back to back.
pub(crate) const BUILD_BURST: f64 = 4.0;

/// A worker's budget of build time.
pub(crate) struct BuildBudget {
    /// Build time left, in s; negative after a build longer than what was left.
    credit: f64,
    /// When `credit` was last brought up to date.
    at: Instant,
}

impl BuildBudget {
    /// A full budget.
    pub fn new() -> Self {
        BuildBudget {
            credit: BUILD_BURST,
            at: Instant::now(),
        }
    }

    fn refill(&mut self, now: Instant) {
        let elapsed = now.saturating_duration_since(self.at).as_secs_f64();
        self.credit = (self.credit + elapsed * BUILD_DUTY).min(BUILD_BURST);
        self.at = now;
    }

    /// How long from `now` until a build may start: zero while credit is left.
    pub fn wait(&mut self, now: Instant) -> Duration {
        self.refill(now);
        if self.credit > 0.0 {
            Duration::ZERO
        } else {
            // Until the credit is positive again (a little over zero, so time has passed).
            Duration::from_secs_f64(-self.credit / BUILD_DUTY) + Duration::from_millis(1)
        }
    }

    /// Charges a build that took `took` (wall time) and ended at `now`.
    pub fn spend(&mut self, took: Duration, now: Instant) {
        self.refill(now);
        self.credit -= took.as_secs_f64();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quiet_spell_allows_a_burst_and_a_flood_averages_the_duty() {
        let start = Instant::now();
        let mut budget = BuildBudget::new();
        budget.at = start;
        // Two builds of 1.5 s back to back: both start at once.
        let mut now = start;
        for _ in 0..2 {
            assert_eq!(budget.wait(now), Duration::ZERO);
            now += Duration::from_secs_f64(1.5);
            budget.spend(Duration::from_secs_f64(1.5), now);
        }
        // A flood of 1 s builds, each started as soon as allowed: over 100 builds the
        // building is a quarter of the time, plus the burst.
        let flood_start = now;
        let mut built = 0.0;
        for _ in 0..100 {
            now += budget.wait(now);
            now += Duration::from_secs(1);
            budget.spend(Duration::from_secs(1), now);
            built += 1.0;
        }
        let elapsed = (now - flood_start).as_secs_f64();
        assert!(
            built <= BUILD_DUTY * elapsed + BUILD_BURST + 1.0,
            "{built} in {elapsed}"
        );
        assert!(built >= BUILD_DUTY * elapsed - 1.0, "{built} in {elapsed}");
    }
}
