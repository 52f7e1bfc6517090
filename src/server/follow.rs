//! What follows a committed settings change on the server's side: the fan-out's byte
//! bound, the force estimator and the images. Called by [`Control`] in commit order, on the
//! change's thread, before the requester hears of the change.
//!
//! [`Control`]: crate::instrument::Control

use std::sync::Weak;
use std::sync::atomic::Ordering;

use super::state::AppState;
use crate::instrument::{Committed, affects_physics};

/// The followers of `state`'s control plane (held weakly: the control plane is the state's).
pub(crate) fn followers(state: Weak<AppState>) -> impl Fn(&Committed<'_>) + Send + Sync {
    move |c| {
        let Some(state) = state.upgrade() else {
            return;
        };
        state.queue_bytes.store(
            c.settings.server.client_queue_bytes as usize,
            Ordering::Relaxed,
        );
        let rebuild = c.touched(crate::instrument::force::affects_estimator)
            || (c.touched(crate::instrument::force::moves_a_modulus)
                && state.force.outgrown(c.settings));
        // The estimator's frames must come from the new settings: after a change of the
        // physics, or of what the estimator models (e.g. the demodulators, whose frames in
        // flight have the old layout), those before the change has settled are left out.
        let settle_from = (rebuild || c.touched(affects_physics)).then(|| {
            c.t.unwrap_or(0.0) + crate::instrument::sweeper::automatic_settling(c.settings)
        });
        state.force.follow(
            c.epoch,
            settle_from,
            rebuild.then(|| (**c.settings).clone()),
        );
        if c.touched(crate::instrument::image::affects_images) {
            state.image.configure(c.settings, c.epoch);
        }
        state.image.committed(c.epoch);
    }
}
