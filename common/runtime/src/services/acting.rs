//! The step loop every actor in the real environment shares: SAC's actor (`actor.rs`, acting
//! with the learner's policy) and MPC's planning actor (`planning.rs`, planning on the model
//! trainer's ensemble).
//!
//! Per local step t (global step g): serve a stop or a checkpoint barrier, wait until the role
//! holds weights it may act with at g (lockstep: exactly the sequential run's version), take
//! the env step straight into a loaned shared-memory sample, report a finished episode before
//! its transition, send the transition and report progress. After the last step it reports
//! `Done` and serves barriers until the stop. What differs between the two actors (which
//! weights, which version g needs, the checkpoint, what `Done` counts) is an [`ActingRole`].

use std::time::{Duration, Instant};

use serde::de::DeserializeOwned;
use serde::Serialize;

use mbpo_train::actor::{Behaviour, EnvActor};
use mbpo_train::TrainError;
use mbpo_wire::*;

use crate::barrier;
use crate::error::ensure_protocol;
use crate::{Result, *};

/// What one kind of actor adds to the shared step loop ([`act`]).
pub trait ActingRole: Sized {
    /// The process role (its node, log and checkpoint file).
    const ROLE: RoleKind;
    /// The weights it acts with.
    const WEIGHTS: WeightsKind;
    /// Its checkpoint file's contents.
    type Checkpoint: Serialize + DeserializeOwned;

    /// Its state after `steps` local steps.
    fn checkpoint(&self, steps: u64) -> Self::Checkpoint;
    /// Continue from [`ActingRole::checkpoint`]; returns the local steps done.
    fn restore(&mut self, state: Self::Checkpoint) -> Result<u64>;
    /// Take the newest snapshot `weights` holds, if there is one.
    fn take_newest<S: Transport>(&mut self, weights: &WeightsSubscriber<S>, d: &Dims)
        -> Result<()>;
    /// The version global step `g` acts with in the sequential run (lockstep requires it).
    fn sequential_version(&self, g: u64) -> u64;
    /// The oldest version it may act with at `g` (pipelined: within the configured lag).
    fn oldest_allowed(&self, g: u64) -> u64;
    /// Whether it holds received weights of at least `version`.
    fn holds(&self, version: u64) -> bool;
    /// The version of the weights it acts with.
    fn version(&self) -> u64;
    /// The environment and its episode counters.
    fn env_actor(&self) -> &EnvActor;
    /// One env step whose transition goes straight into `sink`.
    fn act_into(
        &mut self,
        behaviour: Behaviour,
        sink: &mut dyn mbpo_core::TransitionSink,
    ) -> std::result::Result<(), TrainError>;
    /// After a step: whether to report progress now rather than within 500 ms.
    fn after_step(&mut self, _behaviour: Behaviour) -> bool {
        false
    }
    /// `Done.work` and `Done.median_step_seconds` when its steps are done, and the words the
    /// log line adds.
    fn finish(&mut self) -> Finish;
}

/// What an actor adds to its `Done` report and log line.
pub struct Finish {
    /// `Done.work`.
    pub work: u64,
    /// `Done.median_step_seconds`.
    pub median_step_seconds: f32,
    /// Words for the log line after "done: N steps, ".
    pub log: String,
}

/// The versions a transition or progress record carries: the acting weights' in their field.
fn stamp<R: ActingRole>(role: &R) -> (u64, u64) {
    match R::WEIGHTS {
        WeightsKind::Policy => (role.version(), 0),
        WeightsKind::Model => (0, role.version()),
    }
}

/// The name of what `R` acts with, for messages.
fn weights_name<R: ActingRole>() -> &'static str {
    match R::WEIGHTS {
        WeightsKind::Policy => "policy",
        WeightsKind::Model => "model",
    }
}

/// Run the actor of `args` in its own process: `make` builds its role once the ports wait.
pub fn act<S: Transport, R: ActingRole>(
    args: &ServiceArgs,
    make: impl FnOnce(&Process<S>) -> Result<R>,
) -> Result<()> {
    let s = Process::<S>::open(args, R::ROLE)?;
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::<S>::create(&s.node)?;
    let (hash, len) = match R::WEIGHTS {
        WeightsKind::Policy => (d.policy_hash, d.policy_len),
        WeightsKind::Model => (d.model.layout_hash, d.model.len()),
    };
    let weights = WeightsSubscriber::create(&s.node, R::WEIGHTS, hash, len)?;
    let real = TransitionPublisher::create(&s.node, Channel::Real, d.rows(), 1)?;
    stats_pub.wait_for_subscribers(1, Duration::from_secs(60))?;
    // Every consumer of real data (model trainer, and rollout generator and learner in an MBPO
    // run; or this host's gateway): nothing sent afterwards can be lost.
    real.wait_for_subscribers(s.real_consumers(), Duration::from_secs(120))?;
    let mut waiter = Waiter::new()?;
    waiter.attach(&control.sub).attach(&weights);

    let mut role = make(&s)?;
    let mut lag = SlackTracker::default();
    let mut last_progress = Instant::now();
    let steps = actor_steps(cfg.steps, args.actors, args.index);
    let file = barrier::FileTarget::new(
        &args.run_dir,
        barrier::actor_file(args.index),
        R::ROLE.checkpoint_kind(),
    );
    let mut first = 1;
    if let Some(dir) = &args.resume_from {
        first = role.restore(file.read(dir)?)? + 1;
    }
    // At the cut: write the state after `done` local steps, wait for the resume.
    let write_at = |role: &R, done: u64, cut| {
        let state = role.checkpoint(done);
        barrier::write_and_await_resume(&waiter, &control, &stats_pub, &file, cut, &state)
    };
    // At a barrier: report the steps done, then as above.
    let at_barrier = |role: &R, done: u64| -> Result<bool> {
        match barrier::report_paused(&waiter, &control, &stats_pub, done)? {
            Some(cut) => write_at(role, done, cut),
            None => Ok(false),
        }
    };
    let started = Instant::now();
    let mut ipc = Duration::ZERO;
    for t in first..=steps {
        let g = global_step(t, args.actors, args.index);
        let behaviour = loop {
            control.poll()?;
            if control.stopped() {
                tracing::info!("stopped before step {g}");
                return Ok(());
            }
            if control.pause_requested() {
                if !at_barrier(&role, t - 1)? {
                    tracing::info!("stopped after the checkpoint, before step {g}");
                    return Ok(());
                }
                continue;
            }
            if s.schedule.is_warm_up(g) {
                break Behaviour::Uniform;
            }
            let need = role.oldest_allowed(g);
            let ok = wait_for(
                &waiter,
                &control,
                &|| format!("{} version {need}", weights_name::<R>()),
                || {
                    role.take_newest(&weights, &d)?;
                    Ok(role.holds(need) || control.pause_requested())
                },
            )?;
            if !ok {
                tracing::info!("stopped before step {g}");
                return Ok(());
            }
            if control.pause_requested() {
                continue;
            }
            let exact = role.sequential_version(g);
            if s.mode == Mode::Lockstep {
                ensure_protocol!(
                    role.version() == exact,
                    "lockstep {} at step {g} got {} version {} (want {exact})",
                    R::ROLE.name(args.index),
                    weights_name::<R>(),
                    role.version()
                );
            }
            lag.see(exact as f64 - role.version() as f64);
            break Behaviour::Policy;
        };
        let episodes = role.env_actor().episodes;
        // The env step writes its transition straight into the sample it is sent in.
        let t0 = Instant::now();
        let mut loan = real.loan_rows(1)?;
        ipc += t0.elapsed();
        if let Err(e) = role.act_into(behaviour, &mut loan) {
            drop(loan);
            let (w, c, p) = (&waiter, &control, &stats_pub);
            return barrier::after_env_failure(w, c, p, e, g, t - 1, |cut| {
                write_at(&role, t - 1, cut)
            });
        }
        let report_now = role.after_step(behaviour);
        let a = role.env_actor();
        if a.episodes > episodes {
            // Before the transition: the supervisor may rely on having every episode ≤ t.
            stats_pub.report(EpisodeEnd {
                env_steps: g,
                episode_return: a.last_return.unwrap_or(f64::NAN),
                version: role.version(),
            })?;
        }
        let (policy_version, model_version) = stamp(&role);
        let meta = TransitionMeta {
            policy_version,
            model_version,
            env_steps: g,
        };
        let t0 = Instant::now();
        loan.send(meta)?;
        ipc += t0.elapsed();
        if report_now || last_progress.elapsed() >= Duration::from_millis(500) {
            last_progress = Instant::now();
            stats_pub.report(Progress {
                env_steps: g,
                policy_version,
                model_version,
                ..Default::default()
            })?;
        }
    }
    let finish = role.finish();
    let (lo, hi, mean) = lag.get();
    let a = role.env_actor();
    stats_pub.report(Done {
        real: steps,
        work: finish.work,
        episodes_cut: a.episodes_cut,
        episodes_lost: a.episodes_lost,
        median_step_seconds: finish.median_step_seconds,
        slack_min: lo,
        slack_max: hi,
        slack_mean: mean,
        ipc_seconds: ipc.as_secs_f32(),
        wall_seconds: started.elapsed().as_secs_f32(),
        ..Default::default()
    })?;
    tracing::info!(
        "done: {steps} steps, {}{} lag {lo}..{hi} (mean {mean:.2})",
        finish.log,
        weights_name::<R>()
    );
    barrier::idle_until_stop(&waiter, &control, &stats_pub, Some(steps), |cut| {
        write_at(&role, steps, cut)
    })
}
