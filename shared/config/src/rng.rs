//! The random streams of a run, named once. A run has one `seed`; every consumer of
//! randomness draws from its own ChaCha stream of that seed (`set_stream`), or seeds its
//! own generator with a value derived from it here — so that adding a consumer, or
//! drawing more in one, changes no other consumer's numbers, and one `--seed` still
//! decides everything.
//!
//! Invariant: no two consumers share a stream of the same seed; every stream id and
//! derivation of the run's seed used anywhere in pednav is defined in this module. One
//! level down, an episode's seed (drawn by its actor from the actor's seed) drives the
//! simulator's streams of that episode — its traffic and its domain randomisation —
//! which `pednav-sim` derives itself, as it has no run.

/// `set_stream` ids of ChaCha generators seeded with the run's seed.
pub mod stream {
    /// Initial weights of the policy network.
    pub const POLICY_INIT: u64 = 1;
    /// Initial weights of the fraction-proposal network.
    pub const FRACTION_INIT: u64 = 2;
    /// Initial weights of the quantile network (and its target, a copy).
    pub const QUANTILE_INIT: u64 = 3;
    /// Initial weights of the second critic of twin critics (and its target).
    pub const TWIN_CRITIC_INIT: u64 = 4;
    /// Initial weights of the state-prediction head.
    pub const STATE_HEAD_INIT: u64 = 5;
    /// Initial weights of the contrastive head.
    pub const CONTRAST_HEAD_INIT: u64 = 6;
    /// The learner's replay batch sampler.
    pub const BATCH_SAMPLER: u64 = 7;
    /// The learned policy's action noise, per episode seed (actors, evaluation).
    pub const ACTING_NOISE: u64 = 11;
    /// The learner's own draws in an update (next actions, reparameterised samples).
    pub const LEARNER_UPDATE: u64 = 100;
}

/// The curriculum service's seed (task sampling; the task-value net adds its own mix).
pub fn curriculum_seed(run_seed: u64) -> u64 {
    run_seed ^ 0x6375_7272_6963_756c // "curricul"
}

/// The task-value net's seed, from the curriculum's.
pub fn task_net_seed(curriculum_seed: u64) -> u64 {
    curriculum_seed ^ 0x6E65_7477 // "netw"
}

/// Actor `actor`'s seed in its `incarnation` (a restarted actor draws new episodes).
pub fn actor_seed(run_seed: u64, actor: u32, incarnation: u32) -> u64 {
    run_seed ^ (actor as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ ((incarnation as u64) << 48)
}

/// The seed of the untrained network `pednav-diagnose` compares the trained encoder with
/// (a different initialisation than the run's own, so "untrained" is not "the run at
/// update 0").
pub fn untrained_reference_seed(run_seed: u64) -> u64 {
    run_seed.wrapping_add(1)
}

/// The seed of the candidate tasks a curriculum classification draws (`classify`:
/// the maps of a run's curriculum snapshots): one fixed seed, not the run's, so that
/// snapshots of any two runs are classified on the same candidates.
pub const CLASSIFICATION_CANDIDATES: u64 = 1;

/// The seed of a probe's example order over its epochs (`pednav_experiments::probe`),
/// from the probe's own seed (which initialises its weights).
pub fn probe_order_seed(probe_seed: u64) -> u64 {
    probe_seed ^ 0x00c0_ffee
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stream_ids_are_distinct_and_derived_seeds_differ_from_the_run_seed() {
        let ids = [
            stream::POLICY_INIT,
            stream::FRACTION_INIT,
            stream::QUANTILE_INIT,
            stream::TWIN_CRITIC_INIT,
            stream::STATE_HEAD_INIT,
            stream::CONTRAST_HEAD_INIT,
            stream::BATCH_SAMPLER,
            stream::ACTING_NOISE,
            stream::LEARNER_UPDATE,
        ];
        let distinct: std::collections::BTreeSet<u64> = ids.into_iter().collect();
        assert_eq!(distinct.len(), ids.len());
        let seed = 7;
        let derived = [
            curriculum_seed(seed),
            task_net_seed(curriculum_seed(seed)),
            actor_seed(seed, 0, 1),
            actor_seed(seed, 1, 1),
            actor_seed(seed, 0, 2),
            untrained_reference_seed(seed),
            probe_order_seed(seed),
        ];
        let distinct: std::collections::BTreeSet<u64> = derived.into_iter().chain([seed]).collect();
        assert_eq!(distinct.len(), derived.len() + 1);
    }
}
