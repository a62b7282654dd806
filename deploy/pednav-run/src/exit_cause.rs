//! Why a process exited, read from its log whatever the environment did to it.
//!
//! A pednav binary whose `main` returns an error ends its log with anyhow's report:
//! `Error: <message>`, a blank line, `Caused by:` and the chain (one cause indented,
//! or several numbered `0: …`, `1: …`). The environment adds to that: with
//! `RUST_BACKTRACE` (1 or full) or `RUST_LIB_BACKTRACE` a `Stack backtrace:` of many
//! frames follows the chain; with `RUST_LOG=debug` debug lines of other threads may
//! come after it; a panic writes `thread '…' panicked at …` and its message instead.
//! [`ExitCause::parse`] keeps the error and its chain and drops the rest, so the
//! launcher's restart lines and final message name the cause in every case.
//!
//! Invariant: [`ExitCause::report`] never contains a backtrace frame, and
//! [`ExitCause::headline`] is one line.

/// The cause of one exit.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExitCause {
    /// The error's own message (`Error: …`, possibly several lines), or a panic's
    /// `panicked at …` line and message; `None` when the log holds neither.
    pub error: Option<String>,
    /// The `Caused by:` chain, outermost first, without its numbering.
    pub causes: Vec<String>,
    /// The log line before the error (what the process was doing), or, without an
    /// error, the log's last lines.
    pub context: Vec<String>,
}

/// Lines of the log kept when it shows no error.
const TAIL_LINES: usize = 8;

fn is_backtrace_start(line: &str) -> bool {
    let l = line.trim_start();
    l.starts_with("Stack backtrace:")
        || l.starts_with("stack backtrace:")
        || l.starts_with("Backtrace omitted")
        || l.starts_with("note: run with `RUST_BACKTRACE")
        || l.starts_with("note: Some details are omitted")
}

/// A `  12: symbol` or `      at file:line` frame of a backtrace.
fn is_frame(line: &str) -> bool {
    let l = line.trim_start();
    l.starts_with("at ")
        || l.split_once(": ").is_some_and(|(n, _)| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
}

impl ExitCause {
    /// Read the cause out of a process's log.
    pub fn parse(log: &str) -> ExitCause {
        let lines: Vec<&str> = log.lines().collect();
        if let Some(i) = lines.iter().rposition(|l| l.starts_with("Error: ")) {
            let mut error = vec![lines[i].trim_start_matches("Error: ").to_string()];
            let mut k = i + 1;
            while k < lines.len() && !lines[k].trim().is_empty() && !is_backtrace_start(lines[k]) {
                error.push(lines[k].to_string());
                k += 1;
            }
            while k < lines.len() && lines[k].trim().is_empty() {
                k += 1;
            }
            let mut causes = Vec::new();
            if lines.get(k).is_some_and(|l| l.trim() == "Caused by:") {
                k += 1;
                while k < lines.len() && lines[k].starts_with(char::is_whitespace) && !lines[k].trim().is_empty() {
                    let l = lines[k].trim();
                    if is_backtrace_start(l) {
                        break;
                    }
                    // Strip anyhow's numbering ("0: ") of a multi-cause chain.
                    let text = match l.split_once(": ") {
                        Some((n, rest)) if n.bytes().all(|b| b.is_ascii_digit()) && !n.is_empty() => rest,
                        _ => l,
                    };
                    causes.push(text.to_string());
                    k += 1;
                }
            }
            let context = i.checked_sub(1).map(|j| vec![lines[j].to_string()]).unwrap_or_default();
            return ExitCause { error: Some(error.join("\n")), causes, context };
        }
        if let Some(i) = lines.iter().rposition(|l| l.contains("panicked at")) {
            let mut error = vec![lines[i].to_string()];
            error.extend(
                lines[i + 1..]
                    .iter()
                    .take_while(|l| !is_backtrace_start(l) && !is_frame(l))
                    .take(4)
                    .map(|l| l.to_string()),
            );
            return ExitCause { error: Some(error.join("\n")), causes: Vec::new(), context: Vec::new() };
        }
        let kept: Vec<String> =
            lines.iter().filter(|l| !is_frame(l) && !is_backtrace_start(l)).map(|l| l.to_string()).collect();
        ExitCause { error: None, causes: Vec::new(), context: kept[kept.len().saturating_sub(TAIL_LINES)..].to_vec() }
    }

    /// One line: the error's first line and, when there is a chain, its root cause —
    /// e.g. `the final checkpoint could not be written — No space left on device (os
    /// error 28)`; without an error, the log's last line.
    pub fn headline(&self) -> String {
        match &self.error {
            Some(e) => {
                let first = e.lines().next().unwrap_or_default();
                match self.causes.last() {
                    Some(root) => format!("{first} — {root}"),
                    None => first.to_string(),
                }
            }
            None => self.context.last().cloned().unwrap_or_else(|| "(empty log)".into()),
        }
    }

    /// The whole cause for a person: the context line, the error and its chain as
    /// anyhow writes them, without any backtrace.
    pub fn report(&self) -> String {
        let mut out = self.context.join("\n");
        if let Some(e) = &self.error {
            if !out.is_empty() {
                out.push('\n');
            }
            out.push_str("Error: ");
            out.push_str(e);
            if !self.causes.is_empty() {
                out.push_str("\n\nCaused by:");
                for (n, c) in self.causes.iter().enumerate() {
                    // A cause of several lines keeps them under its own indentation.
                    let (first, rest) = c.split_once('\n').unwrap_or((c, ""));
                    let indent = if self.causes.len() == 1 { "    " } else { "       " };
                    if self.causes.len() == 1 {
                        out.push_str(&format!("\n    {first}"));
                    } else {
                        out.push_str(&format!("\n    {n}: {first}"));
                    }
                    for line in rest.lines() {
                        out.push('\n');
                        out.push_str(indent);
                        out.push_str(line);
                    }
                }
            }
        }
        out
    }
}

/// An error as anyhow reports it — `Error: <message>`, then `Caused by:` and the chain
/// (numbered when it has several links) — without a backtrace.
pub fn report_of(e: &anyhow::Error) -> String {
    let causes: Vec<String> = e.chain().skip(1).map(|c| c.to_string()).collect();
    ExitCause { error: Some(e.to_string()), causes, context: Vec::new() }.report()
}

#[cfg(test)]
mod tests {
    use super::*;

    const CHAIN: [&str; 6] = [
        "2026-12-01T10:00:21Z  INFO resuming",
        "Error: the final checkpoint could not be written (last good on disk: update 100)",
        "",
        "Caused by:",
        "    0: checkpoint runs/x/checkpoints/learner: write and sync runs/x/checkpoints/learner.tmp/optimizer.safetensors: No space left on device (os error 28)",
        "    1: No space left on device (os error 28)",
    ];

    fn progress_lines() -> Vec<String> {
        (0..20).map(|i| format!("2026-12-01T10:00:{i:02}Z  INFO learner received={i}")).collect()
    }

    fn check_chain(log: &str, how: &str) {
        let c = ExitCause::parse(log);
        assert_eq!(
            c.headline(),
            "the final checkpoint could not be written (last good on disk: update 100) — No space left on device (os error 28)",
            "{how}"
        );
        assert_eq!(c.causes.len(), 2, "{how}: {c:?}");
        let report = c.report();
        assert!(
            report.starts_with("2026-12-01T10:00:21Z  INFO resuming\nError: the final checkpoint"),
            "{how}: {report}"
        );
        assert!(report.contains("Caused by:\n    0: checkpoint runs/x"), "{how}: {report}");
        assert!(!report.contains("backtrace") && !report.contains("received=19"), "{how}: {report}");
    }

    #[test]
    fn the_launchers_own_report_has_the_chain_and_no_backtrace() {
        let e = anyhow::anyhow!("No space left on device").context("writing x").context("the run stopped");
        assert_eq!(
            report_of(&e),
            "Error: the run stopped\n\nCaused by:\n    0: writing x\n    1: No space left on device"
        );
        assert_eq!(report_of(&anyhow::anyhow!("alone")), "Error: alone");
    }

    #[test]
    fn a_plain_error_gives_its_message_and_chain() {
        let mut log = progress_lines();
        log.extend(CHAIN.map(String::from));
        check_chain(&log.join("\n"), "plain");
    }

    #[test]
    fn a_backtrace_after_the_chain_is_dropped() {
        // RUST_BACKTRACE=1 / full and RUST_LIB_BACKTRACE=1: anyhow appends the frames.
        for frames in [
            vec![
                "",
                "Stack backtrace:",
                "   0: anyhow::error::<impl anyhow::Error>::msg",
                "             at /rustc/src/error.rs:83:36",
                "   1: pednav_learner::main",
            ],
            vec![
                "",
                "Stack backtrace:",
                "   0: std::backtrace_rs::backtrace::libunwind::trace",
                "   1: std::backtrace::Backtrace::create",
            ],
        ] {
            let mut log = progress_lines();
            log.extend(CHAIN.map(String::from));
            log.extend(frames.iter().map(|s| s.to_string()));
            check_chain(&log.join("\n"), "with a backtrace");
        }
    }

    #[test]
    fn debug_lines_after_the_report_do_not_hide_it() {
        // RUST_LOG=debug: other threads may still log while the process exits.
        let mut log = progress_lines();
        log.extend(CHAIN.map(String::from));
        log.push("2026-12-01T10:00:22Z DEBUG iceoryx2::port: node removed".into());
        log.push("2026-12-01T10:00:22Z DEBUG wgpu_core::device: dropping device".into());
        check_chain(&log.join("\n"), "with debug lines after it");
    }

    #[test]
    fn a_single_cause_and_a_panic_and_a_silent_log() {
        let log = "x\nError: resuming from runs/x\n\nCaused by:\n    checksum mismatch: the file is corrupted";
        let c = ExitCause::parse(log);
        assert_eq!(c.headline(), "resuming from runs/x — checksum mismatch: the file is corrupted");
        assert!(c.report().ends_with("Caused by:\n    checksum mismatch: the file is corrupted"), "{}", c.report());
        let panic = "INFO start\nthread 'main' panicked at learner/src/replay.rs:88:9:\nindex out of bounds\nstack backtrace:\n   0: rust_begin_unwind";
        let c = ExitCause::parse(panic);
        assert_eq!(c.headline(), "thread 'main' panicked at learner/src/replay.rs:88:9:");
        assert!(c.report().contains("index out of bounds") && !c.report().contains("rust_begin_unwind"));
        let plain: String = (0..20).map(|i| format!("line {i}\n")).collect();
        let c = ExitCause::parse(&plain);
        assert_eq!((c.headline(), c.context.len()), ("line 19".to_string(), TAIL_LINES));
    }
}
