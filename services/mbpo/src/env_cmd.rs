//! `mbpo env list` and `mbpo env replay`.

use crate::cli::{EnvCommand, ReplayArgs};
use anyhow::{bail, Context};
use mbpo_envs::{make, ENV_IDS};
use serde_json::json;
use std::io::Write;

pub fn run(cmd: EnvCommand) -> anyhow::Result<()> {
    match cmd {
        EnvCommand::List => list(),
        EnvCommand::Replay(args) => replay(&args),
    }
}

fn list() -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    for id in ENV_IDS {
        let env = make(id)?;
        writeln!(
            out,
            "{}",
            json!({
                "id": id,
                "obs_dim": env.obs_dim(),
                "act_dim": env.act_dim(),
                "action_low": env.action_space().low,
                "action_high": env.action_space().high,
                "state": env.restorable().map(|r| r.state_layout()),
                "max_episode_steps": env.max_episode_steps(),
            })
        )?;
    }
    Ok(())
}

/// Parse a comma-separated list of numbers, naming the flag and the bad item on error.
fn parse_list<T: std::str::FromStr>(flag: &str, text: &str) -> anyhow::Result<Vec<T>>
where
    T::Err: std::error::Error + Send + Sync + 'static,
{
    text.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .enumerate()
        .map(|(i, s)| {
            s.parse::<T>()
                .with_context(|| format!("--{flag}: item {} is '{s}', expected a number", i + 1))
        })
        .collect()
}

/// One replayed step, fields in the documented order. Observations are printed as Python's
/// `obs.tolist()` gives them, so the output diffs cleanly with Gymnasium: the f64 value of each
/// f32 for float32 environments, the float64 observation itself for the MuJoCo tasks.
#[derive(serde::Serialize)]
struct StepLine<'a> {
    t: usize,
    obs: Obs<'a>,
    reward: f64,
    terminated: bool,
    truncated: bool,
}

#[derive(serde::Serialize)]
#[serde(untagged)]
enum Obs<'a> {
    #[serde(serialize_with = "f32s_as_f64")]
    F32(&'a [f32]),
    F64(&'a [f64]),
}

fn f32s_as_f64<S: serde::Serializer>(v: &&[f32], s: S) -> Result<S::Ok, S::Error> {
    s.collect_seq(v.iter().map(|&x| x as f64))
}

fn replay(args: &ReplayArgs) -> anyhow::Result<()> {
    let mut env = make(&args.env)?;
    let state: Vec<f64> = parse_list("state", &args.state)?;
    let actions: Vec<f32> = parse_list("actions", &args.actions)?;
    let act_dim = env.act_dim();
    if actions.is_empty() || !actions.len().is_multiple_of(act_dim) {
        bail!(
            "--actions: {} values given, but {} takes {act_dim} value(s) per step, so the count must be a positive multiple of {act_dim}",
            actions.len(),
            args.env
        );
    }
    let mut obs = vec![0.0f32; env.obs_dim()];
    let Some(restorable) = env.restorable_mut() else {
        bail!(
            "{} cannot start from a given state (it has no saved-state capability), so it cannot be replayed",
            args.env
        );
    };
    restorable
        .reset_to(&state, &mut obs)
        .with_context(|| format!("--state '{}'", args.state))?;
    let mut out = std::io::stdout().lock();
    let steps = actions.len() / act_dim;
    for (t, action) in actions.chunks_exact(act_dim).enumerate() {
        let step = env.step(action, &mut obs)?;
        let line = StepLine {
            t,
            obs: env.observation_f64().map_or(Obs::F32(&obs), Obs::F64),
            reward: step.reward,
            terminated: step.terminated,
            truncated: step.truncated,
        };
        writeln!(out, "{}", serde_json::to_string(&line)?)?;
        if step.terminated || step.truncated {
            if t + 1 < steps {
                tracing::warn!(
                    "episode ended at step {t}; the remaining {} action(s) were not applied",
                    steps - t - 1
                );
            }
            break;
        }
    }
    Ok(())
}
