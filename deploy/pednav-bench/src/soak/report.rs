//! The soak's report: the Markdown table, `soak.json` and the list of failures, built
//! from the kills, the restarts and what the observer saw.

use pednav_runtime::stats::BridgeStats;

use super::*;

/// Everything the report is made of.
pub(super) struct Report<'a> {
    pub(super) cfg: &'a RunConfig,
    pub(super) config: &'a Path,
    pub(super) seed: u64,
    pub(super) actors: u32,
    pub(super) minutes: f64,
    pub(super) mean: f64,
    pub(super) across_hosts: bool,
    pub(super) link_cut_secs: f64,
    /// The soak's directory (on one host, the run's).
    pub(super) run_dir: &'a Path,
    /// The learner's run directory (across hosts, the learner host's).
    pub(super) learner_dir: &'a Path,
    /// The actors' run directory (across hosts, the actor host's).
    pub(super) actor_dir: &'a Path,
    pub(super) schedule: &'a [PlannedKill],
    pub(super) kills: &'a [KillRecord],
    pub(super) skipped: &'a [PlannedKill],
    pub(super) obs: &'a Observer,
    pub(super) log: &'a LauncherLog,
    pub(super) training_started: Option<f64>,
    pub(super) stopped_at: f64,
    pub(super) end: f64,
    /// Each launcher's exit (on one host, one).
    pub(super) exits: &'a [(Host, ExitStatus)],
    /// The launcher that ended before the soak did.
    pub(super) early: Option<(Host, ExitStatus)>,
    pub(super) interrupted: bool,
}

impl Report<'_> {
    /// How the report names `host`'s launcher: `launcher` on one host.
    fn launcher(&self, host: Host) -> String {
        if self.across_hosts { format!("{} launcher", host.label()) } else { "launcher".into() }
    }

    /// The Markdown report, `soak.json`'s content and the failures.
    pub(super) fn build(&self) -> (String, Value, Vec<String>) {
        let mut failures = Vec::new();
        let mut md = String::new();
        let obs = self.obs;
        let restarts = &self.log.restarts;
        let warmup = self.cfg.dsac.warmup;
        let exits =
            self.exits.iter().map(|(h, e)| format!("{}: {e}", self.launcher(*h))).collect::<Vec<_>>().join(", ");
        md += &format!(
            "## Soak: {} min, seed {}, {} actor(s){}, {}\n\nRun directory `{}`; launched at 0 s, learner updating from \
             {}, stopped (SIGINT) at {:.1} s, exited by {:.1} s ({exits}).\n\n",
            self.minutes,
            self.seed,
            self.actors,
            if self.across_hosts {
                format!(
                    " across two hosts on this machine (a learner host with no actors, an actor host; link through a \
                     loopback relay, cuts of {} s)",
                    self.link_cut_secs
                )
            } else {
                String::new()
            },
            self.config.display(),
            self.run_dir.display(),
            secs(self.training_started),
            self.stopped_at,
            self.end,
        );
        if let Some((host, e)) = self.early {
            failures.push(format!("the {} ended before the soak did ({e})", self.launcher(host)));
        }
        for (host, e) in self.exits {
            if self.early.is_none() && !e.success() {
                failures.push(format!("the {} did not stop cleanly after SIGINT ({e})", self.launcher(*host)));
            }
        }
        if self.interrupted {
            failures.push("the soak was interrupted (Ctrl-C) before its end".into());
        }

        // Kills.
        md += "| # | planned (s) | killed at (s) | victim | pid | env steps at kill | updates at kill | launcher restart | training past the kill's figures after | notes |\n|---|---|---|---|---|---|---|---|---|---|\n";
        let mut used = vec![false; restarts.len()];
        let mut kills_json = Vec::new();
        for (i, k) in self.kills.iter().enumerate() {
            let process = k.plan.victim.process();
            let restart =
                restarts.iter().enumerate().find(|(j, r)| !used[*j] && r.process == process && r.at >= k.at - 0.5).map(
                    |(j, r)| {
                        used[j] = true;
                        r.clone()
                    },
                );
            // After a link cut, training must go on once the link is back.
            let after_restart = match k.plan.victim {
                Victim::Link => k.at + self.link_cut_secs,
                _ => restart.as_ref().map_or(k.at, |r| r.at),
            };
            let new_learner = |p: &&LearnerPoint| p.t > k.at && p.pid != k.pid as u64;
            let continued = k.before.and_then(|b| {
                obs.points
                    .iter()
                    .filter(|p| p.t >= after_restart && (k.plan.victim != Victim::Learner || new_learner(p)))
                    .find(|p| p.updates > b.updates && p.env_steps > b.env_steps)
                    .map(|p| p.t - k.at)
            });
            let mut notes = String::new();
            let mut extra = json!(null);
            match k.plan.victim {
                Victim::Learner => {
                    if let Some(first) = obs.points.iter().find(new_learner) {
                        let resumed = first.resumed_from.unwrap_or(0);
                        let updating = obs
                            .points
                            .iter()
                            .filter(|p| p.pid == first.pid && p.updates > resumed)
                            .map(|p| p.t - k.at)
                            .next();
                        let (b_steps, b_updates) = k.before.map_or((0, 0), |b| (b.env_steps, b.updates));
                        // When the killed learner's stats last changed (as polled): what it took
                        // after that is not in its last count.
                        let stats_age =
                            obs.points.iter().rev().find(|p| p.pid == k.pid as u64 && p.t <= k.at).map(|p| k.at - p.t);
                        let allowance =
                            intake_before(&obs.points, k.pid as u64, k.at).map(|(rate, age)| died_allowance(rate, age));
                        notes = format!(
                            "its stats last changed {} before (≤ {} records of each stream may die with it); resumed \
                             from update {resumed} ({} redone) and env step {} ({} rolled back: received after the \
                             last checkpoint), refill {warmup} steps, updating again after {}",
                            secs(stats_age),
                            allowance.map_or("?".into(), |a| a.to_string()),
                            b_updates.saturating_sub(resumed),
                            first.resumed_env_steps,
                            b_steps.saturating_sub(first.resumed_env_steps),
                            secs(updating)
                        );
                        extra = json!({
                            "killed_learner_stats_age_s": stats_age,
                            "died_allowance_per_stream": allowance,
                            "new_pid": first.pid,
                            "resumed_from_update": first.resumed_from,
                            "resumed_env_steps": first.resumed_env_steps,
                            "updates_redone": b_updates.saturating_sub(resumed),
                            "env_steps_rolled_back": b_steps.saturating_sub(first.resumed_env_steps),
                            "refill_steps": warmup,
                            "updating_again_after_s": updating,
                        });
                    } else {
                        notes = "no stats from a new learner process".into();
                    }
                }
                Victim::Curriculum => {
                    notes = "resumes its saved state (count below)".into();
                }
                Victim::LearnerHostBridge | Victim::ActorHostBridge => {
                    notes = "what it carried is held by the actors and sent again (streams below)".into();
                }
                Victim::Link => {
                    notes = format!("every connection closed, new ones refused for {} s", self.link_cut_secs);
                }
                Victim::Actor(a) => {
                    if let Some(inc) = k.incarnation {
                        let sending = obs.actors_live.get(&(a as u64, inc + 1)).and_then(|(_, t)| *t).map(|t| t - k.at);
                        notes = format!("incarnation {inc} → {}: sending after {}", inc + 1, secs(sending));
                        extra = json!({"incarnation": inc, "replacement_sending_after_s": sending});
                    }
                }
            }
            md += &format!(
                "| {} | {:.1} | {:.1} | {} | {} | {} | {} | {} | {} | {} |\n",
                i + 1,
                k.plan.at_secs,
                k.at,
                process,
                if k.plan.victim.is_process() { k.pid.to_string() } else { "—".into() },
                k.before.map_or("—".into(), |b| b.env_steps.to_string()),
                k.before.map_or("—".into(), |b| b.updates.to_string()),
                match (&restart, k.plan.victim.is_process()) {
                    (Some(r), _) => format!("+{:.1} s (restart {})", r.at - k.at, r.number),
                    (None, true) => "**none**".into(),
                    (None, false) => format!("— (link back after {} s)", self.link_cut_secs),
                },
                continued.map_or("**no**".into(), |c| format!("{c:.1} s")),
                notes
            );
            if restart.is_none() && k.plan.victim.is_process() {
                failures.push(format!("kill {} ({process}): the launcher reported no restart", i + 1));
            }
            if continued.is_none() {
                failures.push(format!(
                    "kill {} ({process}): training did not get past the kill's updates and env steps",
                    i + 1
                ));
            }
            kills_json.push(json!({
                "planned_s": k.plan.at_secs,
                "at_s": k.at,
                "victim": k.plan.victim.kind(),
                "process": process,
                "pid": k.plan.victim.is_process().then_some(k.pid),
                "env_steps_at_kill": k.before.map(|b| b.env_steps),
                "updates_at_kill": k.before.map(|b| b.updates),
                "restart": restart.as_ref().map(|r| json!({"after_s": r.at - k.at, "number": r.number, "status": r.status})),
                "continued_after_s": continued,
                "details": extra,
            }));
        }
        for s in self.skipped {
            md += &format!(
                "| — | {:.1} | skipped | {} | — | | | | | no such process for {VICTIM_WAIT_SECS} s |\n",
                s.at_secs,
                s.victim.process()
            );
        }
        let mut per_kind = BTreeMap::new();
        for &kind in victim_kinds(self.across_hosts) {
            let n = self.kills.iter().filter(|k| k.plan.victim.kind() == kind).count();
            per_kind.insert(kind, n);
            if n == 0 {
                failures.push(format!("no {kind} was killed"));
            }
        }

        // Restarts.
        let mut by_process: BTreeMap<&str, u32> = BTreeMap::new();
        for r in restarts {
            *by_process.entry(&r.process).or_default() += 1;
        }
        let unplanned: Vec<&Restart> = restarts.iter().zip(&used).filter(|(_, u)| !**u).map(|(r, _)| r).collect();
        let curriculum_resumes = std::fs::read_to_string(self.learner_dir.join("logs/curriculum.log"))
            .map_or(0, |l| l.matches("resumed curriculum state").count());
        let curriculum_kills = per_kind["curriculum"];
        md += &format!(
            "\nKills: {} (of {} planned{}). Restarts the launcher{} reported: {} \
             ({} last progress line: {}){}. The curriculum service resumed its saved state {} time(s) \
             for {} restart(s).\n",
            victim_kinds(self.across_hosts)
                .iter()
                .map(|k| format!("{k} {}", per_kind[k]))
                .collect::<Vec<_>>()
                .join(", "),
            self.schedule.len(),
            if self.kills.len() + self.skipped.len() < self.schedule.len() {
                ", the rest fell after the end"
            } else {
                ""
            },
            if self.across_hosts { "s" } else { "" },
            if by_process.is_empty() {
                "none".to_string()
            } else {
                by_process.iter().map(|(p, n)| format!("{p} {n}")).collect::<Vec<_>>().join(", ")
            },
            if self.across_hosts { "the learner host's" } else { "its" },
            self.log.progress_restarts.map_or("—".into(), |n| format!("restarts {n}")),
            if unplanned.is_empty() {
                ", all of them the soak's kills".to_string()
            } else {
                format!(
                    "; **not caused by the soak**: {}",
                    unplanned
                        .iter()
                        .map(|r| format!("{} at {:.1} s ({})", r.process, r.at, r.status))
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            },
            curriculum_resumes,
            by_process.get("curriculum").copied().unwrap_or(0),
        );
        if (curriculum_resumes as u32) < by_process.get("curriculum").copied().unwrap_or(0) {
            failures.push(format!(
                "the curriculum service resumed its state {curriculum_resumes} time(s) after {curriculum_kills} kill(s)"
            ));
        }
        for r in &unplanned {
            failures.push(format!("{} died without a kill at {:.1} s ({})", r.process, r.at, r.status));
        }

        // End figures.
        let last = obs.last_sample();
        let final_learner = read_stats::<LearnerStats>(&RunDir::new(self.learner_dir), "learner");
        let final_status = final_learner.as_ref().map(|v| v.status.as_str());
        md += &format!(
            "\nAt the end (metrics/learner.csv): env steps {}, updates {}; the last learner's status: {} (a final \
             checkpoint is written on `stopped`).\n",
            last.map_or("—".into(), |s| s.env_steps.to_string()),
            last.map_or("—".into(), |s| s.updates.to_string()),
            final_status.unwrap_or("—"),
        );
        if final_learner.as_ref().map(|v| v.status) != Some(ProcessStatus::Stopped) {
            failures.push(format!("the last learner did not stop cleanly (status {final_status:?})"));
        }

        // Step accounting.
        let final_pid = final_learner.as_ref().map(|v| v.pid as u64);
        let mut views: Vec<(u64, &LearnerStats)> = obs.learners.iter().map(|(p, v)| (*p, v)).collect();
        if let (Some(pid), Some(v)) = (final_pid, final_learner.as_ref()) {
            views.retain(|(p, _)| *p != pid);
            views.push((pid, v));
        }
        let mut received: BTreeMap<(u64, u64), Vec<Received>> = BTreeMap::new();
        // Jumps over records a learner before took, per stream: on one host an ack
        // reaches the actor before its next record, so there are none; across hosts a
        // dead learner's last ack can arrive after its replacement took older records
        // (judged with the learner restarts below).
        let mut jumps: BTreeMap<(u64, u64), u64> = BTreeMap::new();
        for (_, v) in &views {
            for s in &v.streams {
                *jumps.entry((s.actor as u64, s.incarnation as u64)).or_default() += s.resumed;
                received.entry((s.actor as u64, s.incarnation as u64)).or_default().push(Received {
                    first: s.first_seq,
                    records: s.records,
                    checksum: s.checksum,
                    jumped: s.jumped.clone(),
                });
            }
        }
        let mut sent: BTreeMap<(u64, u64), Sent> = BTreeMap::new();
        for ((a, i), (v, _)) in &obs.actors_live {
            sent.insert((*a, *i), Sent { steps: v.steps_sent, checksum: v.checksum, exact: false });
        }
        let actor_run = RunDir::new(self.actor_dir);
        for entry in std::fs::read_dir(actor_run.stats()).into_iter().flatten().flatten() {
            let name = entry.file_name().to_string_lossy().to_string();
            let Some(v) = name
                .strip_prefix("actor-")
                .and_then(|n| n.strip_suffix(".json"))
                .and_then(|n| n.split_once('.'))
                .filter(|(a, i)| a.parse::<u64>().is_ok() && i.parse::<u64>().is_ok())
                .and_then(|_| read_stats::<ActorStats>(&actor_run, name.trim_end_matches(".json")))
            else {
                continue;
            };
            sent.insert(
                (v.actor as u64, v.incarnation as u64),
                Sent { steps: v.steps_sent, checksum: v.checksum, exact: true },
            );
        }
        // Each learner restart, with what a stream crossing it may lose (unbounded for a
        // death the soak did not cause: that is a failure of its own).
        let learner_restarts: Vec<(f64, u64)> = restarts
            .iter()
            .filter(|r| r.process == "learner")
            .map(|r| {
                let kill = self.kills.iter().find(|k| {
                    k.plan.victim == Victim::Learner && r.at >= k.at - 0.5 && r.at <= k.at + LEARNER_RESTART_SLACK_SECS
                });
                let allowance = kill
                    .and_then(|k| intake_before(&obs.points, k.pid as u64, k.at))
                    .map_or(u64::MAX, |(rate, age)| died_allowance(rate, age));
                (r.at, allowance)
            })
            .collect();
        let actor_restart = |a: u64, number: u64| {
            restarts.iter().find(|r| r.process == format!("actor-{a}") && r.number as u64 == number).map(|r| r.at)
        };
        md += &format!(
            "\nSteps, actor → learner, per actor incarnation (`stats/actor-K.I.json`, or the last `actor-K.live.json` of \
             a killed one, against the `streams` of every learner process's `stats/learner.json`: each learner's \
             records are one run of sequence numbers, less the ranges it jumped over). A stream that did not cross \
             a learner restart must arrive whole. Across a restart, the actors send the new learner again what the \
             killed one took without acknowledging (its intake queue included); what is still missing died with the killed learner — taken \
             and acknowledged after its last stats write, into its replay (not checkpointed) — and is allowed up to \
             1.5 × the killed learner's intake over the time since its last stats write; anything beyond is lost. A \
             restarted learner refills dsac.warmup = {warmup} steps before updating.\n\n| \
             stream (actor.incarnation) | sent | received | learner processes | may die with killed learners | lost \
             |\n|---|---|---|---|---|---|\n"
        );
        let keys: std::collections::BTreeSet<(u64, u64)> = sent.keys().chain(received.keys()).copied().collect();
        let (mut lost, mut died, mut streams_json) = (0u64, 0u64, Vec::new());
        for key in keys {
            let (a, i) = key;
            let begin = if i <= 1 { Some(0.0) } else { actor_restart(a, i - 1) };
            let finish = actor_restart(a, i).unwrap_or(self.end);
            let crossed: Vec<u64> = learner_restarts
                .iter()
                .filter(|(r, _)| {
                    begin.is_none_or(|b| b <= r + LEARNER_RESTART_SLACK_SECS)
                        && finish >= r - LEARNER_RESTART_SLACK_SECS
                })
                .map(|(_, a)| *a)
                .collect();
            let allowance = (!crossed.is_empty()).then(|| crossed.iter().fold(0u64, |s, a| s.saturating_add(*a)));
            let jumped = jumps.get(&key).copied().unwrap_or(0);
            if jumped > 0 && !(self.across_hosts && allowance.is_some()) {
                failures.push(format!(
                    "actor {a} incarnation {i}: a learner jumped {jumped} time(s) over records a learner before it took{}",
                    if self.across_hosts { ", on a stream that crossed no learner restart" } else { "" }
                ));
            }
            let s = sent.get(&key).copied();
            let r = received.get(&key).map(Vec::as_slice).unwrap_or(&[]);
            let verdict = account(s, r, allowance);
            lost += verdict.lost();
            died += verdict.died_with_learner();
            if verdict.failed() {
                failures.push(format!("stream {a}.{i}: {}", verdict.text().replace("**", "")));
            }
            let total: u64 = r.iter().map(|x| x.records).sum();
            md += &format!(
                "| {a}.{i} | {} | {total} | {} | {} | {} |\n",
                s.map_or("?".into(), |s| format!("{}{}", s.steps, if s.exact { "" } else { " (killed; last report)" })),
                r.len(),
                match allowance {
                    None => "no (crossed no learner restart)".to_string(),
                    Some(u64::MAX) => "unbounded (an unplanned learner restart)".to_string(),
                    Some(a) => format!("≤ {a} ({} restart(s))", crossed.len()),
                },
                verdict.text()
            );
            streams_json.push(json!({
                "actor": a, "incarnation": i,
                "sent": s.map(|s| s.steps), "sent_exact": s.map(|s| s.exact),
                "received": total, "learner_processes": r.len(),
                "learner_restarts_crossed": crossed.len(),
                "jumps": jumped,
                "died_allowance": allowance,
                "verdict": format!("{verdict:?}"),
                "lost": verdict.lost(),
                "died_with_killed_learner": verdict.died_with_learner(),
            }));
        }
        md += &format!(
            "\n**Lost on the learner's side: {lost}** (must be 0: records missing from streams that crossed no learner \
             restart or beyond what the killed learners could hold, gaps, checksum mismatches). Died with killed \
             learners (the documented loss of a learner restart): {died} records over {} learner restart(s).\n",
            learner_restarts.len()
        );
        // Across hosts: what each bridge moved (its `stats/bridge.json`, written by the
        // last bridge process of the host).
        let bridges: BTreeMap<&str, BridgeStats> = if self.across_hosts {
            [(Host::Learner, self.learner_dir), (Host::Actors, self.actor_dir)]
                .into_iter()
                .filter_map(|(h, d)| Some((h.label(), read_stats::<BridgeStats>(&RunDir::new(d), "bridge")?)))
                .collect()
        } else {
            BTreeMap::new()
        };
        for (host, b) in &bridges {
            md += &format!(
                "\nThe {host}'s last bridge: {} step records, {} episode reports, {} weights, {} hosts gone, {} \
                 refused.\n",
                b.step_records, b.episode_reports, b.weights, b.hosts_gone, b.refused
            );
        }
        let passed = failures.is_empty();
        md += &if passed {
            "\n**Soak passed.**".to_string()
        } else {
            format!("\n**Soak failed:**\n- {}", failures.join("\n- "))
        };
        let json = json!({
            "config": self.config.display().to_string(),
            "seed": self.seed,
            "actors": self.actors,
            "minutes": self.minutes,
            "mean_kill_interval_secs": self.mean,
            "across_hosts": self.across_hosts,
            "link_cut_secs": self.across_hosts.then_some(self.link_cut_secs),
            "run_dir": self.run_dir.display().to_string(),
            "training_started_s": self.training_started,
            "stopped_s": self.stopped_at,
            "duration_s": self.end,
            // One host: the launcher's exit; across hosts: each host's.
            "launcher_exit": if self.across_hosts {
                json!(self.exits.iter().map(|(h, e)| (h.label(), e.to_string())).collect::<BTreeMap<_, _>>())
            } else {
                json!(self.exits.first().map(|(_, e)| e.to_string()))
            },
            "schedule": self.schedule.iter().map(|k| json!({"at_s": k.at_secs, "victim": k.victim.process()})).collect::<Vec<_>>(),
            "kills": kills_json,
            "skipped": self.skipped.iter().map(|k| json!({"at_s": k.at_secs, "victim": k.victim.process()})).collect::<Vec<_>>(),
            "kills_per_kind": per_kind,
            "restarts_reported": by_process,
            "progress_line_restarts": self.log.progress_restarts,
            "unplanned_restarts": unplanned.iter().map(|r| json!({"process": r.process, "at_s": r.at, "status": r.status})).collect::<Vec<_>>(),
            "curriculum_resumes": curriculum_resumes,
            "end": {
                "env_steps": last.map(|s| s.env_steps),
                "updates": last.map(|s| s.updates),
                "learner_status": final_status,
            },
            "streams": streams_json,
            "bridges": bridges,
            "lost_on_learner_side": lost,
            "died_with_killed_learners": died,
            "refill_steps_per_learner_restart": warmup,
            "passed": passed,
            "failures": failures,
        });
        (md, json, failures)
    }
}
