//! The extension points, proven from this file alone:
//! - a task the project does not ship (one `Env` impl, one `mbpo_envs::register` call) runs
//!   under the sequential trainer and under the in-process pipeline, and lockstep equals
//!   sequential on it too. The toy does not offer the optional saved-state capability
//!   (`RestorableEnv`), as a Python env or a robot would not: checkpoints still resume, starting
//!   a new episode;
//! - an algorithm the project does not ship (a uniform-random baseline: one function, one
//!   `mbpo_train::algorithm::register` call) is a config's `algo`, runs where `mbpo train`
//!   runs algorithms, and is refused by the pipeline by name, as it names no roles; one that
//!   names its roles (MBPO's, under another name) runs in the in-process pipeline too;
//!   and `mbpo run`'s launcher, called from this program, runs it as processes of the role
//!   binaries, which learn it from the run plan;
//! - a role served by a worker of one's own (one `Worker` impl on the serving loop: a toy
//!   evaluator) over a transport the project does not use (iceoryx2's `ipc_threadsafe`, picked
//!   at the call site), with a checkpoint barrier, and lockstep still equals sequential;
//! - a planner of one's own (one `Planner` impl) drives the MPC controller.

use std::path::Path;
use std::time::Duration;

use clap::Parser as _;
use mbpo_core::rng::{stream, uniform_range_f32, Rng};
use mbpo_core::{BatchPolicy, UniformPolicy};
use mbpo_envs::{register, BoxSpace, Env, EnvError, Step, TaskSpec};
use mbpo_integration_tests::*;
use mbpo_plan::{Mpc, PlanError, Planner, PlanningModel};
use mbpo_runtime::barrier::Cut;
use mbpo_runtime::in_process::{run_in_process, run_in_process_with, InProcessRun};
use mbpo_runtime::services::{service_loop, ServiceLoop};
use mbpo_runtime::serving::{self, serve, AtCut, Cx, Worker};
use mbpo_runtime::{send_ack, ControlInbox, Mode, Process, RoleKind, Slack};
use mbpo_train::algorithm::{self, AlgorithmSpec};
use mbpo_train::run_dir::MetricsRow;
use mbpo_train::{
    train_mbpo, train_mbpo_with, ExperimentConfig, RunDir, RunOptions, Schedule, Summary,
    TrainError,
};
use mbpo_wire::{
    ControlPublisher, Done, EvalResult, ProducerId, Role, Transport, Waiter, WeightsKind,
    WeightsSubscriber,
};

/// A point on a line pushed by the action; reward −x² − 0.1·a²; 50-step episodes.
struct Toy {
    x: f64,
    steps: usize,
    obs_space: BoxSpace,
    act_space: BoxSpace,
}

const TOY_ID: &str = "ToyLine-v0";

impl Env for Toy {
    fn id(&self) -> &'static str {
        TOY_ID
    }
    fn observation_space(&self) -> &BoxSpace {
        &self.obs_space
    }
    fn action_space(&self) -> &BoxSpace {
        &self.act_space
    }
    fn max_episode_steps(&self) -> usize {
        50
    }
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) -> Result<(), EnvError> {
        self.x = uniform_range_f32(rng, -1.0, 1.0) as f64;
        self.steps = 0;
        obs[0] = self.x as f32;
        Ok(())
    }
    fn elapsed_steps(&self) -> usize {
        self.steps
    }
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<Step, EnvError> {
        let a = action[0].clamp(-1.0, 1.0) as f64;
        self.x = (self.x + 0.1 * a).clamp(-2.0, 2.0);
        self.steps += 1;
        obs[0] = self.x as f32;
        Ok(Step {
            reward: -self.x * self.x - 0.1 * a * a,
            terminated: false,
            truncated: self.steps >= 50,
        })
    }
}

fn make_toy() -> Result<Box<dyn Env>, EnvError> {
    Ok(Box::new(Toy {
        x: 0.0,
        steps: 0,
        obs_space: BoxSpace::new(vec![-2.0], vec![2.0]),
        act_space: BoxSpace::new(vec![-1.0], vec![1.0]),
    }))
}

/// Register the toy once per test binary (tests run on threads of one process).
fn register_toy() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        register(TaskSpec {
            id: TOY_ID,
            make: make_toy,
            termination: mbpo_envs::termination::never,
            reward: None,
            target_return: Some(-5.0),
            mujoco: false,
        })
        .unwrap()
    });
}

#[test]
fn a_registered_task_runs_sequentially_and_in_the_pipeline_with_equal_results() {
    register_toy();
    let mut cfg = tiny_config(300);
    cfg.env = TOY_ID.into();
    cfg.eval.every = 100;
    let dir = scratch("extension-toy-env");
    let seq = train_mbpo(&cfg, &dir.join("sequential")).unwrap();
    let run = InProcessRun {
        out: dir.join("lockstep"),
        ipc_root: ipc_root("ext-toy"),
        mode: Mode::Lockstep,
        actors: 1,
        slack: Slack::ZERO,
        timeout: Duration::from_secs(240),
    };
    let s = run_in_process(&cfg, &run).unwrap();
    assert_eq!(s.summary.env, TOY_ID);
    assert_eq!(s.summary.policy_sha256, seq.policy_sha256);
    assert_eq!(
        metrics_without_timing(&run.out),
        metrics_without_timing(&dir.join("sequential"))
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_env_that_cannot_save_its_state_resumes_with_a_new_episode() {
    register_toy();
    assert!(make_toy().unwrap().restorable().is_none());
    let dir = scratch("extension-toy-resume");
    let mut cfg = tiny_config(125);
    cfg.env = TOY_ID.into();
    cfg.eval.every = 100;
    // 125 steps end 25 steps into the third 50-step episode: the checkpoint cannot hold it.
    let first = train_mbpo(&cfg, &dir).unwrap();
    assert_eq!((first.env_steps, first.episodes_cut_by_resume), (125, 0));
    cfg.steps = 300;
    let resume = RunOptions {
        resume: true,
        ..Default::default()
    };
    let resumed = train_mbpo_with(&cfg, &dir, resume).unwrap();
    assert_eq!(resumed.status, "completed");
    assert_eq!(resumed.env_steps, 300);
    assert_eq!(resumed.episodes_cut_by_resume, 1);
    let rows: Vec<String> = metrics_without_timing(&dir)
        .iter()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().to_string())
        .collect();
    // Eval points 100, 200, 300 and the first run's last step.
    assert_eq!(rows, ["100", "125", "200", "300"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The toy algorithm: a uniform-random policy, evaluated at the config's eval points.
fn train_random(
    cfg: &ExperimentConfig,
    out: &Path,
    opts: RunOptions,
) -> Result<Summary, TrainError> {
    if opts.resume {
        return Err(TrainError::Config(
            "the random baseline keeps no checkpoints".into(),
        ));
    }
    let mut run = RunDir::create(out, cfg)?;
    let mut env = mbpo_envs::make(&cfg.env)?;
    let space = env.action_space().clone();
    let mut policy = UniformPolicy {
        low: space.low.clone(),
        high: space.high.clone(),
    };
    let mut rng = stream(cfg.seed, "random.eval", 0);
    let schedule = Schedule::of(cfg);
    let (mut last, mut best) = (f64::NAN, f64::NEG_INFINITY);
    for t in (1..=cfg.steps).filter(|&t| schedule.is_eval_point(t)) {
        // Actions are [-1, 1] inside learners; this one acts in the env's own box.
        let ret = evaluate_in_box(&mut policy, env.as_mut(), cfg.eval.episodes, &mut rng);
        run.write_metrics(&MetricsRow {
            env_steps: t,
            eval_return: ret,
            ..Default::default()
        })?;
        (last, best) = (ret, best.max(ret));
    }
    let summary = Summary {
        algo: cfg.algo.name().into(),
        env: cfg.env.clone(),
        seed: cfg.seed,
        env_steps: cfg.steps,
        sac_updates: 0,
        final_eval_return: last,
        best_eval_return: best,
        target_return: cfg.target_return(),
        env_steps_to_target: run.env_steps_to_target(cfg.target_return())?,
        policy_sha256: String::new(),
        wall_seconds: 0.0,
        median_seconds_per_env_step: None,
        status: "completed".into(),
        episodes_cut_by_resume: 0,
        episodes_lost_to_env_exit: 0,
    };
    run.write_summary(&summary)?;
    Ok(summary)
}

/// Mean return of `episodes` episodes of `policy` acting directly in the env's action box.
fn evaluate_in_box(
    policy: &mut UniformPolicy,
    env: &mut dyn Env,
    episodes: usize,
    rng: &mut Rng,
) -> f64 {
    let (mut obs, mut action) = (vec![0.0f32; env.obs_dim()], vec![0.0f32; env.act_dim()]);
    let mut total = 0.0;
    for _ in 0..episodes {
        env.reset(rng, &mut obs).unwrap();
        loop {
            policy.act_batch(&obs, 1, &mut action, rng);
            let step = env.step(&action, &mut obs).unwrap();
            total += step.reward;
            if step.terminated || step.truncated {
                break;
            }
        }
    }
    total / episodes as f64
}

#[test]
fn a_registered_algorithm_runs_as_a_configs_algo_and_the_pipeline_refuses_it() {
    let unknown = toml::from_str::<ExperimentConfig>("algo = \"random-policy\"").unwrap_err();
    assert!(
        unknown
            .to_string()
            .contains("unknown algorithm 'random-policy'"),
        "{unknown}"
    );
    let algo = algorithm::register(AlgorithmSpec {
        name: "random-policy",
        train: train_random,
        pipeline: None,
    })
    .unwrap();
    let mut cfg: ExperimentConfig =
        toml::from_str("algo = \"random-policy\"\nenv = \"Pendulum-v1\"\nsteps = 400").unwrap();
    assert_eq!(cfg.algo, algo);
    cfg.eval.every = 200;
    cfg.eval.episodes = 2;
    cfg.validate("test").unwrap();
    let dir = scratch("extension-random-algo");
    let s = algorithm::train(&cfg, &dir.join("train"), RunOptions::default()).unwrap();
    assert_eq!((s.algo.as_str(), s.env_steps), ("random-policy", 400));
    // Pendulum under random actions: about -1200 per episode.
    assert!((-1800.0..-800.0).contains(&s.final_eval_return), "{s:?}");
    let rows: Vec<String> = metrics_without_timing(&dir.join("train"))
        .iter()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().to_string())
        .collect();
    assert_eq!(rows, ["200", "400"]);
    let run = InProcessRun {
        out: dir.join("pipeline"),
        ipc_root: ipc_root("ext-algo"),
        mode: Mode::Lockstep,
        actors: 1,
        slack: Slack::ZERO,
        timeout: Duration::from_secs(30),
    };
    let err = run_in_process(&cfg, &run).unwrap_err().to_string();
    // (The test below may have registered one more by now.)
    assert!(err.contains("the pipeline runs mbpo or mpc"), "{err}");
    assert!(
        err.contains("not random-policy (run it with `mbpo train`)"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// One row: a name, a single-process run and the roles it runs as -- MBPO's own, so lockstep
/// must equal the sequential run bit for bit. Registers it, and returns a tiny config of it,
/// a scratch directory and its sequential run's summary (in `<dir>/sequential`).
fn mbpo_under_another_name(name: &'static str) -> (ExperimentConfig, std::path::PathBuf, Summary) {
    let mbpo = algorithm::lookup("mbpo").unwrap();
    let algo = algorithm::register(AlgorithmSpec {
        name,
        train: train_mbpo_with,
        pipeline: mbpo.pipeline,
    })
    .unwrap();
    let mut cfg = tiny_config(300);
    cfg.algo = algo;
    cfg.eval.every = 100;
    let dir = scratch(&format!("extension-{name}"));
    let seq = algorithm::train(&cfg, &dir.join("sequential"), RunOptions::default()).unwrap();
    (cfg, dir, seq)
}

#[test]
fn a_registered_algorithm_on_existing_roles_runs_in_the_pipeline_too() {
    let (cfg, dir, seq) = mbpo_under_another_name("mbpo-again");
    let run = InProcessRun {
        out: dir.join("lockstep"),
        ipc_root: ipc_root("ext-roles"),
        mode: Mode::Lockstep,
        actors: 1,
        slack: Slack::ZERO,
        timeout: Duration::from_secs(240),
    };
    let s = run_in_process(&cfg, &run).unwrap();
    assert_eq!(
        (s.summary.algo.as_str(), seq.algo.as_str()),
        ("mbpo-again", "mbpo-again")
    );
    assert_eq!(s.summary.policy_sha256, seq.policy_sha256);
    assert_eq!(
        metrics_without_timing(&run.out),
        metrics_without_timing(&dir.join("sequential"))
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The launcher of `mbpo run` as a library (`mbpo::supervisor::launch`): this test program
/// registers an algorithm and launches it; its roles are processes of the installed role
/// binaries, which know the algorithm from the run plan alone.
#[test]
fn a_registered_algorithm_runs_under_the_launcher_of_mbpo_run() {
    let (cfg, dir, seq) = mbpo_under_another_name("mbpo-launched");
    let (input, out, root) = (
        write_config(&cfg, &dir),
        dir.join("lockstep"),
        ipc_root("ext-launch"),
    );
    let mut argv = vec!["mbpo", "run", "--mode", "lockstep", "--quiet"];
    argv.extend(run_args(&input, &out, &root, &[]));
    let mbpo::cli::Command::Run(args) = mbpo::cli::Cli::try_parse_from(argv).unwrap().command
    else {
        panic!("not `mbpo run`");
    };
    let bins = bin_dir();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let ended = mbpo::supervisor::launch(&args, bins).map_err(|e| format!("{e:#}"));
        tx.send(ended).unwrap();
    });
    let ended = rx.recv_timeout(Duration::from_secs(300));
    ended.expect("the run ends within 5 minutes").unwrap();
    let s = summary(&out);
    assert_eq!(
        (s["status"].as_str(), s["algo"].as_str()),
        (Some("completed"), Some("mbpo-launched"))
    );
    assert_eq!(
        s["policy_sha256"],
        seq.policy_sha256.as_str(),
        "lockstep != sequential"
    );
    assert_eq!(
        metrics_without_timing(&out),
        metrics_without_timing(&dir.join("sequential"))
    );
    // Each role a process of its own binary: the learner's log names the algorithm.
    let learner = std::fs::read_to_string(out.join("logs/learner.log")).unwrap();
    assert!(learner.contains("mbpo-launched"), "{learner}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A toy evaluator: at each eval point t it waits for policy version t, acknowledges it (the
/// lockstep learner waits for that) and reports t / 1000 as the evaluation's return.
struct CountingEvaluator {
    params: Vec<f32>,
    version: u64,
    evals: u64,
    next: Option<u64>,
}

/// Its ports: the policy, and acknowledgements to the learner.
struct CountingPorts<S: Transport> {
    acks: ControlPublisher<S>,
    policy: WeightsSubscriber<S>,
}

impl<S: Transport> Worker<S> for CountingEvaluator {
    const KIND: RoleKind = RoleKind::Evaluator;
    type Ports = CountingPorts<S>;
    /// Evaluations done, and the cut's step.
    type Checkpoint = (u64, u64);

    fn ports(s: &Process<S>) -> mbpo_runtime::Result<CountingPorts<S>> {
        let policy = WeightsKind::Policy;
        Ok(CountingPorts {
            acks: ControlPublisher::create(&s.node)?,
            policy: WeightsSubscriber::create(
                &s.node,
                policy,
                s.dims.policy_hash,
                s.dims.policy_len,
            )?,
        })
    }
    fn connect(
        s: &Process<S>,
        control: &ControlInbox<S>,
        p: &CountingPorts<S>,
    ) -> mbpo_runtime::Result<()> {
        control.sub.update_connections();
        let n = s
            .pipeline
            .subscribers(mbpo_wire::Channel::Control, s.args.actors);
        p.acks.wait_for_subscribers(n, Duration::from_secs(60))?;
        Ok(())
    }
    fn attach<'a>(p: &'a CountingPorts<S>, waiter: &mut Waiter<'a, S>) {
        waiter.attach(&p.policy);
    }
    fn new(cx: &Cx<'_, S, CountingPorts<S>>) -> mbpo_runtime::Result<Self> {
        Ok(Self {
            params: vec![0.0; cx.s.dims.policy_len],
            version: 0,
            evals: 0,
            next: cx.s.schedule.next_eval_point(0),
        })
    }
    fn restore(
        &mut self,
        (evals, after): (u64, u64),
        cx: &Cx<'_, S, CountingPorts<S>>,
    ) -> mbpo_runtime::Result<()> {
        (self.evals, self.next) = (evals, cx.s.schedule.next_eval_point(after));
        Ok(())
    }
    fn step(&mut self, cx: &Cx<'_, S, CountingPorts<S>>) -> mbpo_runtime::Result<serving::Step> {
        let Some(t) = self.next else {
            return Ok(serving::Step::Finished);
        };
        if let Some(h) = cx.ports.policy.receive_latest_into(&mut self.params)? {
            self.version = mbpo_wire::policy_version_of(h.version);
        }
        if self.version < t {
            return Ok(serving::Step::Waiting);
        }
        send_ack(&cx.ports.acks, ProducerId::new(Role::Learner, 0), t)?;
        cx.stats.report(EvalResult {
            env_steps: t,
            policy_version: self.version,
            model_version: 0,
            mean_return: t as f64 / 1000.0,
            episodes: 1,
        })?;
        self.evals += 1;
        self.next = cx.s.schedule.next_eval_point(t);
        Ok(serving::Step::Worked)
    }
    fn done_so_far(&self) -> u64 {
        self.evals
    }
    fn at_cut(
        &mut self,
        cut: Cut,
        _: &Cx<'_, S, CountingPorts<S>>,
    ) -> mbpo_runtime::Result<AtCut<(u64, u64)>> {
        if self.next.is_some_and(|t| t <= cut.env_steps) {
            return Ok(AtCut::Work);
        }
        Ok(AtCut::Write((self.evals, cut.env_steps)))
    }
    fn finish(&mut self, cx: &Cx<'_, S, CountingPorts<S>>) -> mbpo_runtime::Result<()> {
        cx.stats.report(Done {
            work: self.evals,
            ..Default::default()
        })?;
        Ok(())
    }
    fn waiting_for(&self) -> String {
        format!("policy version {:?}", self.next)
    }
}

/// The `eval_return` column of a run's metrics.csv.
fn eval_returns(run: &Path) -> Vec<f64> {
    let text = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = header.iter().position(|&h| h == "eval_return").unwrap();
    lines
        .map(|l| l.split(',').nth(col).unwrap().parse().unwrap())
        .collect()
}

#[test]
fn a_role_served_by_a_worker_of_ones_own_over_another_transport_equals_sequential() {
    let mut cfg = tiny_config(400);
    cfg.eval.every = 100;
    (cfg.checkpoint.every, cfg.checkpoint.keep) = (200, 5);
    let dir = scratch("extension-toy-role");
    let seq = train_mbpo(&cfg, &dir.join("sequential")).unwrap();
    let run = InProcessRun {
        out: dir.join("lockstep"),
        ipc_root: ipc_root("ext-toy-role"),
        mode: Mode::Lockstep,
        actors: 1,
        slack: Slack::ZERO,
        timeout: Duration::from_secs(240),
    };
    type Threadsafe = mbpo_wire::ipc_threadsafe::Service;
    let loops = |kind: RoleKind| -> ServiceLoop {
        match kind {
            RoleKind::Evaluator => serve::<Threadsafe, CountingEvaluator>,
            other => service_loop::<Threadsafe>(other),
        }
    };
    let s = run_in_process_with::<Threadsafe>(&cfg, &run, &loops).unwrap();
    // The toy's evaluations are the run's; learning is the sequential run's, bit for bit.
    assert_eq!(eval_returns(&run.out), [0.1, 0.2, 0.3, 0.4]);
    assert_eq!(s.summary.policy_sha256, seq.policy_sha256);
    // It took part in the barriers (the periodic one near step 200, the last one) with a file
    // of its own: the evaluations of the eval points <= T.
    let mut cuts = Vec::new();
    for entry in std::fs::read_dir(run.out.join("checkpoints")).unwrap() {
        let t: u64 = entry
            .unwrap()
            .file_name()
            .to_str()
            .unwrap()
            .parse()
            .unwrap();
        let file = mbpo_train::checkpoint::dir_for(&run.out, t).join("evaluator");
        let kind = RoleKind::Evaluator.checkpoint_kind();
        let state: (u64, u64) = mbpo_train::checkpoint::read(&file, kind).unwrap();
        assert_eq!(state, (t / 100, t), "checkpoint after step {t}");
        cuts.push(t);
    }
    cuts.sort();
    assert_eq!((cuts.len(), cuts.last()), (2, Some(&400)), "{cuts:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A toy planner: the constant plan of the better of "push" (+1) and "pull" (−1) over its
/// horizon, by the model's predicted return.
struct BangBang {
    horizon: usize,
    plan: Vec<f32>,
    predicted: f32,
}

impl Planner for BangBang {
    fn horizon(&self) -> usize {
        self.horizon
    }
    fn act_dim(&self) -> usize {
        1
    }
    fn plan(
        &mut self,
        model: &mut dyn PlanningModel,
        obs: &[f32],
        rng: &mut Rng,
    ) -> Result<&[f32], PlanError> {
        let mut best = (f32::NEG_INFINITY, 0.0);
        for a in [1.0f32, -1.0] {
            let (mut o, mut ret) = (obs.to_vec(), 0.0);
            for _ in 0..self.horizon {
                let (mut r, mut next) = ([0.0f32], vec![0.0f32; o.len()]);
                model.step(&o, &[a], &[0], rng, &mut r, &mut next)?;
                (ret, o) = (ret + r[0], next);
            }
            if ret > best.0 {
                best = (ret, a);
            }
        }
        self.predicted = best.0;
        self.plan = vec![best.1; self.horizon];
        Ok(&self.plan)
    }
    fn predicted_return(&self) -> f32 {
        self.predicted
    }
    fn shift(&mut self, _k: usize) {}
    fn reset(&mut self) {
        self.plan.clear();
    }
    fn warm_start(&self) -> Option<&[f32]> {
        None
    }
    fn set_warm_start(&mut self, _: Option<&[f32]>) -> Result<(), PlanError> {
        Ok(())
    }
}

/// The toy task's dynamics as a planning model: x' = x + 0.1·a, reward −x'².
struct LineModel;

impl PlanningModel for LineModel {
    fn obs_dim(&self) -> usize {
        1
    }
    fn act_dim(&self) -> usize {
        1
    }
    fn members(&self) -> usize {
        1
    }
    fn step(
        &mut self,
        obs: &[f32],
        act: &[f32],
        members: &[usize],
        _rng: &mut Rng,
        reward: &mut [f32],
        next_obs: &mut [f32],
    ) -> Result<(), PlanError> {
        for i in 0..members.len() {
            next_obs[i] = obs[i] + 0.1 * act[i];
            reward[i] = -next_obs[i] * next_obs[i];
        }
        Ok(())
    }
}

#[test]
fn a_planner_of_ones_own_drives_the_mpc_controller() {
    let mut rng = stream(0, "toy.plan", 0);
    let planner = BangBang {
        horizon: 5,
        plan: Vec::new(),
        predicted: 0.0,
    };
    // Closed loop: a plan per step, its first action executed; the point is driven to 0.
    let mut mpc = Mpc::new(Box::new(planner), false);
    let (mut x, mut action) = (1.0f32, [0.0f32]);
    mpc.act(&mut LineModel, &[x], &mut rng, &mut action)
        .unwrap();
    // Pulling for 5 steps: x = 0.9 .. 0.5, return −(0.81 + 0.64 + 0.49 + 0.36 + 0.25).
    assert!((mpc.planner().predicted_return() + 2.55).abs() < 1e-5);
    assert_eq!(action[0], -1.0);
    x += 0.1 * action[0];
    for _ in 1..10 {
        assert!(mpc
            .act(&mut LineModel, &[x], &mut rng, &mut action)
            .unwrap());
        assert_eq!(action[0], if x > 0.0 { -1.0 } else { 1.0 }, "x = {x}");
        x += 0.1 * action[0];
    }
    assert!(x.abs() < 1e-5, "x = {x}");
    assert_eq!(mpc.plans(), 10);
    // Open loop: one plan per horizon, executed to its end.
    let planner = BangBang {
        horizon: 5,
        plan: Vec::new(),
        predicted: 0.0,
    };
    let mut mpc = Mpc::new(Box::new(planner), true);
    let planned: Vec<bool> = (0..10)
        .map(|_| {
            mpc.act(&mut LineModel, &[-1.0], &mut rng, &mut action)
                .unwrap()
        })
        .collect();
    assert_eq!(planned.iter().filter(|&&p| p).count(), 2);
    assert_eq!(action[0], 1.0);
}
