//! The kill schedule: every kind of process killed at seeded random times, within
//! what the supervisor's restart budget allows.

use super::*;

/// A process the soak kills.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Victim {
    /// The learner.
    Learner,
    /// The curriculum service.
    Curriculum,
    /// Actor K.
    Actor(u32),
}

impl Victim {
    /// Its kind: `learner`, `curriculum` or `actor`.
    pub fn kind(self) -> &'static str {
        match self {
            Victim::Learner => "learner",
            Victim::Curriculum => "curriculum",
            Victim::Actor(_) => "actor",
        }
    }

    /// The supervisor's name of the process (its log's name, its restart lines').
    pub fn process(self) -> String {
        match self {
            Victim::Actor(k) => format!("actor-{k}"),
            v => v.kind().to_string(),
        }
    }

    /// Its binary's file name.
    pub fn binary(self) -> &'static str {
        match self {
            Victim::Learner => "pednav-learner",
            Victim::Curriculum => "pednav-curriculum",
            Victim::Actor(_) => "pednav-actor",
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

/// The kills of a `duration_secs` run with `actors` actors, drawn by one ChaCha8 RNG
/// seeded with `seed` (see the module doc); an error when the schedule cannot kill
/// every kind or could spend a process's restart budget.
pub fn kill_schedule(seed: u64, duration_secs: f64, mean_secs: f64, actors: u32) -> Result<Vec<PlannedKill>> {
    if !(mean_secs.is_finite() && mean_secs > 0.0) {
        bail!("--mean-kill-interval-secs must be a positive number of seconds, got {mean_secs}");
    }
    if !(duration_secs.is_finite() && duration_secs > 0.0) {
        bail!("--minutes must be positive, got {}", duration_secs / 60.0);
    }
    if actors == 0 || actors as usize > pednav_runtime::ipc::MAX_ACTORS {
        bail!("--actors must be 1 … {}, got {actors}", pednav_runtime::ipc::MAX_ACTORS);
    }
    let last = duration_secs - recovery_secs(mean_secs);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut t, mut kills, mut round) = (0.0, Vec::<PlannedKill>::new(), Vec::<u8>::new());
    loop {
        t += mean_secs * (0.5 + unit(&mut rng));
        if t > last {
            break;
        }
        if round.is_empty() {
            // A new round: the three kinds in a shuffled order (Fisher–Yates), taken from the end.
            round = vec![0, 1, 2];
            for i in (1..round.len()).rev() {
                let j = ((unit(&mut rng) * (i + 1) as f64) as usize).min(i);
                round.swap(i, j);
            }
            let previous = kills.last().map(|k| k.victim.kind());
            if previous.is_some() && previous == round.last().map(|&r| kind_name(r)) {
                let n = round.len();
                round.swap(0, n - 1);
            }
        }
        let victim = match round.pop().expect("a round is refilled when empty") {
            0 => Victim::Learner,
            1 => Victim::Curriculum,
            _ => Victim::Actor(((unit(&mut rng) * actors as f64) as u32).min(actors - 1)),
        };
        kills.push(PlannedKill { at_secs: t, victim });
    }
    if ["learner", "curriculum", "actor"].iter().any(|kind| !kills.iter().any(|k| k.victim.kind() == *kind)) {
        bail!(
            "seed {seed}: only {} kill(s) fit in {:.1} min at a mean interval of {mean_secs} s (the last {:.0} s are \
             left for recovery) — too few to kill the learner, the curriculum service and an actor each at least \
             once: raise --minutes, lower --mean-kill-interval-secs or try another --seed",
            kills.len(),
            duration_secs / 60.0,
            recovery_secs(mean_secs)
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

pub(super) fn kind_name(r: u8) -> &'static str {
    match r {
        0 => "learner",
        1 => "curriculum",
        _ => "actor",
    }
}
