//! Gymnasium v5 MuJoCo tasks on MuJoCo 3.17.0 through the crate `mujoco-rs` (feature `mujoco`).
//!
//! One [`MujocoEnv`] steps exactly as Gymnasium's `MujocoEnv.step` does: `data.ctrl = action`
//! (float32 widened to float64; MuJoCo clamps it to the control range), `mj_step` frame-skip
//! times, `mj_rnePostConstraint` (for Ant's contact forces), then the task's observation, reward
//! and health rule ([`Task`]). With the same MuJoCo library the physics is bit-identical to
//! Python's `mujoco`, so a replay of Gymnasium's trajectories agrees to the last bit
//! (`tests/gymnasium_mujoco.rs`).
//!
//! Observations are float64 in Gymnasium; [`Env::step`] writes them rounded to f32 and
//! [`Env::observation_f64`] gives the float64 values. The physical state for [`RestorableEnv::reset_to`] is
//! qpos followed by qvel; a reset clears MuJoCo's data first (`mj_resetData`, so warm starts and
//! time are those of a fresh episode), as Gymnasium's `reset` does. A checkpoint taken
//! mid-episode also keeps [`RestorableEnv::resume_state`] (MuJoCo's integration state with the solver's warm
//! start), so the resumed episode continues bit for bit (`tests/mujoco_resume.rs`).

mod model;
mod task;

pub use model::{assets_dir, ASSETS_ENV_VAR};
pub use task::{ant_is_healthy, hopper_is_healthy, walker2d_is_healthy, Task, MAX_EPISODE_STEPS};

use mbpo_core::rng::{normal_f64, uniform_range_f64};
use mbpo_core::Rng;
use mujoco_rs::prelude::{MjData, MjModel, MjtState};

/// MuJoCo's state that `mj_step` integrates from: time, qpos, qvel, actuator activations, the
/// solver's warm start (`qacc_warmstart`), ... (`mjSTATE_INTEGRATION`).
const INTEGRATION_STATE: u32 = MjtState::mjSTATE_INTEGRATION as u32;

use crate::{BoxSpace, Env, EnvError, RestorableEnv, Step};
use task::{StepState, VelocityNoise};

/// A Gymnasium v5 MuJoCo task (see the module docs).
pub struct MujocoEnv {
    task: Task,
    data: MjData<Box<MjModel>>,
    /// `data.qpos` / `data.qvel` of a fresh `MjData` (the model's qpos0 and zeros).
    init_qpos: Vec<f64>,
    init_qvel: Vec<f64>,
    /// `model.opt.timestep * frame_skip`, as Gymnasium's `dt` property computes it.
    dt: f64,
    obs64: Vec<f64>,
    /// Scratch for the contact cost (nbody × 6).
    scratch: Vec<f64>,
    steps: usize,
    /// The x position the next step measures its forward velocity from, when restored from a
    /// checkpoint (see [`RestorableEnv::resume_state`]); `None`: read it from `data`.
    restored_x_before: Option<f64>,
    observation_space: BoxSpace,
    action_space: BoxSpace,
}

impl std::fmt::Debug for MujocoEnv {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MujocoEnv")
            .field("task", &self.task)
            .field("steps", &self.steps)
            .finish_non_exhaustive()
    }
}

impl MujocoEnv {
    /// Load the task's MJCF file from Gymnasium's assets (see [`assets_dir`]).
    pub fn new(task: Task) -> Result<Self, EnvError> {
        Self::with_assets(task, &assets_dir())
    }

    /// Load the task's MJCF file ([`Task::xml_file`]) from the folder `assets`.
    pub fn with_assets(task: Task, assets: &std::path::Path) -> Result<Self, EnvError> {
        let model = Box::new(model::load(task.id(), assets, task.xml_file())?);
        let timestep = model.opt().timestep;
        let ctrlrange = model.actuator_ctrlrange().to_vec();
        let data = MjData::new(model);
        let init_qpos = data.qpos().to_vec();
        let init_qvel = data.qvel().to_vec();
        let obs_dim = init_qpos.len() - task.skipped_qpos() + init_qvel.len();
        let scratch = vec![0.0; data.cfrc_ext().len() * 6];
        Ok(Self {
            task,
            dt: timestep * task.frame_skip() as f64,
            obs64: vec![0.0; obs_dim],
            scratch,
            steps: 0,
            restored_x_before: None,
            observation_space: BoxSpace::new(
                vec![f32::NEG_INFINITY; obs_dim],
                vec![f32::INFINITY; obs_dim],
            ),
            // `actuator_ctrlrange.astype(np.float32)`.
            action_space: BoxSpace::new(
                ctrlrange.iter().map(|r| r[0] as f32).collect(),
                ctrlrange.iter().map(|r| r[1] as f32).collect(),
            ),
            init_qpos,
            init_qvel,
            data,
        })
    }

    /// The task.
    pub fn task(&self) -> Task {
        self.task
    }

    /// Seconds of simulated time per step.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// The forward coordinate whose change is rewarded: Ant's torso body x (`data.body(1).xpos`,
    /// which `mj_step` computed before its last integration), Humanoid's centre of mass (from
    /// `xipos`, the same), otherwise qpos[0].
    fn x_position(&self) -> f64 {
        match self.task {
            Task::Ant => self.data.xpos()[1][0],
            Task::Humanoid => task::mass_center_x(self.data.model().body_mass(), self.data.xipos()),
            _ => self.data.qpos()[0],
        }
    }

    /// Gymnasium's `set_state` after `mj_resetData`: a fresh episode at (qpos, qvel).
    fn set_state(&mut self, qpos: &[f64], qvel: &[f64]) {
        self.data.reset();
        self.data.qpos_mut().copy_from_slice(qpos);
        self.data.qvel_mut().copy_from_slice(qvel);
        self.data.forward();
        self.steps = 0;
        self.restored_x_before = None;
    }

    fn write_obs(&mut self, obs: &mut [f32]) {
        self.task
            .write_observation(self.data.qpos(), self.data.qvel(), &mut self.obs64);
        for (o, &v) in obs.iter_mut().zip(&self.obs64) {
            *o = v as f32;
        }
    }
}

impl Env for MujocoEnv {
    fn id(&self) -> &'static str {
        self.task.id()
    }

    fn observation_space(&self) -> &BoxSpace {
        &self.observation_space
    }

    fn action_space(&self) -> &BoxSpace {
        &self.action_space
    }

    fn max_episode_steps(&self) -> usize {
        MAX_EPISODE_STEPS
    }

    /// qpos = init_qpos + U(−s, s); qvel = init_qvel + U(−s, s) or s·N(0, 1) (per task), drawn
    /// from `rng` (the distributions of Gymnasium's `reset_model`, not NumPy's bits).
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) -> Result<(), EnvError> {
        let (scale, velocity_noise) = self.task.reset_noise();
        let qpos: Vec<f64> = self
            .init_qpos
            .iter()
            .map(|&q| q + uniform_range_f64(rng, -scale, scale))
            .collect();
        let qvel: Vec<f64> = self
            .init_qvel
            .iter()
            .map(|&v| {
                v + match velocity_noise {
                    VelocityNoise::Uniform => uniform_range_f64(rng, -scale, scale),
                    VelocityNoise::Normal => scale * normal_f64(rng),
                }
            })
            .collect();
        self.set_state(&qpos, &qvel);
        self.write_obs(obs);
        Ok(())
    }

    fn elapsed_steps(&self) -> usize {
        self.steps
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<Step, EnvError> {
        debug_assert_eq!(action.len(), self.act_dim(), "{}: action length", self.id());
        let x_before = self
            .restored_x_before
            .take()
            .unwrap_or_else(|| self.x_position());
        for (c, &a) in self.data.ctrl_mut().iter_mut().zip(action) {
            *c = a as f64;
        }
        for _ in 0..self.task.frame_skip() {
            self.data.step();
        }
        self.data.rne_post_constraint();
        self.write_obs(obs);
        let x_velocity = (self.x_position() - x_before) / self.dt;
        let cfrc_ext: &[f64] = match self.task {
            Task::Ant | Task::Humanoid => self.data.cfrc_ext().as_flattened(),
            _ => &[],
        };
        let (reward, terminated) = self.task.reward(&mut StepState {
            qpos: self.data.qpos(),
            qvel: self.data.qvel(),
            obs: &self.obs64,
            x_velocity,
            action,
            cfrc_ext,
            scratch: &mut self.scratch,
        });
        self.steps += 1;
        Ok(Step {
            reward,
            terminated,
            truncated: self.steps >= MAX_EPISODE_STEPS,
        })
    }

    fn observation_f64(&self) -> Option<&[f64]> {
        Some(&self.obs64)
    }

    fn restorable(&self) -> Option<&dyn RestorableEnv> {
        Some(self)
    }

    fn restorable_mut(&mut self) -> Option<&mut dyn RestorableEnv> {
        Some(self)
    }
}

impl RestorableEnv for MujocoEnv {
    fn state_dim(&self) -> usize {
        self.init_qpos.len() + self.init_qvel.len()
    }

    fn state_layout(&self) -> &'static str {
        self.task.state_layout()
    }

    fn reset_to(&mut self, state: &[f64], obs: &mut [f32]) -> Result<(), EnvError> {
        let nq = self.init_qpos.len();
        if state.len() != self.state_dim() {
            return Err(EnvError::StateDim {
                env: self.task.id(),
                expected: self.state_dim(),
                found: state.len(),
                layout: self.task.state_layout(),
            });
        }
        let (qpos, qvel) = state.split_at(nq);
        self.set_state(qpos, qvel);
        self.write_obs(obs);
        Ok(())
    }

    /// Restores only the step count; `reset_to(qpos ++ qvel)` starts from a fresh `mjData`, so
    /// without [`RestorableEnv::set_resume_state`] the solver's warm start differs from the uninterrupted
    /// episode and the continuation is close to, not bit-identical with, the original.
    fn set_elapsed_steps(&mut self, steps: usize) {
        self.steps = steps;
    }

    /// MuJoCo's integration state (`mjSTATE_INTEGRATION`, with the solver's warm start) and the
    /// x position the next step's forward velocity starts from: Ant and Humanoid read it from
    /// `xpos` and `xipos`, which after a step hold the last sub-step's kinematics, not those of
    /// `qpos`. (MuJoCo keeps a little state outside `mjtState` -- sleeping trees, flex contacts
    /// -- which none of these six models uses; a model that does would need it here too.)
    fn resume_state(&self) -> Vec<f64> {
        let mut extra = self.data.state(INTEGRATION_STATE).into_vec();
        extra.push(self.restored_x_before.unwrap_or_else(|| self.x_position()));
        extra
    }

    fn set_resume_state(&mut self, extra: &[f64]) -> Result<(), EnvError> {
        let n = self.data.model().state_size(INTEGRATION_STATE);
        if extra.len() != n + 1 {
            return Err(EnvError::StateDim {
                env: self.task.id(),
                expected: n + 1,
                found: extra.len(),
                layout: "MuJoCo's integration state (mjSTATE_INTEGRATION), then the x position",
            });
        }
        self.data
            .set_state(&extra[..n], INTEGRATION_STATE)
            .map_err(|e| EnvError::ResumeState {
                env: self.task.id(),
                message: e.to_string(),
            })?;
        self.restored_x_before = Some(extra[n]);
        Ok(())
    }

    fn state(&self) -> Vec<f64> {
        let mut s = self.data.qpos().to_vec();
        s.extend_from_slice(self.data.qvel());
        s
    }
}
