//! `mbpo bench diagnose`: what a run's critic and model believe, held against the real
//! environment, at a kept checkpoint.
//!
//! MBPO trains its critic mostly on model data (1 − real_ratio = 95 % of each batch). When a
//! run's evaluations swing or its critic loss grows, the suspects are (MBPO paper §4-5):
//!
//! * the critic over-estimating: Q(s, a) above the soft return the policy really gets
//!   ([`ValueCheck`], from fresh episodes of the current stochastic policy);
//! * the model wrong where the current policy goes: its one-step error on those episodes far
//!   above the holdout error it was early-stopped on ([`ModelCheck`]);
//! * imagined data unlike the real: next states outside the box of every real state seen,
//!   another termination rate, other value targets ([`DataCheck`] of D_model next to D_env);
//! * the rollouts' termination rule disagreeing with the environment's on real transitions.
//!
//! Each is one number; `results/diagnose-<run>.json` keeps them per checkpoint, so a curve's
//! swing can be put next to what changed. Nothing is written to the run, and the run's random
//! streams are not touched (the episodes draw from their own `diagnose` stream).

use mbpo_core::rng::stream;
use mbpo_core::{Batch, ReplayBuffer, Rng, StateBox};
use mbpo_sac::{ActionScale, Sac};
use mbpo_train::config::ExperimentConfig;
use mbpo_train::error::TrainError;
use mbpo_train::Mbpo;
use serde::Serialize;
use std::path::Path;

/// A state's soft return is known when its episode terminated, or when enough steps followed
/// it before the time limit that the missing tail weighs γ^n ≤ 1 % of a value: n =
/// ⌈ln 0.01 / ln γ⌉ (459 steps for γ = 0.99).
pub fn known_tail(gamma: f64) -> usize {
    if gamma <= 0.0 {
        return 1;
    }
    (0.01f64.ln() / gamma.ln()).ceil().max(1.0) as usize
}

/// Horizons of the open-loop model error ([`ModelCheck::open_loop_obs_mse`]): 1..=this.
pub const OPEN_LOOP_HORIZON: usize = 5;

/// Rows sampled from each buffer for [`DataCheck`] (whole SAC batches).
pub const BUFFER_ROWS: usize = 10_240;

/// What one checkpoint of a run shows.
#[derive(Debug, Clone, Serialize)]
pub struct Diagnosis {
    /// Env steps of the checkpoint.
    pub at: u64,
    /// SAC temperature α.
    pub alpha: f32,
    /// Rollout length k of the newest imagined batch.
    pub rollout_length: usize,
    /// The critic against real soft returns.
    pub value: ValueCheck,
    /// The model against real transitions of the current policy.
    pub model: ModelCheck,
    /// Samples of the real buffer D_env.
    pub real: DataCheck,
    /// Samples of the model buffer D_model.
    pub imagined: DataCheck,
}

/// min(Q₁, Q₂)(s_t, a_t) against the Monte-Carlo soft return
/// G_t = r_t + γ(1 − d_t)(G_{t+1} − α log π(a_{t+1}|s_{t+1})) of the same episode, over
/// states whose return is known ([`known_tail`]).
#[derive(Debug, Clone, Serialize)]
pub struct ValueCheck {
    /// Episodes of the stochastic policy played.
    pub episodes: usize,
    /// Of them, ended by termination (not the time limit).
    pub terminated: usize,
    /// Mean undiscounted return.
    pub mean_return: f64,
    /// Mean episode length.
    pub mean_length: f64,
    /// States compared.
    pub states: usize,
    /// Mean min(Q₁, Q₂) over them.
    pub q_mean: f64,
    /// Mean soft return over them.
    pub soft_return_mean: f64,
    /// q_mean − soft_return_mean: positive = over-estimation.
    pub bias: f64,
    /// bias / |soft_return_mean|.
    pub relative_bias: f64,
}

/// The model's one-step error (mean over members' elites of the MSE of the mean prediction
/// of [reward, Δobs], the holdout criterion) where the current policy goes.
#[derive(Debug, Clone, Serialize)]
pub struct ModelCheck {
    /// Elite holdout MSE of the newest training (what early stopping saw).
    pub holdout_mse: Option<f64>,
    /// Elite MSE on the fresh episodes' transitions.
    pub on_policy_mse: f64,
    /// on_policy_mse / holdout_mse.
    pub on_policy_over_holdout: Option<f64>,
    /// Open-loop error at horizons h = 1..=[`OPEN_LOOP_HORIZON`]: each elite, from a real
    /// state s_t, fed the episode's real actions a_t..a_{t+h-1} and its own mean predictions,
    /// against the real s_{t+h} (MSE over dimensions, mean over start states and elites; start
    /// states with h real steps after them in their episode). What k-step rollouts compound.
    pub open_loop_obs_mse: Vec<f64>,
    /// Real transitions whose `terminated` the rollouts' termination rule gets wrong.
    pub termination_disagreements: usize,
    /// Real transitions checked.
    pub transitions: usize,
}

/// One buffer's sampled rows, seen by the critic.
#[derive(Debug, Clone, Serialize)]
pub struct DataCheck {
    /// Rows sampled (0: the buffer is empty and the rest is 0).
    pub rows: usize,
    /// Mean reward.
    pub reward_mean: f64,
    /// Fraction of rows with a terminal next state.
    pub terminal_rate: f64,
    /// Fraction of rows whose next state leaves, in some dimension, the [min, max] box of
    /// every state and next state in D_env ([`StateBox`]).
    pub outside_real_box: f64,
    /// Per observation dimension, the fraction of rows whose next state leaves the box in that
    /// dimension: which coordinates the model invents (a joint angle at its limit, where any
    /// sample noise crosses, or a velocity).
    pub outside_real_box_by_dim: Vec<f64>,
    /// Mean min(Q₁, Q₂)(s, a).
    pub q_mean: f64,
    /// Mean soft TD target y = r + γ(1 − d)(min Q̄(s', a') − α log π(a'|s')).
    pub td_target_mean: f64,
    /// Root mean square of min(Q₁, Q₂)(s, a) − y.
    pub td_error_rms: f64,
}

impl DataCheck {
    /// The `n` dimensions most often outside the real box, as `obs[j] share`, most first
    /// (none outside: "-").
    pub fn most_outside_dims(&self, n: usize) -> String {
        let mut dims: Vec<(usize, f64)> = self
            .outside_real_box_by_dim
            .iter()
            .copied()
            .enumerate()
            .filter(|&(_, share)| share > 0.0)
            .collect();
        dims.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        if dims.is_empty() {
            return "-".into();
        }
        dims.iter()
            .take(n)
            .map(|(j, share)| format!("obs[{j}] {share:.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

impl Diagnosis {
    /// One line for a terminal: the figures to compare across checkpoints.
    pub fn summary_line(&self) -> String {
        let (v, m, i, r) = (&self.value, &self.model, &self.imagined, &self.real);
        let open_loop: Vec<String> = m
            .open_loop_obs_mse
            .iter()
            .map(|e| format!("{e:.3}"))
            .collect();
        format!(
            "at {:>6}: return {:7.1} ({:5.0} steps) | Q {:7.1} vs soft return {:7.1} (bias {:+.0} %) \
             | model MSE on-policy {:.4} vs holdout {}, open loop h=1..{} {} | imagined: terminal \
             {:.3} (real {:.3}), outside real box {:.4} (most: {}), Q {:.1} (real {:.1}), TD \
             error {:.2} (real {:.2}) | k {} alpha {:.3}",
            self.at,
            v.mean_return,
            v.mean_length,
            v.q_mean,
            v.soft_return_mean,
            100.0 * v.relative_bias,
            m.on_policy_mse,
            m.holdout_mse.map_or("-".into(), |h| format!("{h:.4}")),
            open_loop.len(),
            open_loop.join(" "),
            i.terminal_rate,
            r.terminal_rate,
            i.outside_real_box,
            i.most_outside_dims(3),
            i.q_mean,
            r.q_mean,
            i.td_error_rms,
            r.td_error_rms,
            self.rollout_length,
            self.alpha
        )
    }
}

/// Restore `run` (config `cfg`) at its complete checkpoint after `at` env steps and diagnose
/// it with `episodes` fresh episodes of its stochastic policy.
pub fn diagnose_at(
    cfg: &ExperimentConfig,
    run: &Path,
    at: u64,
    episodes: usize,
) -> Result<Diagnosis, TrainError> {
    let (mut mbpo, book) = Mbpo::from_kept_checkpoint(cfg, run, at)?;
    let holdout_mse = book.models.values().next_back().copied();
    let mut rng = stream(cfg.seed, "diagnose", at);
    let played = play_episodes(cfg, mbpo.sac(), episodes, &mut rng)?;
    let alpha = mbpo.sac().alpha();
    let value = value_check(mbpo.sac(), &played, alpha, cfg.sac.gamma as f64);
    let model = model_check(&mut mbpo, &played, holdout_mse)?;
    let learner = mbpo.learner_mut();
    let rollout_length = learner.rollout_length;
    let (sac, d_env, d_model) = learner.sac_and_buffers();
    let box_ = StateBox::of(d_env);
    let real = data_check(sac, d_env, &box_, alpha, &mut rng);
    let imagined = data_check(sac, d_model, &box_, alpha, &mut rng);
    Ok(Diagnosis {
        at,
        alpha,
        rollout_length,
        value,
        model,
        real,
        imagined,
    })
}

/// Fresh episodes: their transitions (policy-space actions, as D_env keeps them), and per
/// step the log-probability of the action and where each episode ends.
struct Played {
    transitions: Batch,
    log_prob: Vec<f32>,
    /// (first row, rows, terminated) per episode.
    episodes: Vec<(usize, usize, bool)>,
    returns: Vec<f64>,
}

fn play_episodes(
    cfg: &ExperimentConfig,
    sac: &Sac,
    episodes: usize,
    rng: &mut Rng,
) -> Result<Played, TrainError> {
    let mut env = cfg.make_env()?;
    let (o, a) = (env.obs_dim(), env.act_dim());
    let scale = ActionScale::new(&env.action_space().low, &env.action_space().high);
    let mut cache = sac.actor.cache(1);
    let (mut obs, mut next) = (vec![0.0f32; o], vec![0.0f32; o]);
    let mut env_action = vec![0.0f32; a];
    let mut out = Played {
        transitions: Batch::new(o, a, 0),
        log_prob: Vec::new(),
        episodes: Vec::new(),
        returns: Vec::new(),
    };
    for _ in 0..episodes {
        let first = out.log_prob.len();
        let mut ret = 0.0;
        env.reset(rng, &mut obs)?;
        let terminated = loop {
            sac.actor
                .sample(&sac.actor_params, &obs, 1, &mut cache, Some(rng));
            let action = &cache.action[..a];
            scale.to_env(action, &mut env_action);
            let step = env.step(&env_action, &mut next)?;
            ret += step.reward;
            let t = &mut out.transitions;
            t.obs.extend_from_slice(&obs);
            t.act.extend_from_slice(action);
            t.reward.push(step.reward as f32);
            t.next_obs.extend_from_slice(&next);
            t.terminated.push(if step.terminated { 1.0 } else { 0.0 });
            t.len += 1;
            out.log_prob.push(cache.log_prob[0]);
            if step.terminated || step.truncated {
                break step.terminated;
            }
            std::mem::swap(&mut obs, &mut next);
        };
        out.episodes
            .push((first, out.log_prob.len() - first, terminated));
        out.returns.push(ret);
    }
    Ok(out)
}

/// min(Q₁, Q₂) of the critic `sac` at the `n` rows `obs`, `act`.
fn q_min(sac: &Sac, obs: &[f32], act: &[f32], n: usize) -> Vec<f32> {
    let mut cache = sac.critic.cache(n.max(1));
    sac.critic
        .forward(&sac.critic_params, obs, act, n, &mut cache);
    let (q1, q2) = (sac.critic.q(&cache, 0), sac.critic.q(&cache, 1));
    (0..n).map(|r| q1[r].min(q2[r])).collect()
}

/// Each step's Monte-Carlo soft return G_t = r_t + γ(1 − d_t)(G_{t+1} − α log π(a_{t+1}|s_{t+1}))
/// where it is known ([`known_tail`]); `None` for the last steps of a truncated episode,
/// whose tail is unknown.
fn soft_returns(played: &Played, alpha: f32, gamma: f64) -> Vec<Option<f64>> {
    let tail = known_tail(gamma);
    let mut out = vec![None; played.log_prob.len()];
    for &(first, len, terminated) in &played.episodes {
        let mut g_next = 0.0;
        for i in (0..len).rev() {
            let row = first + i;
            let bootstrap = match i + 1 < len {
                true => gamma * (g_next - alpha as f64 * played.log_prob[row + 1] as f64),
                false => 0.0,
            };
            let g = played.transitions.reward[row] as f64 + bootstrap;
            if terminated || len - i >= tail {
                out[row] = Some(g);
            }
            g_next = g;
        }
    }
    out
}

fn value_check(sac: &Sac, played: &Played, alpha: f32, gamma: f64) -> ValueCheck {
    let t = &played.transitions;
    let q = q_min(sac, &t.obs, &t.act, t.len);
    let (mut q_sum, mut g_sum, mut states) = (0.0, 0.0, 0usize);
    for (q, g) in q.iter().zip(soft_returns(played, alpha, gamma)) {
        if let Some(g) = g {
            q_sum += *q as f64;
            g_sum += g;
            states += 1;
        }
    }
    let per = |x: f64| if states > 0 { x / states as f64 } else { 0.0 };
    let (q_mean, soft_return_mean) = (per(q_sum), per(g_sum));
    let episodes = played.episodes.len();
    let per_episode = |x: f64| x / episodes.max(1) as f64;
    ValueCheck {
        episodes,
        terminated: played.episodes.iter().filter(|e| e.2).count(),
        mean_return: per_episode(played.returns.iter().sum()),
        mean_length: per_episode(played.episodes.iter().map(|e| e.1 as f64).sum()),
        states,
        q_mean,
        soft_return_mean,
        bias: q_mean - soft_return_mean,
        relative_bias: (q_mean - soft_return_mean) / soft_return_mean.abs().max(1e-9),
    }
}

fn model_check(
    mbpo: &mut Mbpo,
    played: &Played,
    holdout_mse: Option<f64>,
) -> Result<ModelCheck, TrainError> {
    let transitions = &played.transitions;
    let rollout = mbpo.rollout_mut();
    let model_err = |e: mbpo_model::PredictError| TrainError::Config(e.to_string());
    let mse = rollout
        .model_mut()
        .evaluate_mse(transitions)
        .map_err(model_err)?;
    let elites = rollout.model_mut().elites().to_vec();
    let on_policy_mse =
        elites.iter().map(|&e| mse[e] as f64).sum::<f64>() / elites.len().max(1) as f64;
    let n = transitions.len;
    let mut done = vec![false; n];
    rollout
        .done_batch(
            &transitions.obs,
            &transitions.act,
            &transitions.next_obs,
            n,
            &mut done,
        )
        .map_err(|e| TrainError::Config(e.to_string()))?;
    let termination_disagreements = (0..n)
        .filter(|&r| done[r] != (transitions.terminated[r] > 0.5))
        .count();
    Ok(ModelCheck {
        holdout_mse,
        on_policy_mse,
        on_policy_over_holdout: holdout_mse.map(|h| on_policy_mse / h),
        open_loop_obs_mse: open_loop_errors(mbpo, played, OPEN_LOOP_HORIZON)?,
        termination_disagreements,
        transitions: n,
    })
}

/// Start rows t whose episode has at least `horizon` real steps from t on: (row, episode
/// end), in row order.
fn open_loop_starts(played: &Played, horizon: usize) -> Vec<usize> {
    played
        .episodes
        .iter()
        .flat_map(|&(first, len, _)| first..(first + len + 1).saturating_sub(horizon))
        .collect()
}

/// [`ModelCheck::open_loop_obs_mse`] of the rollout model on the played episodes.
fn open_loop_errors(
    mbpo: &mut Mbpo,
    played: &Played,
    horizon: usize,
) -> Result<Vec<f64>, TrainError> {
    let t = &played.transitions;
    let (o, a) = (t.obs_dim, t.act_dim);
    let starts = open_loop_starts(played, horizon);
    let n = starts.len();
    let model = mbpo.rollout_mut().model_mut();
    let elites = model.elites().to_vec();
    let mut sums = vec![0.0f64; horizon];
    if n == 0 || elites.is_empty() {
        return Ok(sums);
    }
    let d = 1 + o;
    let (mut mean, mut logvar) = (vec![0.0f32; n * d], vec![0.0f32; n * d]);
    let (mut obs, mut act) = (vec![0.0f32; n * o], vec![0.0f32; n * a]);
    for &e in &elites {
        let members = vec![e; n];
        for (i, &row) in starts.iter().enumerate() {
            obs[i * o..(i + 1) * o].copy_from_slice(&t.obs[row * o..(row + 1) * o]);
        }
        for (h, sum) in sums.iter_mut().enumerate() {
            for (i, &row) in starts.iter().enumerate() {
                let r = row + h;
                act[i * a..(i + 1) * a].copy_from_slice(&t.act[r * a..(r + 1) * a]);
            }
            model
                .predict_gaussian(&obs, &act, n, &members, &mut mean, &mut logvar)
                .map_err(|e| TrainError::Config(e.to_string()))?;
            for (i, &row) in starts.iter().enumerate() {
                let r = row + h;
                let predicted = &mean[i * d + 1..(i + 1) * d];
                let real = &t.next_obs[r * o..(r + 1) * o];
                let se: f64 = predicted
                    .iter()
                    .zip(real)
                    .map(|(&p, &y)| ((p - y) as f64).powi(2))
                    .sum();
                *sum += se / o as f64;
                obs[i * o..(i + 1) * o].copy_from_slice(predicted);
            }
        }
    }
    let count = (n * elites.len()) as f64;
    Ok(sums.into_iter().map(|s| s / count).collect())
}

fn data_check(
    sac: &mut Sac,
    buffer: &ReplayBuffer,
    box_: &StateBox,
    alpha: f32,
    rng: &mut Rng,
) -> DataCheck {
    let (o, a, b) = (buffer.obs_dim(), buffer.act_dim(), sac.config.batch_size);
    let mut batch = Batch::new(o, a, b);
    let (mut reward, mut terminal, mut outside) = (0.0, 0.0, 0usize);
    let mut outside_by_dim = vec![0usize; o];
    let (mut q_sum, mut y_sum, mut err2) = (0.0, 0.0, 0.0);
    let batches = if buffer.is_empty() {
        0
    } else {
        BUFFER_ROWS / b
    };
    for _ in 0..batches {
        buffer.sample_into(rng, &mut batch);
        reward += batch.reward.iter().map(|&r| r as f64).sum::<f64>();
        terminal += batch.terminated.iter().map(|&d| d as f64).sum::<f64>();
        outside += batch
            .next_obs
            .chunks_exact(o)
            .filter(|s| box_.count_outside(s, &mut outside_by_dim))
            .count();
        let q = q_min(sac, &batch.obs, &batch.act, b);
        let y = sac.td_targets(&batch, alpha, rng);
        for (&q, &y) in q.iter().zip(y) {
            q_sum += q as f64;
            y_sum += y as f64;
            err2 += ((q - y) as f64).powi(2);
        }
    }
    let rows = batches * b;
    let per = |x: f64| if rows > 0 { x / rows as f64 } else { 0.0 };
    DataCheck {
        rows,
        reward_mean: per(reward),
        terminal_rate: per(terminal),
        outside_real_box: per(outside as f64),
        outside_real_box_by_dim: outside_by_dim.iter().map(|&c| per(c as f64)).collect(),
        q_mean: per(q_sum),
        td_target_mean: per(y_sum),
        td_error_rms: per(err2).sqrt(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two episodes by hand: one terminated after 3 steps, one truncated after 3 steps.
    fn played(log_prob: [f32; 6]) -> Played {
        let mut transitions = Batch::new(1, 1, 6);
        transitions.reward = vec![1.0, 2.0, 3.0, 10.0, 20.0, 30.0];
        Played {
            transitions,
            log_prob: log_prob.to_vec(),
            episodes: vec![(0, 3, true), (3, 3, false)],
            returns: vec![6.0, 60.0],
        }
    }

    #[test]
    fn soft_returns_bootstrap_with_the_next_actions_entropy_and_stop_at_termination() {
        let p = played([-1.0, -2.0, -3.0, -4.0, -5.0, -6.0]);
        // γ = 0.5: the tail of a truncated episode is known after ⌈ln 0.01 / ln 0.5⌉ = 7
        // steps, so only the terminated episode counts.
        // (α = 0.25 and γ = 0.5 keep the arithmetic exact.)
        let g = soft_returns(&p, 0.25, 0.5);
        let g2 = 3.0;
        let g1 = 2.0 + 0.5 * (g2 + 0.25 * 3.0);
        let g0 = 1.0 + 0.5 * (g1 + 0.25 * 2.0);
        assert_eq!(g[..3], [Some(g0), Some(g1), Some(g2)]);
        assert_eq!(g[3..], [None, None, None]);
        // γ = 0.01: one step of tail is enough (⌈ln 0.01 / ln 0.01⌉ = 1), so every step of the
        // truncated episode counts, its last with an unknown (zero) tail.
        let g = soft_returns(&p, 0.0, 0.01);
        assert_eq!(g[5], Some(30.0));
        assert_eq!(g[4], Some(20.0 + 0.01 * 30.0));
    }

    #[test]
    fn open_loop_starts_have_the_horizon_inside_their_episode() {
        let p = played([0.0; 6]);
        // Episodes of 3 rows at 0..3 and 3..6.
        assert_eq!(open_loop_starts(&p, 1), [0, 1, 2, 3, 4, 5]);
        assert_eq!(open_loop_starts(&p, 3), [0, 3]);
        assert!(open_loop_starts(&p, 4).is_empty());
    }

    #[test]
    fn the_known_tail_is_where_the_rest_weighs_one_percent() {
        assert_eq!(known_tail(0.99), 459);
        assert!(0.99f64.powi(459) <= 0.01 && 0.99f64.powi(458) > 0.01);
        assert_eq!(known_tail(0.5), 7);
    }

    #[test]
    fn the_dimensions_most_outside_are_named_most_first() {
        let check = |by_dim: Vec<f64>| DataCheck {
            rows: 10,
            reward_mean: 0.0,
            terminal_rate: 0.0,
            outside_real_box: 0.5,
            outside_real_box_by_dim: by_dim,
            q_mean: 0.0,
            td_target_mean: 0.0,
            td_error_rms: 0.0,
        };
        assert_eq!(
            check(vec![0.0, 0.3, 0.1, 0.3, 0.05]).most_outside_dims(3),
            "obs[1] 0.300, obs[3] 0.300, obs[2] 0.100"
        );
        assert_eq!(check(vec![0.0, 0.0]).most_outside_dims(3), "-");
    }
}
