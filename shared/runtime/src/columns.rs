//! The columns of the metrics CSVs (`metrics/<process>.csv`), named once: each process
//! writes its rows with these names and every reader (`pednav-plot`, `pednav-diagnose`,
//! the launcher's soak) looks them up by the same constants, so a renamed column cannot
//! silently empty a plot or a soak figure. The first column of every process CSV is
//! [`STEP`] (written by [`crate::Metrics`] itself). Columns only one reader looks at
//! (most of `episodes.csv`, all of `curriculum.csv`) are named where they are written.

/// The x of every row: env steps received (learner), reported episodes (curriculum),
/// steps sent (actor).
pub const STEP: &str = "step";

/// `metrics/learner.csv`.
pub mod learner {
    /// Seconds since this learner process started.
    pub const ELAPSED_S: &str = "elapsed_s";
    /// Updates done over the run.
    pub const UPDATES: &str = "updates";
    /// Env steps received per second over the interval.
    pub const ENV_STEPS_PER_S: &str = "env_steps_per_s";
    /// Updates per second over the interval.
    pub const UPDATES_PER_S: &str = "updates_per_s";
    /// Milliseconds per update (the DSAC update alone).
    pub const UPDATE_MS: &str = "update_ms";
    /// Milliseconds per batch drawn from the replay.
    pub const SAMPLE_MS: &str = "sample_ms";
    /// Terminal transitions stored.
    pub const REPLAY_TERMINAL: &str = "replay_terminal";
    /// Non-terminal transitions stored.
    pub const REPLAY_NONTERMINAL: &str = "replay_nonterminal";
    /// Critic (quantile Huber) loss, interval mean.
    pub const CRITIC_LOSS: &str = "critic_loss";
    /// Policy loss, interval mean.
    pub const POLICY_LOSS: &str = "policy_loss";
    /// Fraction-proposal loss, interval mean.
    pub const FRACTION_LOSS: &str = "fraction_loss";
    /// Temperature loss, interval mean.
    pub const ALPHA_LOSS: &str = "alpha_loss";
    /// Temperature α, interval mean.
    pub const ALPHA: &str = "alpha";
    /// Policy entropy estimate, interval mean.
    pub const ENTROPY: &str = "entropy";
    /// Mean Q of the batches, interval mean.
    pub const Q_MEAN: &str = "q_mean";
    /// Updates skipped by the non-finite guard, over the run.
    pub const SKIPPED_UPDATES: &str = "skipped_updates";
    /// State-prediction loss (only with `dsac.state_aux_weight` > 0).
    pub const STATE_LOSS: &str = "state_loss";
    /// Temporal contrastive loss (only with `dsac.contrast_weight` > 0).
    pub const CONTRAST_LOSS: &str = "contrast_loss";

    /// Every column the learner writes in every configuration (after [`super::STEP`]).
    pub const ALWAYS: [&str; 16] = [
        ELAPSED_S,
        UPDATES,
        ENV_STEPS_PER_S,
        UPDATES_PER_S,
        UPDATE_MS,
        SAMPLE_MS,
        REPLAY_TERMINAL,
        REPLAY_NONTERMINAL,
        CRITIC_LOSS,
        POLICY_LOSS,
        FRACTION_LOSS,
        ALPHA_LOSS,
        ALPHA,
        ENTROPY,
        Q_MEAN,
        SKIPPED_UPDATES,
    ];
}

/// `metrics/episodes.csv` (written by the curriculum service, one row per episode; its
/// own header, [`episodes::HEADER`], not the [`STEP`]-first layout of [`crate::Metrics`]).
pub mod episodes {
    /// Every column, in the order the curriculum service writes them.
    pub const HEADER: [&str; 13] = [
        "episode",
        DECISION_STEPS,
        "actor",
        "env",
        "task_id",
        "category",
        "x",
        "y",
        "yaw_deg",
        "length",
        DISCOUNTED_RETURN,
        "success",
        "truncated",
    ];
    /// Decision steps of all episodes reported so far, this one included.
    pub const DECISION_STEPS: &str = "decision_steps";
    /// The episode's discounted return.
    pub const DISCOUNTED_RETURN: &str = "discounted_return";
}

/// `metrics/actor-K.csv`.
pub mod actor {
    /// Env steps per second over the interval.
    pub const STEPS_PER_S: &str = "steps_per_s";
    /// Episodes finished.
    pub const EPISODES: &str = "episodes";
    /// Weights version in use.
    pub const POLICY_VERSION: &str = "policy_version";
    /// Mean discounted return of recent episodes.
    pub const RECENT_RETURN: &str = "recent_return";
    /// Milliseconds of policy inference per env step.
    pub const INFERENCE_MS_PER_STEP: &str = "inference_ms_per_step";
    /// Milliseconds of physics per env step.
    pub const SIM_MS_PER_STEP: &str = "sim_ms_per_step";
    /// Milliseconds of rendering and sending per env step.
    pub const RENDER_SEND_MS_PER_STEP: &str = "render_send_ms_per_step";
    /// With traffic: the reward for entering a zebra outside WALK paid in episodes
    /// starting now (`curriculum.entry_reward_ramp` ramps it); empty without traffic.
    pub const ZEBRA_ENTRY_REWARD: &str = "zebra_entry_reward";
    /// With traffic: steps onto a zebra outside WALK so far (this incarnation); empty without.
    pub const DONT_WALK_ENTRIES: &str = "dont_walk_entries";
    /// With traffic: vehicle hits so far (this incarnation); empty without.
    pub const VEHICLE_HITS: &str = "vehicle_hits";

    /// Every column an actor writes (after [`super::STEP`]).
    pub const ALL: [&str; 10] = [
        STEPS_PER_S,
        EPISODES,
        POLICY_VERSION,
        RECENT_RETURN,
        INFERENCE_MS_PER_STEP,
        SIM_MS_PER_STEP,
        RENDER_SEND_MS_PER_STEP,
        ZEBRA_ENTRY_REWARD,
        DONT_WALK_ENTRIES,
        VEHICLE_HITS,
    ];
}
