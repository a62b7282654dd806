//! The replay-ratio limiter: one update per `train_interval` inserted env steps
//! once `warmup` steps are in, whichever side runs ahead waits.
//!
//! Invariant: at every moment, with `i` steps inserted (i ≥ warmup) and `u`
//! updates done, `u ≤ ⌊(i − warmup)/interval⌋ + 1` (updates never outrun data) and
//! `i < warmup + (u + slack)·interval` while the learner is behind (inserters wait),
//! so the ratio of updates to steps is the configured one regardless of machine
//! speed (Acme's `SampleToInsertRatio` with an error buffer of `slack` updates).

use serde::{Deserialize, Serialize};

/// Counters of the limiter (part of the learner state, saved in checkpoints).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct RateLimiter {
    /// Steps before the first update (Table IV: 5e4).
    pub warmup: u64,
    /// Inserted steps per update (Table IV: 8).
    pub interval: u64,
    /// How many updates the learner may fall behind before inserts block.
    pub slack: u64,
    /// Steps inserted so far.
    pub inserted: u64,
    /// Updates done so far.
    pub updates: u64,
}

impl RateLimiter {
    /// A limiter with no steps and no updates yet.
    pub fn new(warmup: u64, interval: u64, slack: u64) -> RateLimiter {
        RateLimiter { warmup, interval: interval.max(1), slack: slack.max(1), inserted: 0, updates: 0 }
    }

    /// Updates the data so far allows in total.
    pub fn allowed_updates(&self) -> u64 {
        if self.inserted < self.warmup { 0 } else { (self.inserted - self.warmup) / self.interval + 1 }
    }

    /// May the learner run an update now?
    pub fn can_update(&self) -> bool {
        self.updates < self.allowed_updates()
    }

    /// May another step be inserted now (or must the actors wait for the learner)?
    pub fn can_insert(&self) -> bool {
        self.allowed_updates() < self.updates + self.slack
    }

    /// Record inserted steps.
    pub fn inserted(&mut self, n: u64) {
        self.inserted += n;
    }

    /// Record one update.
    pub fn updated(&mut self) {
        debug_assert!(self.can_update(), "update beyond the allowed ratio");
        self.updates += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_env_steps_an_actor_reads_off_the_update_count_are_the_first_that_allow_it() {
        for (warmup, interval) in [(5000, 8), (1, 1), (64, 3)] {
            let cfg = pednav_config::DsacConfig { warmup, train_interval: interval, ..Default::default() };
            for u in [1, 2, 7, 1000] {
                let steps = cfg.env_steps_at_update(u);
                let at = |inserted| RateLimiter { inserted, ..RateLimiter::new(warmup, interval, 1) }.allowed_updates();
                assert_eq!(at(steps), u, "warm-up {warmup}, interval {interval}, {u} updates");
                assert_eq!(at(steps - 1), u - 1, "one step fewer allows one update fewer");
            }
            assert_eq!(cfg.env_steps_at_update(0), 0);
        }
    }

    #[test]
    fn warmup_then_one_update_per_interval() {
        let mut r = RateLimiter::new(100, 8, 2);
        r.inserted(99);
        assert!(!r.can_update() && r.can_insert());
        r.inserted(1);
        assert_eq!(r.allowed_updates(), 1);
        assert!(r.can_update());
        r.updated();
        assert!(!r.can_update());
        r.inserted(7);
        assert!(!r.can_update(), "107 steps: still one update");
        r.inserted(1);
        assert!(r.can_update(), "108 steps: a second update");
        // The learner does not update: inserts block once it is `slack` behind.
        r.inserted(7);
        assert!(r.can_insert());
        r.inserted(1);
        assert_eq!(r.allowed_updates(), 3);
        assert!(!r.can_insert(), "two updates behind: inserters wait");
        r.updated();
        assert!(r.can_insert());
    }

    #[test]
    fn simulated_fast_and_slow_sides_keep_the_ratio() {
        for (steps_per_tick, updates_per_tick) in [(1, 100), (100, 1), (3, 1)] {
            let mut r = RateLimiter::new(50, 8, 4);
            for _ in 0..10_000 {
                for _ in 0..steps_per_tick {
                    if r.can_insert() {
                        r.inserted(1);
                    }
                }
                for _ in 0..updates_per_tick {
                    if r.can_update() {
                        r.updated();
                    }
                }
                assert!(r.updates <= r.allowed_updates());
                assert!(r.inserted < r.warmup + (r.updates + r.slack) * r.interval + 1);
            }
            let ratio = (r.inserted - r.warmup) as f64 / r.updates as f64;
            assert!((ratio - 8.0).abs() < 0.5, "ratio {ratio} with {steps_per_tick}:{updates_per_tick}");
        }
    }
}
