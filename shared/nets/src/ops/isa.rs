//! Instruction-set paths of the custom CPU kernels, chosen once per process.
//!
//! Every kernel of [`crate::ops`] (the direct convolution, the small-batch fully
//! connected layer, and the gemm calls behind the convolution and the linear layer)
//! exists for three instruction sets:
//!
//! | [`Isa`] | needs | vector width |
//! |---|---|---|
//! | `baseline` | any x86-64 (SSE2) or other CPU | plain Rust, multiply then add |
//! | `avx2` | AVX2 + FMA (x86-64-v3: every x86 CPU since ≈ 2015) | 8 floats, fused multiply-add |
//! | `avx512` | AVX-512F + AVX2 + FMA (x86-64-v4) | 16 floats |
//!
//! The best path the CPU has is used unless the environment variable `PEDNAV_ISA`
//! (`baseline`, `avx2` or `avx512`) asks for another, so a developer on an AVX-512
//! machine can measure and test the AVX2 path that most cloud CPUs run. Asking for a
//! path the CPU lacks is an error (it would crash on an illegal instruction), never a
//! silent fallback. candle's own operations (element-wise ops, its matmul) keep
//! their own dispatch; the switch covers this crate's kernels.
//!
//! Invariant: [`Isa::active`] returns the same value for the whole life of the
//! process, and only a path for which [`Isa::is_supported`] holds.

use std::sync::OnceLock;

use crate::error::{NetError, config_error};

/// Environment variable that forces an instruction-set path.
pub const ISA_ENV: &str = "PEDNAV_ISA";

/// An instruction-set path of the custom kernels (ordered: each includes the ones before).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Isa {
    /// Portable code: no fused multiply-add, no wide vectors assumed.
    Baseline,
    /// AVX2 with FMA: 8-float vectors.
    Avx2,
    /// AVX-512F (with AVX2 and FMA): 16-float vectors.
    Avx512,
}

impl Isa {
    /// Every path, narrowest first.
    pub const ALL: [Isa; 3] = [Isa::Baseline, Isa::Avx2, Isa::Avx512];

    /// The name `PEDNAV_ISA` takes and the benches print.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Baseline => "baseline",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }

    /// Whether this CPU can run the path.
    pub fn is_supported(self) -> bool {
        match self {
            Isa::Baseline => true,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma"),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => Isa::Avx2.is_supported() && std::arch::is_x86_feature_detected!("avx512f"),
            #[cfg(not(target_arch = "x86_64"))]
            Isa::Avx2 | Isa::Avx512 => false,
        }
    }

    /// The widest path this CPU supports.
    pub fn detected() -> Isa {
        Isa::ALL.into_iter().rev().find(|i| i.is_supported()).unwrap_or(Isa::Baseline)
    }

    /// Every path this CPU supports, narrowest first (the tests run each).
    pub fn supported() -> Vec<Isa> {
        Isa::ALL.into_iter().filter(|i| i.is_supported()).collect()
    }

    /// Parse a `PEDNAV_ISA` value and check that this CPU can run it.
    pub fn parse(value: &str) -> Result<Isa, NetError> {
        let isa = Isa::ALL.into_iter().find(|i| i.name() == value.trim().to_ascii_lowercase()).ok_or_else(|| {
            config_error(ISA_ENV, value, "expected one of `baseline`, `avx2`, `avx512` (unset: the best this CPU has)")
        })?;
        if !isa.is_supported() {
            return Err(config_error(
                ISA_ENV,
                value,
                format!("this CPU cannot run it (best available: `{}`); unset it or pick that", Isa::detected().name()),
            ));
        }
        Ok(isa)
    }

    /// The path `PEDNAV_ISA` asks for, or the best this CPU supports when it is unset
    /// or empty.
    pub fn from_env() -> Result<Isa, NetError> {
        match std::env::var(ISA_ENV) {
            Ok(v) if !v.trim().is_empty() => Isa::parse(&v),
            _ => Ok(Isa::detected()),
        }
    }

    /// The path every kernel of this process uses, read once from the environment.
    ///
    /// # Panics
    /// If `PEDNAV_ISA` names an unknown path or one this CPU cannot run, with the
    /// message of [`Isa::from_env`] (which names the variable and what is allowed).
    /// [`crate::init_cpu_runtime`] resolves it first thing, so a bad value stops a
    /// process at start-up; call [`Isa::from_env`] to handle the error yourself.
    pub fn active() -> Isa {
        static ACTIVE: OnceLock<Isa> = OnceLock::new();
        *ACTIVE.get_or_init(|| Isa::from_env().unwrap_or_else(|e| panic!("{e}")))
    }
}

impl std::fmt::Display for Isa {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_values_name_the_variable() {
        for isa in Isa::supported() {
            assert_eq!(Isa::parse(isa.name()).unwrap(), isa);
            assert_eq!(Isa::parse(&isa.name().to_uppercase()).unwrap(), isa);
        }
        let err = Isa::parse("avx513").unwrap_err().to_string();
        assert!(err.contains("PEDNAV_ISA") && err.contains("avx513") && err.contains("avx2"), "{err}");
    }

    #[test]
    fn unsupported_paths_are_refused_and_supported_ones_are_ordered() {
        let supported = Isa::supported();
        assert_eq!(supported[0], Isa::Baseline);
        assert_eq!(*supported.last().unwrap(), Isa::detected());
        for isa in Isa::ALL {
            assert_eq!(Isa::parse(isa.name()).is_ok(), supported.contains(&isa));
        }
    }
}
