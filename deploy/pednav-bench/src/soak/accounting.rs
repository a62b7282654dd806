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

/// One learner process's count of one stream: the records it took are `records`
/// increasing sequence numbers from `first`, one by one, except the ranges it jumped
/// over (its cursor takes nothing out of order; see [`Received::spans`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Received {
    /// The first record's sequence number (`None`: it took none).
    pub first: Option<u64>,
    /// Records it took.
    pub records: u64,
    /// The CRC-32 sum of those records.
    pub checksum: u32,
    /// The ranges `[from, to)` it jumped over (records a learner before it took), in order.
    pub jumped: Vec<[u64; 2]>,
}

impl Received {
    /// The records it took, as contiguous spans `[a, b)`: from `first`, `records` in
    /// all, stepping over each jumped range.
    pub fn spans(&self) -> Vec<(u64, u64)> {
        let Some(first) = self.first else { return Vec::new() };
        let (mut spans, mut at, mut left) = (Vec::new(), first, self.records);
        for &[from, to] in &self.jumped {
            if from < at || to < from {
                continue; // not after what it took so far: not a jump of this run
            }
            let n = (from - at).min(left);
            if n > 0 {
                spans.push((at, at + n));
            }
            left -= n;
            at = to;
        }
        if left > 0 {
            spans.push((at, at + left));
        }
        spans
    }
}

/// The accounting of one actor incarnation's stream.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// Everything sent arrived once: count and checksum equal.
    Whole,
    /// Everything sent arrived; this many records twice, at two learner processes (a
    /// learner that replaced a killed one is sent again what its predecessor took but
    /// had not acknowledged). The checksums of overlapping counts are not comparable.
    WholeResent(u64),
    /// The sender was killed: at least everything it last reported sending arrived
    /// (what it sent after that report is not known).
    SenderKilled,
    /// The stream crossed a learner restart and this many records died with the
    /// killed learner (taken and acknowledged after its last stats write).
    DiedWithLearner(u64),
    /// As [`Verdict::DiedWithLearner`], for a killed sender: at least this many (what
    /// it sent after its last report is not known).
    DiedWithLearnerAtLeast(u64),
    /// Records missing at the learner that no learner restart explains (beyond what
    /// the killed learners could have taken after their last stats write).
    Lost(u64),
    /// As many records arrived as were sent, with another checksum.
    ChecksumMismatch,
    /// Records counted beyond the last one sent.
    Excess(u64),
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
        matches!(self, Verdict::Lost(_) | Verdict::ChecksumMismatch | Verdict::Excess(_))
    }

    pub(super) fn text(self) -> String {
        match self {
            Verdict::Whole => "0 — whole (count and checksum)".into(),
            Verdict::WholeResent(n) => format!("0 — whole; {n} sent again to the restarted learner"),
            Verdict::SenderKilled => "0 — sender killed: all it last reported arrived".into(),
            Verdict::DiedWithLearner(n) => format!("{n} died with the killed learner"),
            Verdict::DiedWithLearnerAtLeast(n) => format!("≥ {n} died with the killed learner (sender killed)"),
            Verdict::Lost(n) => format!("**{n} LOST**"),
            Verdict::ChecksumMismatch => "**checksum mismatch**".into(),
            Verdict::Excess(n) => format!("**{n} more counted than sent**"),
            Verdict::Unknown => "? (no sender stats)".into(),
        }
    }
}

/// What one killed learner may take with it from one actor's stream: the records it
/// took and acknowledged after its last stats write — 1.5 × its intake rate (all
/// actors') × the time since that write as polled, plus one poll interval. (Its intake
/// queue is not lost: the actors hold what it did not acknowledge and send it again.)
pub fn died_allowance(intake_per_s: f64, stats_age_s: f64) -> u64 {
    (1.5 * intake_per_s * (stats_age_s + POLL.as_secs_f64())).ceil() as u64
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
    let Some(sent) = sent else { return Verdict::Unknown };
    let mut spans: Vec<(u64, u64)> = received.iter().flat_map(Received::spans).filter(|(a, b)| b > a).collect();
    spans.sort_unstable();
    let end = spans.iter().map(|s| s.1).max().unwrap_or(0);
    if sent.exact && end > sent.steps {
        return Verdict::Excess(end - sent.steps);
    }
    // Walk the spans in order: what lies between them (below `sent.steps`) is missing,
    // what two of them share arrived twice.
    let (mut reach, mut missing, mut twice) = (0u64, 0u64, 0u64);
    for &(a, b) in &spans {
        missing += a.min(sent.steps).saturating_sub(reach);
        twice += reach.min(b).saturating_sub(a);
        reach = reach.max(b);
    }
    missing += sent.steps.saturating_sub(reach);
    if missing == 0 {
        if !sent.exact {
            return Verdict::SenderKilled;
        }
        if twice > 0 {
            return Verdict::WholeResent(twice);
        }
        let checksum = received.iter().fold(0u32, |c, r| c.wrapping_add(r.checksum));
        return if checksum == sent.checksum { Verdict::Whole } else { Verdict::ChecksumMismatch };
    }
    match died_allowance {
        Some(a) if missing <= a && sent.exact => Verdict::DiedWithLearner(missing),
        Some(a) if missing <= a => Verdict::DiedWithLearnerAtLeast(missing),
        Some(a) => Verdict::Lost(missing - a),
        None => Verdict::Lost(missing),
    }
}
