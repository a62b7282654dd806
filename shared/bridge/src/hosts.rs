//! The learner host's table of hosts and the global actor ids each one holds.
//!
//! Invariants (tested, the first by property over any sequence of joins and leaves):
//! - the ranges of actor ids never overlap, and every id is below the table's limit
//!   (`pednav_runtime::ipc::MAX_ACTORS`: the learner's acknowledgement table has one
//!   entry per id);
//! - a host that joins again under its name with the same number of actors gets the
//!   same ids (a reconnecting host keeps its streams' identity), also after the
//!   learner host restarted: the table lives in the run directory (`hosts.json`),
//!   written whole to a temporary file and renamed, so a crash leaves the old table
//!   or the new one, never a mix;
//! - the learner host's own actors hold ids `0 .. local` from the start.

use std::ops::Range;
use std::path::Path;

use pednav_runtime::generations::write_atomic;
use pednav_runtime::ipc::MAX_ACTORS;
use serde::{Deserialize, Serialize};

use crate::error::{BridgeError, Result};

/// The name the learner host's own actors are listed under.
pub const LOCAL: &str = "local";

/// The table's file in the learner host's run directory.
pub const HOSTS_FILE: &str = "hosts.json";

/// One host and its actor ids.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Host {
    /// The name the host joined with (unique in the table).
    pub name: String,
    /// Its first global actor id.
    pub first_actor: u32,
    /// How many actors it runs (ids `first_actor .. first_actor + actors`).
    pub actors: u32,
}

impl Host {
    /// The host's global actor ids.
    pub fn ids(&self) -> Range<u32> {
        self.first_actor..self.first_actor + self.actors
    }
}

/// Every host of a run and its actor ids.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HostTable {
    /// Actor ids are below this.
    pub max_actors: u32,
    /// The hosts, in order of their first id.
    pub hosts: Vec<Host>,
}

impl HostTable {
    /// A table holding the learner host's `local` actors (ids `0 .. local`) of at most
    /// `max_actors` in all.
    pub fn new(local: u32, max_actors: u32) -> Result<HostTable> {
        if max_actors as usize > MAX_ACTORS {
            return Err(BridgeError::Hosts(format!(
                "max_actors {max_actors}: this build has actor ids below {MAX_ACTORS} (pednav_runtime::ipc::MAX_ACTORS)"
            )));
        }
        let mut table = HostTable { max_actors, hosts: Vec::new() };
        if local > 0 {
            table.grant(LOCAL, local)?;
        }
        Ok(table)
    }

    /// The host named `name`, if it joined.
    pub fn host(&self, name: &str) -> Option<&Host> {
        self.hosts.iter().find(|h| h.name == name)
    }

    /// Actor ids held by all hosts together.
    pub fn actors(&self) -> u32 {
        self.hosts.iter().map(|h| h.actors).sum()
    }

    /// The hosts that joined (every host but the learner host's own actors).
    pub fn remote(&self) -> impl Iterator<Item = &Host> {
        self.hosts.iter().filter(|h| h.name != LOCAL)
    }

    /// Give the host `name` ids for `actors` actors: its own again when it joined
    /// before with as many; otherwise the lowest free range that fits (a host that
    /// comes back with another count moves there). A refused join changes nothing.
    pub fn join(&mut self, name: &str, actors: u32) -> Result<Range<u32>> {
        if name.is_empty() || name.len() > 64 || !name.chars().all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c)) {
            return Err(BridgeError::Hosts(format!(
                "host name {name:?}: use 1 to 64 letters, digits, '-', '_' or '.'"
            )));
        }
        if name == LOCAL {
            return Err(BridgeError::Hosts(format!("host name {LOCAL:?} is the learner host's own: choose another")));
        }
        self.grant(name, actors)
    }

    /// [`HostTable::join`] without the name rules (the learner host's own entry).
    fn grant(&mut self, name: &str, actors: u32) -> Result<Range<u32>> {
        if actors == 0 {
            return Err(BridgeError::Hosts(format!("host {name:?} joins with no actors")));
        }
        if let Some(h) = self.host(name)
            && h.actors == actors
        {
            return Ok(h.ids());
        }
        // The lowest gap between the other hosts' ranges (sorted by first id) that fits;
        // the host's own old range counts as free, and stays its own if nothing fits.
        let others: Vec<&Host> = self.hosts.iter().filter(|h| h.name != name).collect();
        let mut start = 0u32;
        for h in &others {
            if h.first_actor.saturating_sub(start) >= actors {
                break;
            }
            start = start.max(h.first_actor + h.actors);
        }
        if start.checked_add(actors).is_none_or(|end| end > self.max_actors) {
            return Err(BridgeError::Hosts(format!(
                "host {name:?} asks for {actors} actors, but {} of the {} actor ids are taken and no {actors} in a row \
                 are free: join with fewer actors, or stop a host",
                others.iter().map(|h| h.actors).sum::<u32>(),
                self.max_actors
            )));
        }
        self.leave(name);
        self.hosts.push(Host { name: name.to_string(), first_actor: start, actors });
        self.hosts.sort_by_key(|h| h.first_actor);
        Ok(start..start + actors)
    }

    /// Remove the host `name` (its ids become free); whether it was there.
    pub fn leave(&mut self, name: &str) -> bool {
        let before = self.hosts.len();
        self.hosts.retain(|h| h.name != name);
        self.hosts.len() != before
    }

    /// The host holding actor id `actor`.
    pub fn owner(&self, actor: u32) -> Option<&Host> {
        self.hosts.iter().find(|h| h.ids().contains(&actor))
    }

    /// Check the invariants of a table read from a file.
    fn check(&self) -> std::result::Result<(), String> {
        if self.max_actors as usize > MAX_ACTORS {
            return Err(format!("max_actors {}: this build has actor ids below {MAX_ACTORS}", self.max_actors));
        }
        let mut end = 0u32;
        for (i, h) in self.hosts.iter().enumerate() {
            if h.actors == 0 {
                return Err(format!("host {:?} holds no actors", h.name));
            }
            let ids = format!("{} .. {} + {}", h.first_actor, h.first_actor, h.actors);
            if h.first_actor < end {
                return Err(format!("host {:?}'s ids {ids} overlap the host before it", h.name));
            }
            end =
                h.first_actor.checked_add(h.actors).ok_or_else(|| format!("host {:?}'s ids {ids} overflow", h.name))?;
            if end > self.max_actors {
                return Err(format!("host {:?}'s ids {ids} reach past max_actors {}", h.name, self.max_actors));
            }
            if self.hosts[..i].iter().any(|o| o.name == h.name) {
                return Err(format!("host {:?} is listed twice", h.name));
            }
        }
        Ok(())
    }

    /// Read the table at `path`; `None` when there is no file.
    pub fn load(path: &Path) -> Result<Option<HostTable>> {
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(BridgeError::Io { path: path.to_path_buf(), source }),
        };
        let table: HostTable = serde_json::from_str(&text)
            .map_err(|e| BridgeError::HostFile { path: path.to_path_buf(), problem: e.to_string() })?;
        table.check().map_err(|problem| BridgeError::HostFile { path: path.to_path_buf(), problem })?;
        Ok(Some(table))
    }

    /// Write the table to `path` in one step ([`write_atomic`]).
    pub fn save(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self).expect("a host table serialises");
        write_atomic(path, text.as_bytes()).map_err(|source| BridgeError::Io { path: path.to_path_buf(), source })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn local_actors_hold_the_first_ids_and_hosts_follow() {
        let mut t = HostTable::new(2, 256).unwrap();
        assert_eq!(t.host(LOCAL).unwrap().ids(), 0..2);
        assert_eq!(t.join("gpu-a", 16).unwrap(), 2..18);
        assert_eq!(t.join("gpu-b", 8).unwrap(), 18..26);
        assert_eq!(t.join("gpu-a", 16).unwrap(), 2..18, "a rejoin with as many actors keeps its ids");
        assert_eq!(t.owner(20).unwrap().name, "gpu-b");
        assert!(t.leave("gpu-a"));
        assert_eq!(t.join("gpu-c", 10).unwrap(), 2..12, "the lowest free range that fits");
        assert_eq!(t.join("gpu-d", 7).unwrap(), 26..33, "6 free ids between 12 and 18 are too few");
        assert_eq!(t.join("gpu-b", 4).unwrap(), 12..16, "another count: a new range");
        assert_eq!(t.actors(), 2 + 10 + 7 + 4);
    }

    #[test]
    fn a_join_that_does_not_fit_or_names_badly_is_refused_saying_why() {
        let mut t = HostTable::new(0, 16).unwrap();
        t.join("a", 10).unwrap();
        let err = t.join("b", 7).unwrap_err().to_string();
        assert!(err.contains("\"b\" asks for 7 actors") && err.contains("10 of the 16"), "{err}");
        assert!(t.join("bad name", 1).unwrap_err().to_string().contains("host name"));
        assert!(t.join("c", 0).unwrap_err().to_string().contains("no actors"));
        assert!(t.join(LOCAL, 2).unwrap_err().to_string().contains("learner host's own"));
        assert!(HostTable::new(0, 100_000).unwrap_err().to_string().contains("max_actors 100000"));
        assert_eq!(t.join("b", 6).unwrap(), 10..16);
    }

    #[test]
    fn a_saved_table_reloads_and_a_broken_one_is_refused_naming_the_file() {
        let dir = std::env::temp_dir().join(format!("pednav-hosts-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("hosts.json");
        assert!(HostTable::load(&path).unwrap().is_none());
        let mut t = HostTable::new(2, 256).unwrap();
        t.join("gpu-a", 16).unwrap();
        t.save(&path).unwrap();
        assert_eq!(HostTable::load(&path).unwrap(), Some(t.clone()));
        assert!(!path.with_extension("json.tmp").exists());
        let mut broken = t.clone();
        broken.hosts[1].first_actor = 1;
        std::fs::write(&path, serde_json::to_string(&broken).unwrap()).unwrap();
        let err = HostTable::load(&path).unwrap_err().to_string();
        assert!(err.contains("hosts.json") && err.contains("overlap"), "{err}");
        std::fs::write(&path, "{\"max_actors\": 4}").unwrap();
        assert!(HostTable::load(&path).unwrap_err().to_string().contains("missing field `hosts`"));
        std::fs::write(&path, "{\"max_actors\": 4096, \"hosts\": []}").unwrap();
        assert!(HostTable::load(&path).unwrap_err().to_string().contains("max_actors 4096"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[derive(Debug, Clone)]
    enum Op {
        Join(u8, u32),
        Leave(u8),
    }

    proptest! {
        /// Whatever hosts join and leave: no two hosts share an id, every id is below
        /// the limit, a granted join holds exactly what it asked for, and the table
        /// passes the check a loaded file must pass.
        #[test]
        fn ranges_never_overlap(ops in proptest::collection::vec(prop_oneof![
            3 => (0u8..8, 1u32..40).prop_map(|(h, n)| Op::Join(h, n)),
            1 => (0u8..8).prop_map(Op::Leave),
        ], 0..60)) {
            let mut t = HostTable::new(3, 128).unwrap();
            for op in ops {
                match op {
                    Op::Join(h, n) => {
                        let name = format!("host-{h}");
                        let before = t.clone();
                        match t.join(&name, n) {
                            Ok(ids) => {
                                prop_assert_eq!(ids.len() as u32, n);
                                if let Some(b) = before.host(&name).filter(|b| b.actors == n) {
                                    prop_assert_eq!(ids.clone(), b.ids(), "a rejoin keeps its ids");
                                }
                                prop_assert_eq!(t.host(&name).unwrap().ids(), ids);
                            }
                            Err(_) => {
                                prop_assert_eq!(&t, &before, "a refused join changes nothing");
                                // Refused only when no n ids in a row are free of the other hosts.
                                let held = |id: u32| t.hosts.iter().any(|h| h.name != name && h.ids().contains(&id));
                                let (mut run, mut longest) = (0u32, 0u32);
                                for id in 0..t.max_actors {
                                    run = if held(id) { 0 } else { run + 1 };
                                    longest = longest.max(run);
                                }
                                prop_assert!(longest < n, "refused {} ids with {} free in a row", n, longest);
                            }
                        }
                    }
                    Op::Leave(h) => {
                        t.leave(&format!("host-{h}"));
                    }
                }
                prop_assert!(t.check().is_ok(), "{:?}: {:?}", t, t.check());
                for id in 0..t.max_actors {
                    prop_assert!(t.hosts.iter().filter(|h| h.ids().contains(&id)).count() <= 1);
                }
            }
        }
    }
}
