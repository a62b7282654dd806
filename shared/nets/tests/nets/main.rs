//! One test binary for the networks crate (one link in CI), a module per subject: the
//! convolution kernel and its chain op, heads, networks and encoders, the streaming cache and AdamW.

mod adamw;
mod allocator;
mod common;
mod conv;
mod conv_chain;
mod encoders;
mod heads;
mod stream_cache;
mod support;

/// Every test of this binary (convolution, heads, encoders, the streaming cache,
/// AdamW) also passes on the other instruction-set paths of the kernels.
#[test]
fn every_test_here_passes_on_every_instruction_set() {
    common::rerun_on_every_other_isa("every_test_here_passes_on_every_instruction_set");
}
