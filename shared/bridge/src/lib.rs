//! pednav across hosts: the pieces a bridge between one host's iceoryx2 services and
//! another's is built from.
//!
//! - [`wire`]: every message a run sends, as explicit little-endian bytes with a kind
//!   and a version byte — the in-memory `#[repr(C)]` layouts of
//!   `pednav_runtime::messages` never leave their host;
//! - [`link`]: zenoh sessions that reach only the endpoints they are given (no
//!   scouting), and the keys a run's messages travel under;
//! - [`hosts`]: the learner host's table of joined hosts and the global actor ids
//!   each one was given, kept in the run directory so a restarted learner host gives
//!   a rejoining host the same ids; [`join`]: how a host asks for them;
//! - [`learner_host`] and [`actor_host`]: the two bridges, each a loop between its
//!   host's iceoryx2 services and the link (`pednav-run bridge` runs one).
//!
//! Losslessness across hosts is not here but at the ends: step records carry (actor,
//! incarnation, seq, base) and the learner's acknowledgements travel back
//! (`pednav_runtime::reliable`); episode reports carry (actor, incarnation, seq,
//! low-water mark) and the curriculum service's acknowledgements travel back
//! (`pednav_runtime::reports`), whatever carries them. A bridge holds neither: one
//! that dies costs resends, never a record.

#![warn(missing_docs)]

pub mod actor_host;
pub mod error;
pub mod forward;
pub mod hosts;
pub mod join;
pub mod learner_host;
pub mod link;
mod remote;
pub mod wire;

pub use actor_host::{ActorHostOptions, run_actor_host};
pub use error::{BridgeError, Result};
pub use forward::LEARNER_HOST;
pub use hosts::{HOSTS_FILE, Host, HostTable};
pub use join::{JoinGrant, JoinRequest, request_join};
pub use learner_host::{LearnerHostOptions, run_learner_host, run_name};
pub use link::{Keys, LinkConfig, TlsFiles};
pub use pednav_runtime::stats::BridgeStats;
