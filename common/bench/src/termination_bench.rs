//! How well the learned termination rule ([`mbpo_model::TerminationClassifier`]) recovers a
//! task's exact rule: train it on real transitions of uniformly random actions, then compare its
//! verdicts with the environment's `terminated` flags on transitions of other episodes (another
//! seed). `mbpo bench termination --env Hopper-v5` prints this report.

use std::time::Instant;

use mbpo_core::rng::{stream, uniform_range_f32};
use mbpo_core::Batch;
use mbpo_envs::Env;
use mbpo_model::termination::Confusion;
use mbpo_model::TerminationClassifier;
use serde::Serialize;

use mbpo_train::error::TrainError;

/// The report of [`termination_benchmark`].
#[derive(Debug, Clone, Serialize)]
pub struct TerminationBenchReport {
    /// Environment id.
    pub env: String,
    /// Real transitions trained on, and the terminal ones among them.
    pub train_rows: usize,
    /// Terminal transitions among the training rows.
    pub train_positives: usize,
    /// Transitions of other episodes it is tested on.
    pub test_rows: usize,
    /// Terminal transitions among them.
    pub test_positives: usize,
    /// Of the test transitions predicted terminal, the share that are.
    pub precision: f64,
    /// Of the terminal test transitions, the share predicted terminal.
    pub recall: f64,
    /// Share of test transitions where the prediction equals the env's flag.
    pub accuracy: f64,
    /// Seconds of the training call.
    pub train_seconds: f64,
}

/// Train on `train_steps` random-action transitions of `env` (seed stream `seed`), test on
/// `test_steps` of another stream.
pub fn termination_benchmark(
    mut env: Box<dyn Env>,
    train_steps: usize,
    test_steps: usize,
    seed: u64,
) -> Result<TerminationBenchReport, TrainError> {
    let train = collect(env.as_mut(), train_steps, seed, "bench.termination.train")?;
    let test = collect(env.as_mut(), test_steps, seed, "bench.termination.test")?;
    let mut rule = TerminationClassifier::new(
        env.obs_dim(),
        env.act_dim(),
        &mut stream(seed, "bench.termination.init", 0),
    );
    let started = Instant::now();
    rule.train(&train, &mut stream(seed, "bench.termination.fit", 0));
    let train_seconds = started.elapsed().as_secs_f64();
    let mut predicted = vec![false; test.len];
    rule.predict(
        &test.obs,
        &test.act,
        &test.next_obs,
        test.len,
        &mut predicted,
    );
    let mut counts = Confusion::default();
    for (&p, &t) in predicted.iter().zip(&test.terminated) {
        counts.add(p, t > 0.5);
    }
    let positives = |b: &Batch| b.terminated.iter().filter(|&&t| t > 0.5).count();
    Ok(TerminationBenchReport {
        env: env.id().to_string(),
        train_rows: train.len,
        train_positives: positives(&train),
        test_rows: test.len,
        test_positives: positives(&test),
        precision: counts.precision(),
        recall: counts.recall(),
        accuracy: counts.accuracy(),
        train_seconds,
    })
}

/// `steps` transitions of uniformly random actions in the env's box, resetting at episode end.
fn collect(env: &mut dyn Env, steps: usize, seed: u64, role: &str) -> Result<Batch, TrainError> {
    let (o, a) = (env.obs_dim(), env.act_dim());
    let mut rng = stream(seed, role, 0);
    let mut b = Batch::new(o, a, steps);
    let mut obs = vec![0.0f32; o];
    let mut action = vec![0.0f32; a];
    env.reset(&mut rng, &mut obs)?;
    let space = env.action_space().clone();
    for i in 0..steps {
        for (d, v) in action.iter_mut().enumerate() {
            *v = uniform_range_f32(&mut rng, space.low[d], space.high[d]);
        }
        b.obs[i * o..(i + 1) * o].copy_from_slice(&obs);
        b.act[i * a..(i + 1) * a].copy_from_slice(&action);
        let step = env.step(&action, &mut obs)?;
        b.next_obs[i * o..(i + 1) * o].copy_from_slice(&obs);
        b.reward[i] = step.reward as f32;
        b.terminated[i] = f32::from(step.terminated);
        if step.terminated || step.truncated {
            env.reset(&mut rng, &mut obs)?;
        }
    }
    Ok(b)
}
