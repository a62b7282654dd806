//! The stats files of a run (`stats/*.json`): what each process writes about itself
//! while it runs and when it stops, and what the launcher's soak, the end-to-end
//! tests and people read. One type per file, written and read through the same
//! serde definition, so a writer and a reader cannot disagree on a field's name
//! (a renamed field fails to parse instead of reading as a silent zero).
//!
//! Files: `learner.json` ([`LearnerStats`]), `curriculum.json` ([`CurriculumStats`]),
//! `actor-K.live.json` while actor K runs and `actor-K.I.json` when its incarnation I
//! ends ([`ActorStats`]; names from [`actor_live`] and [`actor_final`]).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// What a process is doing, or why it ended (the `status` of its stats file).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ProcessStatus {
    /// Still running.
    #[serde(rename = "running")]
    Running,
    /// Stopped by the launcher (a learner's final checkpoint is written).
    #[serde(rename = "stopped")]
    Stopped,
    /// An actor whose step stream ended on its own (its learner is gone).
    #[serde(rename = "ended")]
    Ended,
    /// An actor stopped before the learner came up (it sent nothing).
    #[serde(rename = "stopped before the learner came up")]
    StoppedBeforeLearner,
    /// The learner reached `runtime.max_updates`.
    #[serde(rename = "max_updates")]
    MaxUpdates,
    /// The learner reached `runtime.max_env_steps`.
    #[serde(rename = "max_env_steps")]
    MaxEnvSteps,
}

impl ProcessStatus {
    /// The word written in the stats file (and the launcher's done marker).
    pub fn as_str(self) -> &'static str {
        match self {
            ProcessStatus::Running => "running",
            ProcessStatus::Stopped => "stopped",
            ProcessStatus::Ended => "ended",
            ProcessStatus::StoppedBeforeLearner => "stopped before the learner came up",
            ProcessStatus::MaxUpdates => "max_updates",
            ProcessStatus::MaxEnvSteps => "max_env_steps",
        }
    }
}

impl std::fmt::Display for ProcessStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The learner's replay-ratio limiter counters (its `RateLimiter`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimiterCounters {
    /// Steps before the first update.
    pub warmup: u64,
    /// Inserted steps per update.
    pub interval: u64,
    /// How many updates the learner may fall behind before inserts block.
    pub slack: u64,
    /// Steps inserted so far.
    pub inserted: u64,
    /// Updates done so far.
    pub updates: u64,
}

/// One actor incarnation's stream as its sender counts it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActorStats {
    /// Actor id.
    pub actor: u32,
    /// Which start of this actor (1 for the first).
    pub incarnation: u32,
    /// Its process id.
    pub pid: u32,
    /// Running, or why it ended.
    pub status: ProcessStatus,
    /// Step records sent.
    pub steps_sent: u64,
    /// Wrapping sum of the records' CRC-32s (the learner sums the same).
    pub checksum: u32,
    /// Episodes finished.
    pub episodes: u64,
    /// Distinct policy versions it acted with.
    pub policy_versions_used: u64,
    /// The first of them.
    pub first_policy_version: Option<u64>,
    /// The last of them.
    pub last_policy_version: Option<u64>,
    /// Tasks received from the curriculum service.
    pub tasks_received: u64,
    /// The last task's id.
    pub last_task_id: u64,
    /// Step records sent again because a learner asked (it restarted, or records were
    /// lost on the way); they count once in `steps_sent` and `checksum`.
    pub records_resent: u64,
    /// Times a learner asked.
    pub resend_requests: u64,
    /// Times the actor's window was full with no acknowledgement for a while and it
    /// sent everything it held again unasked.
    #[serde(default)]
    pub resend_timeouts: u64,
    /// Episode reports sent again because word that they were taken did not come in
    /// time (a curriculum service, bridge or link that was away), or because a
    /// restarted curriculum service said it lacked them.
    #[serde(default)]
    pub reports_resent: u64,
    /// Episode reports given up unacknowledged to make room in the actor's window.
    #[serde(default)]
    pub reports_given_up: u64,
    /// Episode reports the curriculum service has not said it took (at the end: sent
    /// to nobody who confirmed it).
    #[serde(default)]
    pub reports_unacknowledged: u64,
}

/// Jumps a [`StreamTally`] keeps the ranges of (the first ones; `resumed` counts all).
pub const JUMPS_KEPT: usize = 64;

/// One actor incarnation's stream as one learner process received it. The records a
/// learner takes from a stream are one increasing run of sequence numbers from
/// `first_seq`, one by one ([`crate::reliable`]), except jumps over records a learner
/// before it took (`resumed`, their ranges in `jumped`): `records` records in all, none
/// inside a jumped range. A learner that replaced a killed one may start below where
/// its predecessor ended (records sent again).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StreamTally {
    /// Actor id.
    pub actor: u32,
    /// The actor's incarnation.
    pub incarnation: u32,
    /// Sequence number of the first record taken (`None`: none taken yet).
    pub first_seq: Option<u64>,
    /// Records taken.
    pub records: u64,
    /// Wrapping sum of their CRC-32s.
    pub checksum: u32,
    /// Records dropped because records before them were missing (they were asked for
    /// again); 0 on a stream that crossed no learner restart.
    pub out_of_order: u64,
    /// Records dropped because they had been taken already (sent again).
    pub duplicates: u64,
    /// Jumps over records a learner before this one took ([`crate::reliable::Verdict::Resume`]):
    /// 0 on one machine, where an acknowledgement reaches the actor before its next record.
    #[serde(default)]
    pub resumed: u64,
    /// The records each jump went over, `[from, to)`, in order (the first [`JUMPS_KEPT`]).
    #[serde(default)]
    pub jumped: Vec<[u64; 2]>,
}

/// The learner process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LearnerStats {
    /// Running, stopped, or the budget that ended the run.
    pub status: ProcessStatus,
    /// Its process id.
    pub pid: u32,
    /// Updates done (over the whole run).
    pub updates: u64,
    /// The update count of the checkpoint this process resumed from, if it did.
    pub resumed_from_update: Option<u64>,
    /// Step records this process received.
    pub received_this_process: u64,
    /// Step records received over the whole run (all learner processes).
    pub received_total: u64,
    /// The replay-ratio limiter's counters.
    pub limiter: LimiterCounters,
    /// Every actor incarnation's stream this process received.
    pub streams: Vec<StreamTally>,
}

/// When the PassFirstTask gate opened, as the curriculum service saw it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GateOpened {
    /// Episodes reported when it opened (the one that opened it included).
    pub episodes: u64,
    /// Decision steps of those episodes.
    pub decision_steps: u64,
}

/// How many episode reports of one actor incarnation the curriculum service holds:
/// every one numbered below `taken` (its actor made `episodes` reports; equal when
/// none was lost).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReportsTaken {
    /// Actor id.
    pub actor: u32,
    /// The actor's incarnation.
    pub incarnation: u32,
    /// Every report of that incarnation numbered below this was taken.
    pub taken: u64,
}

/// What a bridge moved (`stats/bridge.json`, written by a host's bridge process every
/// few seconds and when it stops; `pednav_bridge`'s `Tally` documents each counter).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BridgeStats {
    /// `learner-host` or `actor-host`.
    pub role: String,
    /// The host's name on the link.
    pub host: String,
    /// The run's name on the link.
    pub run: String,
    /// Step records moved (put on the link, or published locally).
    pub step_records: u64,
    /// Their observation bytes.
    pub step_bytes: u64,
    /// Episode reports moved.
    pub episode_reports: u64,
    /// Acknowledgement tables of step records moved.
    pub ack_tables: u64,
    /// Acknowledgement tables of episode reports moved.
    pub report_acks: u64,
    /// Weights versions moved.
    pub weights: u64,
    /// Task requests answered across the link.
    pub tasks: u64,
    /// Heartbeats moved.
    pub heartbeats: u64,
    /// Messages refused.
    pub refused: u64,
    /// Records or reports not delivered (the actor still holds them).
    pub not_delivered: u64,
    /// Times a host's liveliness token was withdrawn.
    pub hosts_gone: u64,
}

/// The curriculum service (written when it stops).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CurriculumStats {
    /// Episodes reported.
    pub episodes: u64,
    /// Tasks handed out.
    pub tasks_issued: u64,
    /// Tasks proposed per category name.
    pub proposed: BTreeMap<String, u64>,
    /// Decision steps of the ACL phase (t_c).
    pub t_c: u64,
    /// Decision steps of every reported episode.
    pub decision_steps: u64,
    /// Whether the run is in the ACL phase.
    pub acl_phase: bool,
    /// When this process saw the gate open (`None` if it opened before a resume, or has not).
    pub first_task_passed: Option<GateOpened>,
    /// Episode reports this process received again after it had taken them (their
    /// acknowledgement had not reached the actor yet): dropped, not counted twice.
    #[serde(default)]
    pub duplicate_reports: u64,
    /// The reports it holds, per actor incarnation (the newest 64 of each actor), as
    /// saved with its state: a restored service's include what its predecessors took.
    #[serde(default)]
    pub reports_taken: Vec<ReportsTaken>,
}

/// The stats name of actor `actor`'s running incarnation: `actor-K.live`.
pub fn actor_live(actor: u32) -> String {
    format!("actor-{actor}.live")
}

/// The stats name of actor `actor`'s ended incarnation `incarnation`: `actor-K.I`.
pub fn actor_final(actor: u32, incarnation: u32) -> String {
    format!("actor-{actor}.{incarnation}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_read_back_as_written_and_a_renamed_field_is_refused() {
        let root = std::env::temp_dir().join(format!("pednav-stats-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let dir = crate::RunDir::new(&root);
        std::fs::create_dir_all(dir.stats()).unwrap();
        let learner = LearnerStats {
            status: ProcessStatus::Stopped,
            pid: 7,
            updates: 40,
            resumed_from_update: None,
            received_this_process: 320,
            received_total: 320,
            limiter: LimiterCounters { warmup: 100, interval: 8, slack: 4, inserted: 320, updates: 40 },
            streams: vec![StreamTally {
                actor: 0,
                incarnation: 1,
                first_seq: Some(0),
                records: 320,
                checksum: 99,
                out_of_order: 0,
                duplicates: 0,
                resumed: 1,
                jumped: vec![[3, 5]],
            }],
        };
        dir.write_stats("learner", &learner).unwrap();
        assert_eq!(dir.read_stats::<LearnerStats>("learner").unwrap(), Some(learner));
        assert_eq!(dir.read_stats::<ActorStats>(&actor_live(3)).unwrap(), None, "no such file yet");
        // A file whose writer spelled a field otherwise does not read as this type.
        std::fs::write(
            dir.stats().join("curriculum.json"),
            r#"{"episodes": 3, "tasks_issued": 3, "proposed": {}, "tc": 0, "decision_steps": 9, "acl_phase": false, "first_task_passed": null}"#,
        )
        .unwrap();
        let err = dir.read_stats::<CurriculumStats>("curriculum").unwrap_err().to_string();
        assert!(err.contains("curriculum.json") && err.contains("tc"), "{err}");
        let _ = std::fs::remove_dir_all(&root);
    }
}
