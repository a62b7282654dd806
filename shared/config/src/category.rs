//! The curriculum's task categories and their wire codes (the `category` field of
//! task responses and episode reports between processes).
//!
//! Invariant: `Category::from_code(c.code()) == Some(c)` for every category, and
//! codes never change meaning (they are stored in run metrics).

use serde::{Deserialize, Serialize};

/// Where a proposed task came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Category {
    /// The scene's first task (before PassFirstTask).
    First,
    /// The scene's fixed start (Non-ACL variants).
    Fixed,
    /// f > μ + β_e·σ.
    Easy,
    /// μ − β_f^l·σ < f < μ + β_f^h·σ.
    Frontier,
    /// Any candidate.
    Random,
    /// f < μ − β_h·σ (Hard variant).
    Hard,
}

impl Category {
    /// Every category, in code order.
    pub const ALL: [Category; 6] =
        [Category::First, Category::Fixed, Category::Easy, Category::Frontier, Category::Random, Category::Hard];

    /// The wire code of this category.
    pub fn code(self) -> u32 {
        match self {
            Category::First => 0,
            Category::Fixed => 1,
            Category::Easy => 2,
            Category::Frontier => 3,
            Category::Random => 4,
            Category::Hard => 5,
        }
    }

    /// The category of a wire code (`None` for an unknown code).
    pub fn from_code(code: u32) -> Option<Category> {
        Category::ALL.get(code as usize).copied()
    }

    /// Lower-case name, as in metrics and logs.
    pub fn name(self) -> &'static str {
        match self {
            Category::First => "first",
            Category::Fixed => "fixed",
            Category::Easy => "easy",
            Category::Frontier => "frontier",
            Category::Random => "random",
            Category::Hard => "hard",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip_and_are_stable() {
        for (i, c) in Category::ALL.into_iter().enumerate() {
            assert_eq!(c.code(), i as u32);
            assert_eq!(Category::from_code(c.code()), Some(c));
        }
        assert_eq!(Category::from_code(6), None);
        assert_eq!((Category::Frontier.code(), Category::Hard.name()), (3, "hard"));
    }
}
