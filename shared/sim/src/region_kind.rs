//! [`RegionKind`]: what a patch of ground is — the label the region map stores per
//! cell, the key of the map reward ([`crate::reward`]) and of the ground's look.
//!
//! Invariant: `kind as u8` is the kind's label and its index in
//! [`RegionKind::ALL`], so `from_label(k.label()) == k` and per-kind tables are
//! plain arrays indexed by the label.
//!
//! A module of its own, below [`crate::scene`] (which holds the regions' polygons)
//! and [`crate::reward`] (which gives each kind its reward), so that neither of
//! those two has to import the other for it.

use serde::{Deserialize, Serialize};

/// What a patch of ground is; decides the per-step map reward and the look.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RegionKind {
    /// Carriageway: heavily penalised.
    Road,
    /// Sidewalks on the start side and elsewhere.
    Sidewalk,
    /// The sidewalk on the goal's side of the road.
    GoalSidewalk,
    /// Zebra crossing painted over the road.
    Zebra,
    /// Goal area: reaching it ends the episode with the goal reward.
    Goal,
}

impl RegionKind {
    /// All kinds, in label order (`kind as u8` is the label stored in the region map).
    pub const ALL: [RegionKind; 5] =
        [RegionKind::Road, RegionKind::Sidewalk, RegionKind::GoalSidewalk, RegionKind::Zebra, RegionKind::Goal];

    /// The label stored in the region map.
    pub fn label(self) -> u8 {
        self as u8
    }

    /// The kind of a region-map label.
    pub fn from_label(label: u8) -> RegionKind {
        Self::ALL[label as usize]
    }

    /// Human-readable name used in logs and legends.
    pub fn name(self) -> &'static str {
        match self {
            RegionKind::Road => "road",
            RegionKind::Sidewalk => "sidewalk",
            RegionKind::GoalSidewalk => "goal-side sidewalk",
            RegionKind::Zebra => "zebra crossing",
            RegionKind::Goal => "goal",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::RegionKind;

    #[test]
    fn labels_are_indices_into_all() {
        for (i, k) in RegionKind::ALL.into_iter().enumerate() {
            assert_eq!(k.label() as usize, i);
            assert_eq!(RegionKind::from_label(k.label()), k);
        }
    }
}
