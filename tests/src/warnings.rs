//! The `tracing` warnings a test provokes, captured per thread — shared by the fault
//! tests of several crates (this crate is their dev-dependency).
//!
//! One global subscriber, installed before the test binary's first event, hands every
//! warning to the calling thread's sink while [`logged_warnings`] runs. A scoped
//! (`with_default`) subscriber per test was flaky: a callsite first reached on another
//! test's thread while this test's dispatcher was registering could be cached as
//! "never interested", and the warning was lost. Call [`install`] first in every test
//! of a binary that uses this, so that no callsite is registered before it.

use std::cell::RefCell;
use std::sync::Once;

thread_local! {
    static SINK: RefCell<Option<Vec<String>>> = const { RefCell::new(None) };
}

/// Install the capturing subscriber as the binary's global default (once).
pub fn install() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        tracing::subscriber::set_global_default(Warnings)
            .expect("no other global tracing subscriber in this test binary");
    });
}

/// The warnings logged on this thread while `f` runs, each as its fields' text.
pub fn logged_warnings<T>(f: impl FnOnce() -> T) -> (T, Vec<String>) {
    install();
    SINK.with(|s| *s.borrow_mut() = Some(Vec::new()));
    let out = f();
    let seen = SINK.with(|s| s.borrow_mut().take()).unwrap_or_default();
    (out, seen)
}

struct Warnings;

impl tracing::Subscriber for Warnings {
    fn register_callsite(&self, _: &'static tracing::Metadata<'static>) -> tracing::subscriber::Interest {
        tracing::subscriber::Interest::sometimes()
    }
    fn enabled(&self, metadata: &tracing::Metadata<'_>) -> bool {
        *metadata.level() <= tracing::Level::WARN
    }
    fn new_span(&self, _: &tracing::span::Attributes<'_>) -> tracing::span::Id {
        tracing::span::Id::from_u64(1)
    }
    fn record(&self, _: &tracing::span::Id, _: &tracing::span::Record<'_>) {}
    fn record_follows_from(&self, _: &tracing::span::Id, _: &tracing::span::Id) {}
    fn event(&self, event: &tracing::Event<'_>) {
        SINK.with(|s| {
            if let Some(seen) = s.borrow_mut().as_mut() {
                let mut text = String::new();
                event.record(&mut Fields(&mut text));
                seen.push(text);
            }
        });
    }
    fn enter(&self, _: &tracing::span::Id) {}
    fn exit(&self, _: &tracing::span::Id) {}
}

struct Fields<'a>(&'a mut String);

impl tracing::field::Visit for Fields<'_> {
    fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
        use std::fmt::Write;
        let _ = write!(self.0, "{}={value:?} ", field.name());
    }
}
