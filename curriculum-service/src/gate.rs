//! The PassFirstTask gate of NavACL⁺ (paper §III-B, Appendix): ACL starts once the
//! mean discounted return of the most recent `window` first-task episodes reaches
//! `threshold` (30 and −25 in the paper).
//!
//! Invariant: the gate is closed until `window` first-task returns have been seen,
//! and once open it stays open — the ACL phase, in which t_c counts decision steps,
//! is entered once (the paper's runs "enter the ACL phase" at one point in time).

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// Rolling mean of first-task returns with a latch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PassFirstTask {
    window: usize,
    threshold: f32,
    recent: VecDeque<f32>,
    passed: bool,
}

impl PassFirstTask {
    /// A closed gate.
    pub fn new(window: usize, threshold: f32) -> PassFirstTask {
        PassFirstTask { window, threshold, recent: VecDeque::with_capacity(window), passed: false }
    }

    /// Record the discounted return of a first-task episode; returns whether the gate is open.
    pub fn record(&mut self, discounted_return: f32) -> bool {
        if self.recent.len() == self.window {
            self.recent.pop_front();
        }
        self.recent.push_back(discounted_return);
        if !self.passed && self.recent.len() == self.window {
            self.passed = self.mean().is_some_and(|m| m >= self.threshold);
        }
        self.passed
    }

    /// Mean of the recent returns, if any.
    pub fn mean(&self) -> Option<f32> {
        (!self.recent.is_empty()).then(|| self.recent.iter().sum::<f32>() / self.recent.len() as f32)
    }

    /// Is the gate open?
    pub fn passed(&self) -> bool {
        self.passed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opens_on_the_mean_of_a_full_window_and_latches() {
        let mut g = PassFirstTask::new(3, -25.0);
        assert!(!g.record(0.0), "window not full yet");
        assert!(!g.record(0.0));
        // [0, 0, -80]: mean -26.67 < -25.
        assert!(!g.record(-80.0));
        // [0, -80, 10]: mean -23.33 ≥ -25.
        assert!(g.record(10.0));
        assert_eq!(g.mean(), Some(-70.0 / 3.0));
        // Later failures do not close it.
        for _ in 0..5 {
            assert!(g.record(-300.0));
        }
    }

    #[test]
    fn exactly_the_threshold_passes() {
        let mut g = PassFirstTask::new(2, -25.0);
        g.record(-20.0);
        assert!(g.record(-30.0));
    }
}
