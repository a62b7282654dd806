//! The one error type of the networks library.

/// Everything that can go wrong in `pednav-nets`.
#[derive(Debug, thiserror::Error)]
pub enum NetError {
    /// A tensor operation failed.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
    /// A network setting is out of range or inconsistent.
    #[error("invalid network setting `{field}` = {value}: {message}")]
    Config {
        /// The offending field.
        field: &'static str,
        /// Its value, as text.
        value: String,
        /// What is allowed.
        message: String,
    },
    /// A compute device cannot be used (not built in, or not present).
    #[error("device `{device}`: {message}")]
    Device {
        /// The device as named (`cuda:1`).
        device: String,
        /// Why it cannot be used and what to do.
        message: String,
    },
    /// Saved weights do not match the network they are loaded into.
    #[error("weights for `{network}` do not match: {message}")]
    Incompatible {
        /// Which network.
        network: String,
        /// What differs (missing or extra tensor, shape).
        message: String,
    },
}

/// Result alias of the library.
pub type Result<T, E = NetError> = std::result::Result<T, E>;

pub(crate) fn config_error(field: &'static str, value: impl ToString, message: impl Into<String>) -> NetError {
    NetError::Config { field, value: value.to_string(), message: message.into() }
}
