//! [`Simulator`]: M pedestrians of pednav-sim behind one Python object — what the
//! Gymnasium classes of `pednav_gym` call.
//!
//! One call does one thing to all M environments: `reset` starts the episodes it is
//! given; `step` advances every environment by its action, except those it is asked to
//! restart instead (Gymnasium's next-step autoreset: their actions are ignored); both
//! return every environment's observation — in pixel mode all M views rendered in one
//! submission — with a [`StepBatch`]. `render_people` draws the large views a person
//! looks at, as `pednav-sim view` does, and `oracle_actions` plans the oracle once per
//! simulator and returns its greedy action in every environment.
//!
//! Invariant: everything a call asks for is checked before any environment changes —
//! environment indices, start poses (`Scene::check_task`), the number of actions and,
//! for the environments that step, that they are inside an episode and their actions
//! finite (the checks of `VecEnv::step`, with its errors) — so a refused call changes
//! nothing. Only a failure of the renderer itself can interrupt a call midway.

use std::path::PathBuf;
use std::sync::Arc;

use pednav_sim::oracle::{Oracle, OracleConfig};
use pednav_sim::{
    Action, BackendChoice, Pose, Renderer, RendererConfig, Scene, SimConfig, SimError, SimWorld, Transition, VecEnv,
};
use pyo3::exceptions::PyIndexError;
use pyo3::prelude::*;
use pyo3::types::{PyByteArray, PyDict};

use crate::batch::{StepBatch, Stepped};
use crate::starts::StartPose;
use crate::{PednavError, observation, settings, sim_error, starts};

/// A start Python asks for: `(environment, x m, y m, yaw °, episode seed)`; the seed
/// drives the episode's randomness (the look, when domain randomisation is on).
pub type StartRequest = (usize, f32, f32, f32, u64);

/// The action given to an environment that restarts instead of stepping: any finite
/// action does, as its step is undone.
const IGNORED_ACTION: Action = [0.0; 3];

/// Views for people rendered per submission: a 2×2 atlas of the largest views
/// (1024², the observation's limit) stays at 2048 texels a side, within every adapter.
const PEOPLE_VIEWS_PER_CALL: usize = 4;

/// M pedestrian environments of pednav-sim sharing one world and one renderer.
///
/// `Simulator(num_envs, scene=None, settings=None, backend=None)`: `scene` is a scene
/// file or `built-in:<name>` (the reference corner when `None`), `settings` a dict of
/// `SimConfig` fields (`image_size`, `obs_mode`, `t_max`, …) over its defaults, `backend`
/// `auto`, `vulkan` or `gl` (`PEDNAV_BACKEND` when `None`). Refused values raise
/// `PednavError` naming the field.
#[pyclass(module = "pednav_gym._pednav")]
pub struct Simulator {
    envs: VecEnv,
    backend: BackendChoice,
    /// The observations of the last call, reused from call to call.
    buffer: Vec<u8>,
    /// Renderer of the views for people, built on first use at the size asked for.
    people: Option<Renderer>,
    /// The oracle's plan over this world, made on first use (seconds).
    oracle: Option<Oracle>,
}

/// A start checked against the scene.
struct Start {
    env: usize,
    pose: Pose,
    seed: u64,
}

#[pymethods]
impl Simulator {
    #[new]
    #[pyo3(signature = (num_envs, scene=None, settings=None, backend=None))]
    fn new(
        py: Python<'_>,
        num_envs: usize,
        scene: Option<PathBuf>,
        settings: Option<&Bound<'_, PyDict>>,
        backend: Option<&str>,
    ) -> PyResult<Simulator> {
        let config = settings::sim_config(settings)?;
        let backend = settings::backend(backend)?;
        let envs = py
            .detach(move || -> Result<VecEnv, SimError> {
                let scene = Scene::load_or_reference(scene.as_deref())?;
                let world = SimWorld::new(scene, config)?;
                VecEnv::new(Arc::new(world), num_envs, backend)
            })
            .map_err(sim_error)?;
        Ok(Simulator { envs, backend, buffer: Vec::new(), people: None, oracle: None })
    }

    /// Number of environments M.
    #[getter]
    fn num_envs(&self) -> usize {
        self.envs.num_envs()
    }

    /// The simulator's settings after defaults and overrides, as a dict of `SimConfig`
    /// field → value.
    #[getter]
    fn settings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        settings::settings_dict(py, &self.envs.world().config)
    }

    /// Where the scene came from: its path or `built-in:<name>`.
    #[getter]
    fn scene(&self) -> String {
        self.envs.world().scene.origin.clone()
    }

    /// The graphics adapter of the observation renderer ("name (backend, device
    /// type)"), or `None` in state mode, which renders no observation.
    #[getter]
    fn adapter(&self) -> Option<String> {
        self.envs.renderer().map(Renderer::adapter_description)
    }

    /// Lowest and highest value of each entry of the state observation in this world.
    fn state_bounds(&self) -> (Vec<f32>, Vec<f32>) {
        observation::state_bounds(self.envs.world())
    }

    /// The paper's validation starts of this scene, `(point, x, y, yaw °)` (see the
    /// module function `validation_starts`).
    fn validation_starts(&self) -> Vec<StartPose> {
        starts::validation(&self.envs.world().scene)
    }

    /// The scene's first task (the curriculum's easiest start), `(x, y, yaw °)`.
    fn first_task(&self) -> (f32, f32, f32) {
        starts::degrees(self.envs.world().scene.spec.first_task)
    }

    /// The scene's fixed start (the Non-ACL variants'), `(x, y, yaw °)`.
    fn fixed_start(&self) -> (f32, f32, f32) {
        starts::degrees(self.envs.world().scene.spec.fixed_start)
    }

    /// Start an episode in each environment of `starts` (`(env, x, y, yaw °, seed)`,
    /// each environment at most once); the others are left as they are. Returns the
    /// observations of all environments and the batch (nothing stepped).
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        starts: Vec<StartRequest>,
    ) -> PyResult<(Bound<'py, PyByteArray>, StepBatch)> {
        let starts = checked_starts(&self.envs, &starts)?;
        let (envs, buffer) = (&mut self.envs, &mut self.buffer);
        let batch = py
            .detach(move || -> Result<StepBatch, SimError> {
                for s in &starts {
                    envs.reset(s.env, s.pose, s.seed)?;
                }
                let nothing_stepped: Vec<Stepped> = vec![None; envs.num_envs()];
                let batch = StepBatch::collect(envs, &nothing_stepped);
                observation::write(envs, buffer)?;
                Ok(batch)
            })
            .map_err(sim_error)?;
        Ok((PyByteArray::new(py, &self.buffer), batch))
    }

    /// Step every environment with its action (`actions[e]` = (speed, yaw rate, head
    /// yaw) in [−1, 1]), except the environments of `restarts`, which start a new
    /// episode instead and ignore their action. Returns the observations of all
    /// environments and the batch.
    #[pyo3(signature = (actions, restarts=Vec::new()))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        actions: Vec<Action>,
        restarts: Vec<StartRequest>,
    ) -> PyResult<(Bound<'py, PyByteArray>, StepBatch)> {
        let count = self.envs.num_envs();
        if actions.len() != count {
            return Err(sim_error(SimError::ActionCount { expected: count, got: actions.len() }));
        }
        let starts = checked_starts(&self.envs, &restarts)?;
        let mut restarting = vec![false; count];
        for s in &starts {
            restarting[s.env] = true;
        }
        // `VecEnv::step`'s own checks, made before a restart changes anything.
        for (env, action) in actions.iter().enumerate().filter(|&(env, _)| !restarting[env]) {
            if self.envs.pedestrian(env).done {
                return Err(sim_error(SimError::NeedsReset { env }));
            }
            if !action.iter().all(|v| v.is_finite()) {
                return Err(sim_error(SimError::NonFiniteAction { env, action: *action }));
            }
        }
        let actions: Vec<Action> =
            actions.iter().zip(&restarting).map(|(&a, &restart)| if restart { IGNORED_ACTION } else { a }).collect();
        let (envs, buffer) = (&mut self.envs, &mut self.buffer);
        let batch = py
            .detach(move || -> Result<StepBatch, SimError> {
                // `VecEnv::step` steps every environment, so a restarting one starts,
                // takes the ignored step and is put back at its start: a start is a pure
                // function of (pose, seed) and the world never changes.
                for s in &starts {
                    envs.reset(s.env, s.pose, s.seed)?;
                }
                let transitions: Vec<Transition> = envs.step(&actions)?.to_vec();
                for s in &starts {
                    envs.reset(s.env, s.pose, s.seed)?;
                }
                let stepped: Vec<Stepped> =
                    (0..count).map(|e| (!restarting[e]).then_some((actions[e], transitions[e]))).collect();
                let batch = StepBatch::collect(envs, &stepped);
                observation::write(envs, buffer)?;
                Ok(batch)
            })
            .map_err(sim_error)?;
        Ok((PyByteArray::new(py, &self.buffer), batch))
    }

    /// The current observation of every environment, without changing any.
    fn observations<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyByteArray>> {
        let (envs, buffer) = (&mut self.envs, &mut self.buffer);
        py.detach(move || observation::write(envs, buffer)).map_err(sim_error)?;
        Ok(PyByteArray::new(py, &self.buffer))
    }

    /// The view for people of each environment of `envs`: `size`² greyscale bytes each,
    /// one after another, from the environment's camera (head yaw and look included),
    /// as `pednav-sim view` renders its large picture.
    #[pyo3(signature = (envs, size=512))]
    fn render_people<'py>(
        &mut self,
        py: Python<'py>,
        envs: Vec<usize>,
        size: u32,
    ) -> PyResult<Bound<'py, PyByteArray>> {
        for &env in &envs {
            check_index(env, self.envs.num_envs())?;
        }
        let world = self.envs.world().clone();
        // The renderer draws every size an observation may have, and no other.
        SimConfig { image_size: size, ..world.config.clone() }.validate().map_err(sim_error)?;
        let cameras: Vec<_> = envs.iter().map(|&env| self.envs.camera(env)).collect();
        let (slot, backend) = (&mut self.people, self.backend);
        let pixels = py
            .detach(move || -> Result<Vec<u8>, SimError> {
                let renderer = people_renderer(slot, &world, size, backend)?;
                let frame_len = (size * size) as usize;
                let mut out = vec![0u8; cameras.len() * frame_len];
                for (views, dst) in
                    cameras.chunks(PEOPLE_VIEWS_PER_CALL).zip(out.chunks_mut(PEOPLE_VIEWS_PER_CALL * frame_len))
                {
                    let frames = renderer.render(views)?;
                    for (i, frame) in dst.chunks_exact_mut(frame_len).enumerate() {
                        frames.copy_frame(i, frame);
                    }
                }
                Ok(out)
            })
            .map_err(sim_error)?;
        Ok(PyByteArray::new(py, &pixels))
    }

    /// The oracle's greedy action in every environment (planned on the first call, over
    /// this world with `OracleConfig::default()`, as `pednav-sim` plans it).
    fn oracle_actions(&mut self, py: Python<'_>) -> Vec<Action> {
        let (envs, slot) = (&self.envs, &mut self.oracle);
        let world = envs.world().clone();
        let pedestrians: Vec<_> = (0..envs.num_envs()).map(|env| *envs.pedestrian(env)).collect();
        py.detach(move || {
            let oracle = slot.get_or_insert_with(|| Oracle::plan(&world, OracleConfig::default()));
            pedestrians.iter().map(|p| oracle.best_action(&world, p)).collect()
        })
    }
}

fn check_index(env: usize, count: usize) -> PyResult<()> {
    if env < count {
        Ok(())
    } else {
        Err(PyIndexError::new_err(format!("environment {env} does not exist (the simulator has {count})")))
    }
}

/// The starts of `requests`, each environment existing and named once, each pose one the
/// scene accepts as an episode start.
fn checked_starts(envs: &VecEnv, requests: &[StartRequest]) -> PyResult<Vec<Start>> {
    let mut named = vec![false; envs.num_envs()];
    let mut starts = Vec::with_capacity(requests.len());
    for &(env, x, y, yaw_deg, seed) in requests {
        check_index(env, envs.num_envs())?;
        if std::mem::replace(&mut named[env], true) {
            return Err(PednavError::new_err(format!("environment {env} is started twice in one call")));
        }
        let pose = Pose::from_degrees(x, y, yaw_deg);
        envs.world().scene.check_task(pose).map_err(sim_error)?;
        starts.push(Start { env, pose, seed });
    }
    Ok(starts)
}

/// The renderer for people's views of `size`², built (again) when there is none of that size.
fn people_renderer<'a>(
    slot: &'a mut Option<Renderer>,
    world: &SimWorld,
    size: u32,
    backend: BackendChoice,
) -> Result<&'a mut Renderer, SimError> {
    if slot.as_ref().is_none_or(|r| r.config().image_size != size) {
        let config = RendererConfig {
            image_size: size,
            ..RendererConfig::from_sim(&world.config, PEOPLE_VIEWS_PER_CALL, backend)
        };
        *slot = Some(Renderer::new(&world.scene, &world.map, config)?);
    }
    Ok(slot.as_mut().expect("a renderer was just made"))
}
