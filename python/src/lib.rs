//! # pednav-py — pednav-sim as the Python extension module `pednav_gym._pednav`
//!
//! The Rust half of the `pednav_gym` package (`python/README.md`). The Gymnasium
//! environments in `pednav_gym/` drive the built-in simulator through one class,
//! [`Simulator`] — M pedestrians of a [`pednav_sim::VecEnv`] sharing one world and one
//! renderer — plus a few module-level facts: the action's size and range and the
//! paper's validation starts. Nothing is simulated here: the scene files, the
//! settings and their validation, the reward, the physics, the renderer and the
//! oracle are pednav-sim's; this crate moves requests in and results out.
//!
//! Invariants:
//! - a setting or a scene reaches the simulator only through pednav-sim's own schema
//!   and checks ([`settings`], `Scene::load_or_reference`); whatever the Rust side
//!   refuses is raised as a [`PednavError`] whose message is the Rust error's, which
//!   names the field;
//! - while Rust steps, renders or plans, the GIL is released (`Python::detach`) and
//!   no Python object is touched;
//! - observations cross as one `bytearray` per call, all environments in order
//!   ([`observation`]), which Python views with `numpy.frombuffer` without copying.

#![warn(missing_docs)]

pub mod batch;
pub mod observation;
pub mod settings;
pub mod simulator;
pub mod starts;

use std::path::PathBuf;

use pednav_sim::{Action, Scene, SimError};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

pub use batch::StepBatch;
pub use simulator::Simulator;

pyo3::create_exception!(
    pednav_gym,
    PednavError,
    PyValueError,
    "A request the simulator refused: a setting, scene, start pose or action. The message is pednav-sim's and names the field or value."
);

/// The simulator's error as a Python exception carrying its message.
pub fn sim_error(error: SimError) -> PyErr {
    PednavError::new_err(error.to_string())
}

/// Components of an action: (speed, yaw rate, head yaw), pednav-sim's [`Action`].
pub const ACTION_DIM: usize = std::mem::size_of::<Action>() / std::mem::size_of::<f32>();
/// Lowest value of each action component; lower values are clipped (`pednav_sim::command_of`).
pub const ACTION_LOW: f32 = -1.0;
/// Highest value of each action component; higher values are clipped.
pub const ACTION_HIGH: f32 = 1.0;

/// The paper's validation starts of a scene (`built-in:<name>` or a file; the reference
/// corner when `None`): every validation point at each of the protocol's eight yaws, as
/// `(point, x m, y m, yaw °)` in the protocol's order (points outer, yaws inner).
#[pyfunction]
#[pyo3(signature = (scene=None))]
fn validation_starts(py: Python<'_>, scene: Option<PathBuf>) -> PyResult<Vec<starts::StartPose>> {
    let scene = py.detach(move || Scene::load_or_reference(scene.as_deref())).map_err(sim_error)?;
    Ok(starts::validation(&scene))
}

/// The extension module: [`Simulator`], [`StepBatch`], [`PednavError`], the action's
/// size and range, the state observation's size and [`validation_starts`].
#[pymodule(name = "_pednav")]
mod extension {
    #[pymodule_export]
    use super::{PednavError, Simulator, StepBatch, validation_starts};

    #[pymodule_export]
    const ACTION_DIM: usize = super::ACTION_DIM;
    #[pymodule_export]
    const ACTION_LOW: f32 = super::ACTION_LOW;
    #[pymodule_export]
    const ACTION_HIGH: f32 = super::ACTION_HIGH;
    #[pymodule_export]
    const STATE_DIM: usize = pednav_sim::STATE_OBS_DIM;
    #[pymodule_export]
    const TRAFFIC_STATE_DIM: usize = pednav_sim::TRAFFIC_STATE_DIM;

    /// Give the graphics stack a private runtime directory when none is set, as the
    /// simulator's commands do (`pednav_sim::prepare_headless_env`, which does nothing
    /// once other threads run: from Python they always do, so `pednav_gym/__init__.py`
    /// sets the same directory before importing this module).
    #[pymodule_init]
    fn init() {
        pednav_sim::prepare_headless_env();
    }
}
