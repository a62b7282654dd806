//! The one error type of the settings: a value out of range, naming its field.

/// A setting is out of range. `section` says whose setting it is ("learner" for the
/// `[dsac]` and `[replay]` sections, "curriculum" for `[curriculum]`), so messages
/// read the same wherever the check runs (the launcher's `check` or the process).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid {section} setting `{field}` = {value}: {message}")]
pub struct ConfigError {
    /// Whose setting: "learner" or "curriculum".
    pub section: &'static str,
    /// The offending field.
    pub field: &'static str,
    /// Its value, as text.
    pub value: String,
    /// What is allowed.
    pub message: String,
}

impl ConfigError {
    /// A learner setting (`[dsac]`, `[replay]`) is out of range.
    pub fn learner(field: &'static str, value: impl ToString, message: impl Into<String>) -> ConfigError {
        ConfigError { section: "learner", field, value: value.to_string(), message: message.into() }
    }

    /// A curriculum setting (`[curriculum]`) is out of range.
    pub fn curriculum(field: &'static str, value: impl ToString, message: impl Into<String>) -> ConfigError {
        ConfigError { section: "curriculum", field, value: value.to_string(), message: message.into() }
    }
}

/// Result alias of the settings.
pub type Result<T, E = ConfigError> = std::result::Result<T, E>;
