//! The kill schedule: every kind of victim killed at seeded random times, within
//! what the supervisor's restart budget allows.

use super::*;

/// What the soak kills: a process (SIGKILL), or across hosts the link too (cut).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Victim {
    /// The learner.
    Learner,
    /// The curriculum service.
    Curriculum,
    /// Actor K.
    Actor(u32),
    /// The learner host's bridge (`--across-hosts`).
    LearnerHostBridge,
    /// The actor host's bridge (`--across-hosts`).
    ActorHostBridge,
    /// The link between the hosts, cut for `--link-cut-secs` (`--across-hosts`).
    Link,
}

/// The kinds of victim of a soak on one host, in the order the schedule numbers them.
const ONE_HOST_KINDS: [&str; 3] = ["learner", "curriculum", "actor"];
/// The kinds of victim of a soak across two hosts.
const TWO_HOST_KINDS: [&str; 6] =
    ["learner", "curriculum", "actor", "learner-host-bridge", "actor-host-bridge", "link"];

/// The kinds of victim of a soak, one host or two.
pub fn victim_kinds(across_hosts: bool) -> &'static [&'static str] {
    if across_hosts { &TWO_HOST_KINDS } else { &ONE_HOST_KINDS }
}

impl Victim {
    /// Its kind: one of [`victim_kinds`].
    pub fn kind(self) -> &'static str {
        match self {
            Victim::Learner => "learner",
            Victim::Curriculum => "curriculum",
            Victim::Actor(_) => "actor",
            Victim::LearnerHostBridge => "learner-host-bridge",
            Victim::ActorHostBridge => "actor-host-bridge",
            Victim::Link => "link",
        }
    }

    /// The supervisor's name of the process (its log's name, its restart lines'; a
    /// bridge's with its host, as the soak records the restarts of two launchers).
    pub fn process(self) -> String {
        match self {
            Victim::Actor(k) => format!("actor-{k}"),
            Victim::LearnerHostBridge => format!("{}/bridge", Host::Learner.label()),
            Victim::ActorHostBridge => format!("{}/bridge", Host::Actors.label()),
            v => v.kind().to_string(),
        }
    }

    /// Its binary's file name (the bridge is `pednav-run bridge`; the link has none).
    pub fn binary(self) -> &'static str {
        match self {
            Victim::Learner => "pednav-learner",
            Victim::Curriculum => "pednav-curriculum",
            Victim::Actor(_) => "pednav-actor",
            Victim::LearnerHostBridge | Victim::ActorHostBridge => "pednav-run",
            Victim::Link => "",
        }
    }

    /// The host whose launcher supervises it (on one host: the only one).
    pub fn host(self) -> Host {
        match self {
            Victim::Actor(_) | Victim::ActorHostBridge => Host::Actors,
            _ => Host::Learner,
        }
    }

    /// Whether it is a process the launcher restarts (the link is not).
    pub fn is_process(self) -> bool {
        self != Victim::Link
    }
}

/// One of the two hosts of a soak across hosts (on one host, everything is on
/// [`Host::Learner`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Host {
    /// The learner host: learner, curriculum service (and its bridge).
    Learner,
    /// The actor host: the actors and its bridge.
    Actors,
}

impl Host {
    /// Its name in the report, the process names and its run directory's.
    pub fn label(self) -> &'static str {
        match self {
            Host::Learner => "learner-host",
            Host::Actors => "actor-host",
        }
    }
}

/// One kill of the schedule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlannedKill {
    /// Seconds after the launch.
    pub at_secs: f64,
    /// Who.
    pub victim: Victim,
}

/// The kill-free time at the end of a run with kills `mean_secs` apart on average.
pub fn recovery_secs(mean_secs: f64) -> f64 {
    (0.5 * mean_secs).max(MIN_RECOVERY_SECS)
}

/// Uniform in [0, 1).
pub(super) fn unit(rng: &mut ChaCha8Rng) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

/// The kills of a `duration_secs` run with `actors` actors, on one host or across two,
/// drawn by one ChaCha8 RNG seeded with `seed` (see the module doc); an error when the
/// schedule cannot kill every kind or could spend a process's restart budget.
pub fn kill_schedule(
    seed: u64,
    duration_secs: f64,
    mean_secs: f64,
    actors: u32,
    across_hosts: bool,
) -> Result<Vec<PlannedKill>> {
    if !(mean_secs.is_finite() && mean_secs > 0.0) {
        bail!("--mean-kill-interval-secs must be a positive number of seconds, got {mean_secs}");
    }
    if !(duration_secs.is_finite() && duration_secs > 0.0) {
        bail!("--minutes must be positive, got {}", duration_secs / 60.0);
    }
    if actors == 0 || actors as usize > pednav_runtime::ipc::MAX_ACTORS {
        bail!("--actors must be 1 … {}, got {actors}", pednav_runtime::ipc::MAX_ACTORS);
    }
    let kinds = victim_kinds(across_hosts);
    let last = duration_secs - recovery_secs(mean_secs);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut t, mut kills, mut round) = (0.0, Vec::<PlannedKill>::new(), Vec::<u8>::new());
    loop {
        t += mean_secs * (0.5 + unit(&mut rng));
        if t > last {
            break;
        }
        if round.is_empty() {
            // A new round: every kind in a shuffled order (Fisher–Yates), taken from the end.
            round = (0..kinds.len() as u8).collect();
            for i in (1..round.len()).rev() {
                let j = ((unit(&mut rng) * (i + 1) as f64) as usize).min(i);
                round.swap(i, j);
            }
            let previous = kills.last().map(|k| k.victim.kind());
            if previous.is_some() && previous == round.last().map(|&r| kinds[r as usize]) {
                let n = round.len();
                round.swap(0, n - 1);
            }
        }
        let victim = match round.pop().expect("a round is refilled when empty") {
            0 => Victim::Learner,
            1 => Victim::Curriculum,
            2 => Victim::Actor(((unit(&mut rng) * actors as f64) as u32).min(actors - 1)),
            3 => Victim::LearnerHostBridge,
            4 => Victim::ActorHostBridge,
            _ => Victim::Link,
        };
        kills.push(PlannedKill { at_secs: t, victim });
    }
    if kinds.iter().any(|kind| !kills.iter().any(|k| k.victim.kind() == *kind)) {
        bail!(
            "seed {seed}: only {} kill(s) fit in {:.1} min at a mean interval of {mean_secs} s (the last {:.0} s are \
             left for recovery) — too few to kill each of {} at least once: raise --minutes, lower \
             --mean-kill-interval-secs or try another --seed",
            kills.len(),
            duration_secs / 60.0,
            recovery_secs(mean_secs),
            kinds.join(", ")
        );
    }
    for (i, a) in kills.iter().enumerate() {
        let n = kills[i..]
            .iter()
            .filter(|b| b.victim == a.victim && b.at_secs - a.at_secs < SUPERVISOR_RESTART_WINDOW_SECS)
            .count();
        if n > MAX_PLANNED_KILLS_PER_WINDOW {
            bail!(
                "seed {seed}: {n} kills of {} within {SUPERVISOR_RESTART_WINDOW_SECS} s would come close to the \
                 launcher's restart budget ({} deaths within {SUPERVISOR_RESTART_WINDOW_SECS} s end a run): raise \
                 --mean-kill-interval-secs",
                a.victim.process(),
                SUPERVISOR_MAX_RESTARTS + 1
            );
        }
    }
    Ok(kills)
}
