//! Joining a run from another host: what an actor host asks the learner host, and what
//! it is given.
//!
//! Invariants:
//! - a join is granted only to a host of the same pednav version and wire version
//!   ([`JoinRequest::check`]): hosts that would misread each other are refused before
//!   any record crosses, with a message naming both versions;
//! - a grant carries everything the actor host needs to start — the run's name (under
//!   which its keys live), its resolved `config.toml` (the actor host's run directory
//!   records it, so both hosts act on one config) and the host's global actor ids —
//!   and is recorded in the learner host's `hosts.json` before it is sent, so a
//!   rejoining host gets the same ids, also from a restarted learner host.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use zenoh::Wait;

use crate::error::{BridgeError, Result};
use crate::hosts::{HostTable, LOCAL};
use crate::wire;

/// The key a learner host answers joins on. It is not under a run's keys: the joining
/// host learns the run's name from the answer (a learner host serves one run per
/// listening endpoint).
pub const JOIN_KEY: &str = "pednav/join";

/// The pednav version of this build (hosts of a run must agree on it).
pub const PEDNAV_VERSION: &str = env!("CARGO_PKG_VERSION");

/// An actor host's request to join the run.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JoinRequest {
    /// The host's name (letters, digits, '-', '_', '.'), unique within the run.
    pub host: String,
    /// How many actor processes it runs.
    pub actors: u32,
    /// Its pednav version.
    pub pednav_version: String,
    /// Its wire version ([`wire::VERSION`]).
    pub wire_version: u8,
}

impl JoinRequest {
    /// A request of this build for `actors` actors on the host `host`.
    pub fn new(host: &str, actors: u32) -> JoinRequest {
        JoinRequest {
            host: host.to_string(),
            actors,
            pednav_version: PEDNAV_VERSION.to_string(),
            wire_version: wire::VERSION,
        }
    }

    /// The learner host's check that the requesting build is its own; the refusal
    /// names both versions.
    pub fn check(&self) -> std::result::Result<(), String> {
        if self.pednav_version != PEDNAV_VERSION || self.wire_version != wire::VERSION {
            return Err(format!(
                "host {:?} runs pednav {} (wire version {}), the learner host pednav {PEDNAV_VERSION} (wire version \
                 {}): install the same pednav build on every host of a run",
                self.host,
                self.pednav_version,
                self.wire_version,
                wire::VERSION
            ));
        }
        Ok(())
    }
}

/// The learner host's answer to a granted join.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JoinGrant {
    /// The run's name: its keys live under `pednav/<run>/`.
    pub run: String,
    /// The run's resolved `config.toml`, as the learner host's run directory holds it.
    pub config_toml: String,
    /// The host's first global actor id.
    pub first_actor: u32,
    /// Its number of actors (ids `first_actor .. first_actor + actors`).
    pub actors: u32,
}

/// The learner host's side of joining: the host table (kept in the run directory) and
/// what every grant carries.
pub struct JoinDesk {
    table: HostTable,
    path: PathBuf,
    run: String,
    config_toml: String,
}

impl JoinDesk {
    /// The desk of the run `run` whose resolved config is `config_toml`, with `local`
    /// actors on the learner host itself; the host table is read from `hosts_file` when
    /// a previous learner host left one (its local actors must then be as many).
    pub fn open(hosts_file: &Path, run: &str, config_toml: String, local: u32) -> Result<JoinDesk> {
        let max = pednav_runtime::ipc::MAX_ACTORS as u32;
        let table = match HostTable::load(hosts_file)? {
            Some(t) => {
                let recorded = t.host(LOCAL).map_or(0, |h| h.actors);
                if recorded != local {
                    return Err(BridgeError::HostFile {
                        path: hosts_file.to_path_buf(),
                        problem: format!(
                            "it records {recorded} actor(s) on the learner host, this launch has {local}: launch with \
                             --actors {recorded}, or remove the file to give every host new ids"
                        ),
                    });
                }
                t
            }
            None => HostTable::new(local, max)?,
        };
        Ok(JoinDesk { table, path: hosts_file.to_path_buf(), run: run.to_string(), config_toml })
    }

    /// The table as it stands.
    pub fn table(&self) -> &HostTable {
        &self.table
    }

    /// Grant `request` (recording it in the host table's file first) or say why not.
    pub fn answer(&mut self, request: &JoinRequest) -> std::result::Result<JoinGrant, String> {
        request.check()?;
        let before = self.table.clone();
        let ids = self.table.join(&request.host, request.actors).map_err(|e| e.to_string())?;
        if let Err(e) = self.table.save(&self.path) {
            self.table = before;
            return Err(format!("the learner host cannot record the join: {e}"));
        }
        Ok(JoinGrant {
            run: self.run.clone(),
            config_toml: self.config_toml.clone(),
            first_actor: ids.start,
            actors: ids.end - ids.start,
        })
    }
}

/// Ask the learner host that `session` reaches to let `request` join, trying for at
/// most `timeout` (a learner host's queryable reaches a new session shortly after it
/// connects). A refusal is [`BridgeError::Refused`] with the learner host's reason.
pub fn request_join(session: &zenoh::Session, request: &JoinRequest, timeout: Duration) -> Result<JoinGrant> {
    let body = serde_json::to_vec(request).expect("a join request serialises");
    let deadline = Instant::now() + timeout;
    while Instant::now() < deadline {
        let replies = session
            .get(JOIN_KEY)
            .payload(body.clone())
            .timeout(Duration::from_secs(2))
            .wait()
            .map_err(|e| BridgeError::Link(format!("join request: {e}")))?;
        // The channel ends (an error) when the query is finished without a reply.
        if let Ok(reply) = replies.recv() {
            return match reply.into_result() {
                Ok(sample) => serde_json::from_slice(&sample.payload().to_bytes())
                    .map_err(|e| BridgeError::Link(format!("the learner host's join answer is not one: {e}"))),
                Err(refusal) => {
                    Err(BridgeError::Refused(String::from_utf8_lossy(&refusal.payload().to_bytes()).into_owned()))
                }
            };
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    Err(BridgeError::Link(format!(
        "no learner host answered the join within {} s: is `pednav-run launch --listen …` running there, for this \
         run?",
        timeout.as_secs()
    )))
}

/// A host name the run's keys can carry: the machine's name with every character
/// other than letters, digits, '-', '_' and '.' replaced by '-' (at most 64).
pub fn key_safe_name(raw: &str) -> String {
    let name: String = raw
        .trim()
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() || "-_.".contains(c) { c } else { '-' })
        .take(64)
        .collect();
    if name.is_empty() { "host".to_string() } else { name }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("pednav-join-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir.join("hosts.json")
    }

    #[test]
    fn a_grant_is_recorded_and_a_rejoin_gets_the_same_ids() {
        let file = scratch("rejoin");
        let mut desk = JoinDesk::open(&file, "big", "seed = 1\n".into(), 0).unwrap();
        let a = desk.answer(&JoinRequest::new("gpu-a", 16)).unwrap();
        assert_eq!((a.run.as_str(), a.first_actor, a.actors, a.config_toml.as_str()), ("big", 0, 16, "seed = 1\n"));
        let b = desk.answer(&JoinRequest::new("gpu-b", 4)).unwrap();
        assert_eq!(b.first_actor, 16);
        // A restarted learner host reads the table back: gpu-a keeps its ids.
        let mut again = JoinDesk::open(&file, "big", "seed = 1\n".into(), 0).unwrap();
        assert_eq!(again.answer(&JoinRequest::new("gpu-a", 16)).unwrap().first_actor, 0);
        assert_eq!(again.table().actors(), 20);
        // Its local actors must be what the table records.
        let err = JoinDesk::open(&file, "big", String::new(), 2).err().unwrap().to_string();
        assert!(err.contains("0 actor(s)") && err.contains("--actors 0"), "{err}");
    }

    #[test]
    fn another_build_or_a_bad_name_is_refused_and_changes_nothing() {
        let file = scratch("refuse");
        let mut desk = JoinDesk::open(&file, "big", String::new(), 2).unwrap();
        let mut other = JoinRequest::new("gpu-a", 4);
        other.pednav_version = "0.0.1-other".into();
        let why = desk.answer(&other).unwrap_err();
        assert!(why.contains("0.0.1-other") && why.contains(PEDNAV_VERSION), "{why}");
        let mut wire_other = JoinRequest::new("gpu-a", 4);
        wire_other.wire_version = wire::VERSION.wrapping_add(1);
        assert!(desk.answer(&wire_other).unwrap_err().contains("wire version"));
        assert!(desk.answer(&JoinRequest::new("local", 4)).unwrap_err().contains("learner host's own"));
        assert!(desk.answer(&JoinRequest::new("gpu-a", 300)).unwrap_err().contains("300 actors"));
        assert_eq!(desk.table().actors(), 2, "refusals left the table as it was");
    }

    #[test]
    fn machine_names_become_key_safe() {
        assert_eq!(key_safe_name("gpu-a.lab\n"), "gpu-a.lab");
        assert_eq!(key_safe_name("my host/1*"), "my-host-1-");
        assert_eq!(key_safe_name("  "), "host");
    }
}
