//! The step accounting per actor incarnation: what it sent against what every learner
//! process counted for it, and what may have died with a killed learner.

use super::*;

/// What one actor incarnation sent, from its stats.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sent {
    /// `steps_sent`.
    pub steps: u64,
    /// The CRC-32 sum of its records.
    pub checksum: u32,
    /// From its final stats (a clean stop); otherwise its last live stats (it was
    /// killed: a lower bound, with a checksum of that many records).
    pub exact: bool,
}

/// One learner process's count of one stream.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Received {
    /// Records it took.
    pub records: u64,
    /// The CRC-32 sum of those records.
    pub checksum: u32,
    /// Sequence gaps it saw.
    pub gaps: u64,
}

/// The accounting of one actor incarnation's stream.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// Everything sent arrived: count and checksum equal, no gaps.
    Whole,
    /// The sender was killed: at least everything it last reported sending arrived
    /// (what it sent after that report is not known).
    SenderKilled,
    /// The stream crossed a learner restart and this many records died with the
    /// killed learner (taken after its last stats write, or in its queue).
    DiedWithLearner(u64),
    /// As [`Verdict::DiedWithLearner`], for a killed sender: at least this many (what
    /// it sent after its last report is not known).
    DiedWithLearnerAtLeast(u64),
    /// Records missing at the learner that no learner restart explains (beyond what
    /// the killed learners could have held).
    Lost(u64),
    /// As many records arrived as were sent, with another checksum.
    ChecksumMismatch,
    /// More records counted than sent.
    Excess(u64),
    /// A learner saw sequence gaps inside the stream.
    Gaps(u64),
    /// No stats of the sender.
    Unknown,
}

impl Verdict {
    /// Records lost on the learner's side (beyond what died with a killed learner).
    pub fn lost(self) -> u64 {
        match self {
            Verdict::Lost(n) => n,
            _ => 0,
        }
    }

    /// Records that died with a killed learner (the documented loss).
    pub fn died_with_learner(self) -> u64 {
        match self {
            Verdict::DiedWithLearner(n) | Verdict::DiedWithLearnerAtLeast(n) => n,
            _ => 0,
        }
    }

    /// Whether this is a failure of the soak.
    pub fn failed(self) -> bool {
        matches!(self, Verdict::Lost(_) | Verdict::ChecksumMismatch | Verdict::Excess(_) | Verdict::Gaps(_))
    }

    pub(super) fn text(self) -> String {
        match self {
            Verdict::Whole => "0 — whole (count and checksum)".into(),
            Verdict::SenderKilled => "0 — sender killed: all it last reported arrived".into(),
            Verdict::DiedWithLearner(n) => format!("{n} died with the killed learner"),
            Verdict::DiedWithLearnerAtLeast(n) => format!("≥ {n} died with the killed learner (sender killed)"),
            Verdict::Lost(n) => format!("**{n} LOST**"),
            Verdict::ChecksumMismatch => "**checksum mismatch**".into(),
            Verdict::Excess(n) => format!("**{n} more counted than sent**"),
            Verdict::Gaps(n) => format!("**{n} sequence gaps**"),
            Verdict::Unknown => "? (no sender stats)".into(),
        }
    }
}

/// What one killed learner may take with it from one actor's stream: its intake queue
/// (`step_buffer` records, plus a round's [`STEP_ROUND_PER_ACTOR`]) and what it could
/// take after its last stats write — 1.5 × its intake rate (all actors') × the time
/// since that write as polled, plus one poll interval.
pub fn died_allowance(step_buffer: u64, intake_per_s: f64, stats_age_s: f64) -> u64 {
    step_buffer + STEP_ROUND_PER_ACTOR as u64 + (1.5 * intake_per_s * (stats_age_s + POLL.as_secs_f64())).ceil() as u64
}

/// The intake rate (env steps/s) of learner `pid` over its last ≥ 3 s of stats before
/// `at`, and how long before `at` its stats last changed.
pub(super) fn intake_before(points: &[LearnerPoint], pid: u64, at: f64) -> Option<(f64, f64)> {
    let mine: Vec<&LearnerPoint> = points.iter().filter(|p| p.pid == pid && p.t <= at).collect();
    let last = *mine.last()?;
    let prev = mine.iter().rev().find(|p| p.t <= last.t - 3.0).or(mine.first())?;
    (last.t - prev.t >= 0.5)
        .then(|| ((last.env_steps.saturating_sub(prev.env_steps)) as f64 / (last.t - prev.t), at - last.t))
}

/// The verdict on one stream: `sent` by the actor incarnation, `received` by each
/// learner process that counted it; `died_allowance` is `None` when the stream crossed
/// no learner restart, else how many of its records may have died with the killed
/// learners ([`died_allowance`], summed over the restarts it crossed).
pub fn account(sent: Option<Sent>, received: &[Received], died_allowance: Option<u64>) -> Verdict {
    let gaps: u64 = received.iter().map(|r| r.gaps).sum();
    if gaps > 0 {
        return Verdict::Gaps(gaps);
    }
    let records: u64 = received.iter().map(|r| r.records).sum();
    let checksum = received.iter().fold(0u32, |c, r| c.wrapping_add(r.checksum));
    let Some(sent) = sent else { return Verdict::Unknown };
    if records > sent.steps && sent.exact {
        return Verdict::Excess(records - sent.steps);
    }
    if records >= sent.steps {
        return match (sent.exact, checksum == sent.checksum) {
            (true, true) => Verdict::Whole,
            (true, false) => Verdict::ChecksumMismatch,
            (false, _) => Verdict::SenderKilled,
        };
    }
    let missing = sent.steps - records;
    match died_allowance {
        Some(a) if missing <= a && sent.exact => Verdict::DiedWithLearner(missing),
        Some(a) if missing <= a => Verdict::DiedWithLearnerAtLeast(missing),
        Some(a) => Verdict::Lost(missing - a),
        None => Verdict::Lost(missing),
    }
}
