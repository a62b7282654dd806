//! The one error type of `pednav-bridge`.

use std::path::PathBuf;

/// `Result` with [`BridgeError`].
pub type Result<T> = std::result::Result<T, BridgeError>;

/// What went wrong, naming the message, field or file.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// Bytes from another host that are not a message of the expected kind.
    #[error("message from another host ({kind}): {problem}")]
    Malformed {
        /// The message kind expected.
        kind: &'static str,
        /// What is wrong, naming the field.
        problem: String,
    },
    /// A message of another encoding version: the hosts run different pednav builds.
    #[error(
        "message from another host ({kind}) of wire version {found}; this build reads version {expected}: every \
         host of a run must run the same pednav version"
    )]
    Version {
        /// The message kind.
        kind: &'static str,
        /// The version the bytes carry.
        found: u8,
        /// The version this build reads and writes.
        expected: u8,
    },
    /// An endpoint given to `--listen` or `--connect` that pednav does not use.
    #[error("{flag} {endpoint}: {problem}")]
    Endpoint {
        /// The flag it was given to.
        flag: String,
        /// The endpoint as given.
        endpoint: String,
        /// What is wrong with it.
        problem: String,
    },
    /// A link that could not be configured or opened.
    #[error("link: {0}")]
    Link(String),
    /// The learner host refused this host's join; its reason.
    #[error("the learner host refused the join: {0}")]
    Refused(String),
    /// The local run's services (iceoryx2) or run directory.
    #[error(transparent)]
    Runtime(#[from] pednav_runtime::RuntimeError),
    /// A join the host table cannot grant, or a table that contradicts itself.
    #[error("host table: {0}")]
    Hosts(String),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A host table file that is not one.
    #[error("{path}: not a pednav host table: {problem}")]
    HostFile {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        problem: String,
    },
}
