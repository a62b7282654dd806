//! What the soak sees of the run while it runs: the learner's metrics rows and stats
//! (tagged by pid) and each actor incarnation's live stats, polled every [`POLL`] —
//! across hosts, the learner's from the learner host's run directory and the actors'
//! from the actor host's.

use super::*;

/// One read of the learner's `metrics/learner.csv`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Sample {
    /// Seconds after the launch it was read.
    pub(super) t: f64,
    pub(super) env_steps: u64,
    pub(super) updates: u64,
}

/// One distinct `stats/learner.json` as read.
#[derive(Clone, Copy, Debug)]
pub(super) struct LearnerPoint {
    pub(super) t: f64,
    pub(super) pid: u64,
    pub(super) updates: u64,
    pub(super) env_steps: u64,
    pub(super) resumed_from: Option<u64>,
    /// `received_total` the process resumed with (its checkpoint's).
    pub(super) resumed_env_steps: u64,
}

/// The run's stats and metrics as polled.
pub(super) struct Observer {
    /// The learner's run directory.
    pub(super) dir: RunDir,
    /// The actors' run directory (the same on one host).
    pub(super) actor_dir: RunDir,
    pub(super) actors: u32,
    pub(super) csv_pos: u64,
    pub(super) csv_pending: Vec<u8>,
    pub(super) columns: Option<(usize, usize)>,
    pub(super) samples: Vec<Sample>,
    pub(super) points: Vec<LearnerPoint>,
    /// The last `stats/learner.json` of each learner process (by pid).
    pub(super) learners: BTreeMap<u64, LearnerStats>,
    /// The last `actor-K.live.json` of each (actor, incarnation), and when it was first seen sending.
    pub(super) actors_live: BTreeMap<(u64, u64), (ActorStats, Option<f64>)>,
}

/// A stats file as its writer's type; `None` while it does not exist, or (with a
/// warning) when it does not parse — the soak goes on and its report shows the gap.
pub(super) fn read_stats<T: serde::de::DeserializeOwned>(dir: &RunDir, name: &str) -> Option<T> {
    dir.read_stats(name).unwrap_or_else(|e| {
        tracing::warn!("{e}");
        None
    })
}

impl Observer {
    pub(super) fn new(dir: RunDir, actor_dir: RunDir, actors: u32) -> Observer {
        Observer {
            dir,
            actor_dir,
            actors,
            csv_pos: 0,
            csv_pending: Vec::new(),
            columns: None,
            samples: Vec::new(),
            points: Vec::new(),
            learners: BTreeMap::new(),
            actors_live: BTreeMap::new(),
        }
    }

    pub(super) fn poll(&mut self, t: f64) {
        self.read_csv(t);
        if let Some(v) = read_stats::<LearnerStats>(&self.dir, "learner") {
            let pid = v.pid as u64;
            let point = LearnerPoint {
                t,
                pid,
                updates: v.updates,
                env_steps: v.received_total,
                resumed_from: v.resumed_from_update,
                resumed_env_steps: v.received_total.saturating_sub(v.received_this_process),
            };
            if self
                .points
                .last()
                .is_none_or(|p| (p.pid, p.updates, p.env_steps) != (pid, point.updates, point.env_steps))
            {
                self.points.push(point);
            }
            self.learners.insert(pid, v);
        }
        for k in 0..self.actors {
            if let Some(v) = read_stats::<ActorStats>(&self.actor_dir, &stats::actor_live(k)) {
                let key = (v.actor as u64, v.incarnation as u64);
                let sending = v.steps_sent > 0;
                let entry = self.actors_live.entry(key).or_insert((v.clone(), None));
                if sending && entry.1.is_none() {
                    entry.1 = Some(t);
                }
                entry.0 = v;
            }
        }
    }

    /// Take the complete rows appended to `metrics/learner.csv` since the last read.
    pub(super) fn read_csv(&mut self, t: f64) {
        let Ok(mut f) = std::fs::File::open(self.dir.metrics_csv("learner")) else { return };
        let mut buf = Vec::new();
        if f.seek(SeekFrom::Start(self.csv_pos)).is_err() || f.read_to_end(&mut buf).is_err() {
            return;
        }
        self.csv_pos += buf.len() as u64;
        self.csv_pending.extend_from_slice(&buf);
        while let Some(i) = self.csv_pending.iter().position(|&b| b == b'\n') {
            let line: Vec<u8> = self.csv_pending.drain(..=i).collect();
            let line = String::from_utf8_lossy(&line);
            let cells: Vec<&str> = line.trim_end().split(',').collect();
            match self.columns {
                None => {
                    let col = |name: &str| cells.iter().position(|c| *c == name);
                    self.columns = col(columns::STEP).zip(col(columns::learner::UPDATES));
                }
                Some((s, u)) => {
                    let value = |i: usize| cells.get(i).and_then(|c| c.parse::<f64>().ok());
                    // A row cut short by a kill, continued by the next process, does not parse: skipped.
                    if let (Some(env_steps), Some(updates)) = (value(s), value(u))
                        && cells.len() > s.max(u)
                    {
                        self.samples.push(Sample { t, env_steps: env_steps as u64, updates: updates as u64 });
                    }
                }
            }
        }
    }

    pub(super) fn last_sample(&self) -> Option<Sample> {
        self.samples.last().copied()
    }
}
