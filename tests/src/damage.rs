//! Damage a saved file can suffer between a save and the next load, for the fault
//! tests of the learner's checkpoint and the curriculum service's state file.
//!
//! Invariant: each kind changes or removes the file in a way only the loader's own
//! checks (checksums, parsing, presence) can detect, and the same kind applied to the
//! same bytes always gives the same result.

use std::fs;
use std::io;
use std::path::Path;

/// One way of damaging a file: what the fault tests apply to each file of a saved
/// generation (`pednav_runtime::generations`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Damage {
    /// Four bytes in the middle XOR-ed with 0x5a.
    FlipBytes,
    /// Four bytes in the middle replaced by ASCII digits (`7777`, or `8888` if they
    /// were already `7777`).
    DigitsOverBytes,
    /// The last digit of the number nearest the middle changed (to `0`, or `1` if it
    /// was `0`): a JSON file stays valid and of the same types; only a checksum tells.
    OneDigit,
    /// Cut to half its length.
    TruncateToHalf,
    /// Removed.
    Remove,
}

impl Damage {
    /// Every kind, in a fixed order.
    pub const ALL: [Damage; 5] =
        [Damage::FlipBytes, Damage::DigitsOverBytes, Damage::OneDigit, Damage::TruncateToHalf, Damage::Remove];

    /// Apply this damage to `file` (at least 4 bytes long, except for `Remove`).
    pub fn apply(self, file: &Path) -> io::Result<()> {
        if self == Damage::Remove {
            return fs::remove_file(file);
        }
        let mut bytes = fs::read(file)?;
        if bytes.len() < 4 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("{} is too short to damage", file.display()),
            ));
        }
        let mid = (bytes.len() / 2).min(bytes.len() - 4);
        match self {
            Damage::FlipBytes => bytes[mid..mid + 4].iter_mut().for_each(|b| *b ^= 0x5a),
            Damage::DigitsOverBytes => {
                let digits: &[u8] = if &bytes[mid..mid + 4] == b"7777" { b"8888" } else { b"7777" };
                bytes[mid..mid + 4].copy_from_slice(digits);
            }
            Damage::OneDigit => {
                let last_digit =
                    |i: usize| bytes[i].is_ascii_digit() && !bytes.get(i + 1).is_some_and(u8::is_ascii_digit);
                let at = (0..bytes.len()).filter(|&i| last_digit(i)).min_by_key(|&i| i.abs_diff(mid)).unwrap_or(mid);
                bytes[at] = if bytes[at] == b'0' { b'1' } else { b'0' };
            }
            Damage::TruncateToHalf => bytes.truncate(bytes.len() / 2),
            Damage::Remove => unreachable!("handled above"),
        }
        fs::write(file, bytes)
    }
}

impl std::fmt::Display for Damage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Damage::FlipBytes => "flip 4 bytes",
            Damage::DigitsOverBytes => "digits over 4 bytes",
            Damage::OneDigit => "one digit",
            Damage::TruncateToHalf => "truncate to half",
            Damage::Remove => "remove",
        })
    }
}
