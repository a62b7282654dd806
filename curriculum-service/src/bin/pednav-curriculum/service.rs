//! The curriculum service as a struct: [`CurriculumService::open`] restores (or
//! starts) the run's curriculum and opens its channels, [`CurriculumService::run`]
//! loops over [`CurriculumService::step`] — answer task requests, take episode
//! reports, log — until stopped, then saves the state.
//!
//! Invariants: the saved state (`checkpoints/curriculum.json`, and a snapshot every
//! 500 episodes) holds the curriculum, the next task id, the per-category counts, the
//! decision steps and which episode reports were taken together, so a restart resumes
//! all of them. A save that fails (a full disk) leaves the last good state on disk;
//! the service keeps serving from memory, says so once per interval, and saves again
//! after the next episodes. Every episode report is taken at most once, by (actor,
//! incarnation, seq), acknowledged as taken at once and as saved once the state on
//! disk holds it ([`pednav_runtime::reports`]): its actor holds it until then, so a
//! report that was on its way when this service (or a bridge between hosts) died is
//! sent again, and so is every report a service killed between two saves took after
//! the last one — the restored service lacks it, says so, and takes it again.

use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use pednav_curriculum::{Category, Curriculum, CurriculumError, EpisodeOutcome, Fit, ServiceState};
use pednav_runtime::ipc::{EpisodeAckPublisher, EpisodeSubscriber, HeartbeatPublisher, TaskServer};
use pednav_runtime::messages::{EpisodeHeader, Faults, Heartbeat, ProcessKind, TaskResponse};
use pednav_runtime::reports::ReportCursors;
use pednav_runtime::stats::{CurriculumStats, GateOpened, ReportsTaken};
use pednav_runtime::write_health::WriteHealth;
use pednav_runtime::{AppendFile, Ipc, Metrics, RunConfig, RunDir, StopFlag, columns};
use pednav_sim::{Pose, Scene};

/// Reported episodes between two saved snapshots of the curriculum state
/// (`checkpoints/curriculum-snapshots/`, what `pednav-plot curriculum` draws over time).
const SNAPSHOT_EVERY_EPISODES: u64 = 500;

/// How often the episode-report acknowledgements are published at most (after new
/// reports, or ones that came again).
const ACKS_EVERY: Duration = Duration::from_millis(100);

/// One row per reported episode: `metrics/episodes.csv` (rows the disk does not
/// take wait in memory, [`AppendFile`]).
struct EpisodeLog {
    file: AppendFile,
}

impl EpisodeLog {
    fn open(dir: &RunDir) -> Result<EpisodeLog> {
        let path = dir.metrics_csv("episodes");
        // A file that is missing, or empty because the header write itself failed before a
        // crash, gets the header; one with rows keeps appending.
        let new = std::fs::metadata(&path).map(|m| m.len() == 0).unwrap_or(true);
        let mut file = AppendFile::open(&path)?;
        if new {
            file.append(format!("{}\n", columns::episodes::HEADER.join(",")).into_bytes());
        }
        Ok(EpisodeLog { file })
    }

    fn write(&mut self, episode: u64, steps: u64, h: &EpisodeHeader, start: Pose, ret: f32) -> Result<()> {
        let line = format!(
            "{episode},{steps},{},{},{},{},{:.3},{:.3},{:.1},{},{ret:.4},{},{}\n",
            h.actor,
            h.env,
            h.task_id,
            category_of(h.category)?.name(),
            start.x,
            start.y,
            start.yaw.to_degrees(),
            h.length,
            h.success,
            h.truncated
        );
        self.file.append(line.into_bytes());
        Ok(())
    }
}

/// The curriculum service of one run.
pub struct CurriculumService {
    cfg: RunConfig,
    dir: RunDir,
    stop: StopFlag,
    curriculum: Curriculum,
    next_task_id: u64,
    /// Tasks proposed per category name (saved with the state).
    proposed: BTreeMap<String, u64>,
    /// Decision steps of every reported episode.
    decision_steps: u64,
    /// When this process saw the PassFirstTask gate open: (episodes, decision steps).
    first_task_passed: Option<(u64, u64)>,
    /// Which reports of every actor were taken (saved with the state).
    report_cursors: ReportCursors,
    /// Which reports the newest state on disk holds (an actor forgets those).
    saved_cursors: ReportCursors,
    /// Reports that came again after they were taken (dropped).
    duplicate_reports: u64,
    /// Whether reports came since the acknowledgements were last published, and when
    /// that was.
    acks_due: bool,
    last_acks: Instant,
    episode_log: EpisodeLog,
    // Kept alive for the ports below.
    _ipc: Ipc,
    server: TaskServer,
    reports: EpisodeSubscriber,
    report_acks: EpisodeAckPublisher,
    heartbeat: HeartbeatPublisher,
    metrics: Metrics,
    last_fit: Option<Fit>,
    last_loss: Option<f32>,
    /// Discounted returns and successes of the last 100 episodes.
    recent: VecDeque<(f32, bool)>,
    last_log: Instant,
    since_save: u64,
    /// Writes that failed (state, snapshots, metrics, the episode log) and are retried.
    health: WriteHealth,
    /// Episodes reported at the newest state on disk.
    last_good: Option<u64>,
}

impl CurriculumService {
    /// The run's curriculum (resumed from its saved state when there is one) and its channels.
    pub fn open(dir: RunDir, stop: StopFlag) -> Result<CurriculumService> {
        let cfg = dir.load_config()?;
        let (curriculum, saved) = load_curriculum(&dir.curriculum_state(), &cfg, cfg.scene()?)?;
        let (next_task_id, proposed, decision_steps, report_cursors) = match saved {
            Some(s) => {
                tracing::info!(
                    episodes = curriculum.episodes(),
                    t_c = curriculum.scheduler().t_c(),
                    acl = curriculum.scheduler().in_acl_phase(),
                    "resumed curriculum state"
                );
                (s.next_task_id, s.proposed, s.decision_steps, s.report_cursors)
            }
            None => (1, BTreeMap::new(), 0, ReportCursors::default()),
        };
        std::fs::create_dir_all(dir.curriculum_snapshots())?;
        let ipc = dir.join_ipc(&cfg, "curriculum", stop.clone())?;
        let server = ipc.task_server()?;
        let reports = ipc.episode_subscriber()?;
        let report_acks = ipc.episode_ack_publisher()?;
        let heartbeat = ipc.heartbeat_publisher()?;
        let metrics = Metrics::open(&dir.metrics(), &dir.tb(), "curriculum")?;
        let episode_log = EpisodeLog::open(&dir)?;
        tracing::info!(variant = ?cfg.curriculum.variant, "curriculum service ready");
        let cfg_metrics_secs = cfg.runtime.metrics_every_secs.max(1.0);
        let resumed_at = (curriculum.episodes() > 0).then(|| curriculum.episodes());
        Ok(CurriculumService {
            cfg,
            dir,
            stop,
            curriculum,
            next_task_id,
            proposed,
            decision_steps,
            first_task_passed: None,
            // The first acknowledgements go out at once: a resumed service's say what its
            // state holds (the actors forget those, and send again what it lacks), a
            // fresh one's that it holds nothing.
            acks_due: true,
            saved_cursors: report_cursors.clone(),
            report_cursors,
            duplicate_reports: 0,
            last_acks: Instant::now(),
            episode_log,
            _ipc: ipc,
            server,
            reports,
            report_acks,
            heartbeat,
            metrics,
            last_fit: None,
            last_loss: None,
            recent: VecDeque::new(),
            last_log: Instant::now(),
            since_save: 0,
            health: WriteHealth::new(Duration::from_secs_f64(cfg_metrics_secs)),
            last_good: resumed_at,
        })
    }

    /// Step until stopped, then save the state and the final counters.
    pub fn run(mut self) -> Result<()> {
        while !self.stop.is_set() {
            if !self.step()? {
                std::thread::sleep(Duration::from_micros(500));
            }
        }
        // The last (partial) interval gets its metrics row too.
        self.log_interval()?;
        self.final_save()?;
        // The last acknowledgements, after the state that holds their reports is saved.
        self.publish_acks();
        let c = &self.curriculum;
        self.dir.write_stats(
            "curriculum",
            &CurriculumStats {
                episodes: c.episodes(),
                tasks_issued: self.next_task_id - 1,
                proposed: self.proposed.clone(),
                t_c: c.scheduler().t_c(),
                decision_steps: self.decision_steps,
                acl_phase: c.scheduler().in_acl_phase(),
                first_task_passed: self
                    .first_task_passed
                    .map(|(episodes, decision_steps)| GateOpened { episodes, decision_steps }),
                duplicate_reports: self.duplicate_reports,
                reports_taken: self
                    .report_cursors
                    .streams()
                    .map(|(actor, incarnation, taken)| ReportsTaken { actor, incarnation, taken })
                    .collect(),
            },
        )?;
        tracing::info!(episodes = c.episodes(), "curriculum service stopped; state saved");
        Ok(())
    }

    /// Answer every waiting task request, take every waiting episode report, and log
    /// when the interval is over; returns whether there was anything to do.
    pub fn step(&mut self) -> Result<bool> {
        let mut busy = self.answer_requests()?;
        busy |= self.take_reports()?;
        if self.acks_due && self.last_acks.elapsed() >= ACKS_EVERY {
            self.publish_acks();
        }
        if self.last_log.elapsed().as_secs_f64() >= self.cfg.runtime.metrics_every_secs {
            self.last_log = Instant::now();
            self.log_interval()?;
        }
        Ok(busy)
    }

    fn answer_requests(&mut self) -> Result<bool> {
        let mut busy = false;
        while let Some(request) = self.server.receive().map_err(|e| anyhow::anyhow!("task server: {e:?}"))? {
            busy = true;
            let p = self.curriculum.propose()?;
            if p.fit.is_some() {
                self.last_fit = p.fit;
            }
            *self.proposed.entry(p.category.name().to_string()).or_default() += 1;
            let response = TaskResponse {
                x: p.pose.x,
                y: p.pose.y,
                yaw: p.pose.yaw,
                category: p.category.code(),
                task_id: self.next_task_id,
                ..TaskResponse::default()
            }
            .with_cycle(p.cycle);
            self.next_task_id += 1;
            if let Err(e) = request.send_copy(response) {
                tracing::warn!(actor = request.payload().actor, "task response not delivered: {e:?}");
            }
        }
        Ok(busy)
    }

    /// Publish which reports were taken and which are saved: every actor stops
    /// sending the ones it holds below its entry's `taken` and forgets those below
    /// `saved` (a lost table is replaced by the next: reports keep coming, or come
    /// again, and each makes a new one due, as does every save).
    fn publish_acks(&mut self) {
        self.acks_due = false;
        self.last_acks = Instant::now();
        if let Err(e) = self.report_acks.send_copy(self.report_cursors.table(&self.saved_cursors)) {
            tracing::warn!("episode report acknowledgements not published (sent again after the next report): {e:?}");
        }
    }

    /// Take every waiting episode report once: one that comes again (its actor had
    /// not heard of it yet) is dropped and acknowledged again.
    fn take_reports(&mut self) -> Result<bool> {
        let mut busy = false;
        while let Some(sample) = self.reports.receive().map_err(|e| anyhow::anyhow!("episode subscriber: {e:?}"))? {
            busy = true;
            self.acks_due = true;
            let h = *sample.user_header();
            if !self.report_cursors.is_new(&h) {
                self.duplicate_reports += 1;
                continue;
            }
            let points = sample.payload();
            let category = category_of(h.category);
            if points.len() != h.length as usize + 1 || category.is_err() {
                tracing::warn!(
                    actor = h.actor,
                    env = h.env,
                    category = h.category,
                    "episode report with {} points for {} steps, or of an unknown category: ignored",
                    points.len(),
                    h.length
                );
                // Refused for good: acknowledged, so that it is not sent again.
                self.report_cursors.handled(&h);
                continue;
            }
            let start = Pose { x: points[0].x, y: points[0].y, yaw: points[0].yaw };
            let outcome = EpisodeOutcome {
                category: category?,
                poses: points.iter().map(|p| Pose { x: p.x, y: p.y, yaw: p.yaw }).collect(),
                rewards: points[1..].iter().map(|p| p.reward).collect(),
                truncated: h.truncated != 0,
                success: h.success != 0,
                start_cycle: h.start_cycle(),
            };
            drop(sample);
            // Taken before it is recorded: a save inside `record` holds the report and
            // the cursor that says so together.
            self.report_cursors.handled(&h);
            self.record(&h, start, &outcome)?;
        }
        Ok(busy)
    }

    /// One reported episode: Algorithm 1's update, the episode log, snapshots and saves.
    fn record(&mut self, h: &EpisodeHeader, start: Pose, outcome: &EpisodeOutcome) -> Result<()> {
        let was_acl = self.curriculum.scheduler().in_acl_phase();
        let summary = self.curriculum.report(outcome)?;
        self.decision_steps += h.length as u64;
        let episodes = self.curriculum.episodes();
        if !was_acl && self.curriculum.scheduler().in_acl_phase() {
            // The PassFirstTask gate opened with this episode (NavACL⁺).
            self.first_task_passed = Some((episodes, self.decision_steps));
            tracing::info!(episodes, decision_steps = self.decision_steps, "PassFirstTask passed: ACL phase starts");
        }
        if let Some(l) = summary.trained_loss {
            self.last_loss = Some(l);
        }
        self.episode_log.write(episodes, self.decision_steps, h, start, summary.discounted_return)?;
        self.health.rows("episode log", self.episode_log.file.failure());
        if episodes.is_multiple_of(SNAPSHOT_EVERY_EPISODES) {
            let name = format!("ep{episodes:08}-steps{}.json", self.decision_steps);
            let outcome = self.save(&self.dir.curriculum_snapshots().join(name));
            // A lost snapshot costs a point of the curriculum plot, not the run's state: logged,
            // not a heartbeat fault.
            self.record_save(
                "snapshot",
                Faults::NONE,
                outcome,
                "the snapshot is skipped; the next one is due in 500 episodes",
            );
        }
        self.recent.push_back((summary.discounted_return, outcome.success));
        if self.recent.len() > 100 {
            self.recent.pop_front();
        }
        self.since_save += 1;
        if self.since_save >= self.cfg.runtime.curriculum_save_every_episodes {
            let outcome = self.save(&self.dir.curriculum_state());
            if outcome.is_ok() {
                self.last_good = Some(episodes);
                self.saved();
            }
            self.record_save(
                "curriculum state",
                Faults::STATE,
                outcome,
                "serving goes on; retried after the next episodes",
            );
            self.since_save = 0;
        }
        Ok(())
    }

    /// The state on disk now holds every report taken so far: their actors may forget
    /// them (said with the next acknowledgements).
    fn saved(&mut self) {
        self.saved_cursors = self.report_cursors.clone();
        self.acks_due = true;
    }

    /// Log a failed save once per interval (it is retried at the next one), or its recovery.
    fn record_save(&mut self, what: &'static str, fault: Faults, outcome: Result<()>, meanwhile: &str) {
        match outcome {
            Ok(()) => self.health.succeeded(what),
            Err(e) => {
                let disk_full = e.downcast_ref::<CurriculumError>().is_some_and(CurriculumError::is_disk_full);
                let last = self.last_good.map_or("none yet".into(), |n| format!("after {n} episodes"));
                self.health.failed(
                    what,
                    fault,
                    disk_full,
                    &format!("{e:#}"),
                    &format!("{meanwhile}; last good state: {last}"),
                );
            }
        }
    }

    /// The state at stop ([`pednav_runtime::generations::final_save`]); an error naming
    /// the cause when no attempt succeeds.
    fn final_save(&mut self) -> Result<()> {
        let path = self.dir.curriculum_state();
        pednav_runtime::generations::final_save("final curriculum state", || self.save(&path))
            .map_err(|e| e.context("the final curriculum state could not be written"))?;
        self.saved();
        Ok(())
    }

    /// Metrics row, log line and heartbeat; statistics that do not exist yet (no
    /// episode, no fit) are not written.
    fn log_interval(&mut self) -> Result<()> {
        let c = &self.curriculum;
        let s = c.scheduler();
        let n = self.recent.len();
        let mean_return = (n > 0).then(|| self.recent.iter().map(|r| r.0 as f64).sum::<f64>() / n as f64);
        let success = (n > 0).then(|| self.recent.iter().filter(|r| r.1).count() as f64 / n as f64);
        let count = |cat: Category| Some(self.proposed.get(cat.name()).copied().unwrap_or(0) as f64);
        let values = [
            ("episodes", Some(c.episodes() as f64)),
            ("phase_acl", Some(if s.in_acl_phase() { 1.0 } else { 0.0 })),
            ("t_c", Some(s.t_c() as f64)),
            ("first_task_mean_return", s.gate().mean().map(|m| m as f64)),
            ("mean_return_100", mean_return),
            ("success_rate_100", success),
            ("mu", self.last_fit.map(|f| f.mu as f64)),
            ("sigma", self.last_fit.map(|f| f.sigma as f64)),
            ("fr_loss", self.last_loss.map(|l| l as f64)),
            ("n_first", count(Category::First)),
            ("n_fixed", count(Category::Fixed)),
            ("n_easy", count(Category::Easy)),
            ("n_frontier", count(Category::Frontier)),
            ("n_random", count(Category::Random)),
            ("n_hard", count(Category::Hard)),
        ];
        self.metrics.log_optional(c.episodes(), &values)?;
        self.health.metrics(&self.metrics);
        tracing::info!(
            episodes = c.episodes(),
            acl = s.in_acl_phase(),
            t_c = s.t_c(),
            first_task_mean = ?s.gate().mean(),
            mu = ?self.last_fit.map(|f| f.mu),
            sigma = ?self.last_fit.map(|f| f.sigma),
            loss = ?self.last_loss,
            proposed = ?self.proposed,
            "curriculum"
        );
        let _ = self.heartbeat.send_copy(Heartbeat {
            kind: ProcessKind::CURRICULUM,
            pid: std::process::id(),
            phase: s.in_acl_phase() as u32,
            acl_steps: s.t_c(),
            episodes: c.episodes(),
            recent_return: mean_return.map_or(f32::NAN, |m| m as f32),
            last_good: self.last_good.unwrap_or(0),
            faults: self.health.faults(),
            ..Heartbeat::default()
        });
        Ok(())
    }

    fn save(&self, path: &Path) -> Result<()> {
        let state = ServiceState {
            curriculum: self.curriculum.state()?,
            next_task_id: self.next_task_id,
            proposed: self.proposed.clone(),
            decision_steps: self.decision_steps,
            report_cursors: self.report_cursors.clone(),
        };
        Ok(state.save(path)?)
    }
}

/// The run's curriculum, restored from the saved state at `path` when there is one.
/// A damaged or missing newest state falls back to the previous generation
/// ([`ServiceState::load_or_previous`]).
pub fn load_curriculum(path: &Path, cfg: &RunConfig, scene: Scene) -> Result<(Curriculum, Option<ServiceState>)> {
    if !ServiceState::exists(path) {
        return Ok((Curriculum::new(cfg.curriculum.clone(), scene, cfg.sim.dt, cfg.curriculum_seed())?, None));
    }
    let (saved, read) = ServiceState::load_or_previous(path)?;
    let curriculum =
        Curriculum::from_saved(cfg.curriculum.clone(), scene, cfg.sim.dt, cfg.curriculum_seed(), &saved.curriculum)
            .with_context(|| format!("restoring {}", read.display()))?;
    Ok((curriculum, Some(saved)))
}

/// The category of an episode report's wire code; an unknown code names itself.
fn category_of(code: u32) -> Result<Category> {
    Category::from_code(code).with_context(|| format!("unknown curriculum category code {code} in an episode report"))
}
