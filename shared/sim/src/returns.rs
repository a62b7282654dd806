//! The discounted return of an episode as it unfolds, G = Σₖ γᵏ rₖ₊₁ — one
//! accumulator for the actors' episode reports, the evaluator and `pednav-sim record`.
//!
//! Invariant: after rewards r₁ … rₙ, [`DiscountedReturn::value`] is Σₖ<ₙ γᵏ rₖ₊₁
//! (accumulated in f64) and [`DiscountedReturn::undiscounted`] is Σ rₖ.

/// A running discounted return.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiscountedReturn {
    gamma: f64,
    value: f64,
    discount: f64,
    total: f64,
}

impl DiscountedReturn {
    /// An empty return with discount factor `gamma`.
    pub fn new(gamma: f64) -> DiscountedReturn {
        DiscountedReturn { gamma, value: 0.0, discount: 1.0, total: 0.0 }
    }

    /// Add the next reward.
    pub fn add(&mut self, reward: f32) {
        self.value += self.discount * reward as f64;
        self.discount *= self.gamma;
        self.total += reward as f64;
    }

    /// Σₖ γᵏ rₖ₊₁ so far.
    pub fn value(&self) -> f64 {
        self.value
    }

    /// Σ rₖ so far.
    pub fn undiscounted(&self) -> f64 {
        self.total
    }
}

#[cfg(test)]
mod tests {
    use super::DiscountedReturn;

    #[test]
    fn by_hand() {
        let mut g = DiscountedReturn::new(0.5);
        assert_eq!((g.value(), g.undiscounted()), (0.0, 0.0));
        for r in [4.0, -2.0, 8.0] {
            g.add(r);
        }
        // 4 + 0.5·(−2) + 0.25·8 = 5; 4 − 2 + 8 = 10.
        assert_eq!((g.value(), g.undiscounted()), (5.0, 10.0));
    }
}
