//! Diagnostic: train the ensemble on random Pendulum data, report its fit, plan with it.
use mbpo_core::rng::uniform_range_f32;
use mbpo_core::{stream, Batch};
use mbpo_envs::{make, reward_fn, termination_fn};
use mbpo_model::{ModelConfig, ProbabilisticEnsemble};
use mbpo_plan::{build, EnsembleModel, Mpc, PlannerConfig, PlannerKind, RewardSource};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).map_or(400, |s| s.parse().unwrap());
    let batch: usize = args.get(2).map_or(256, |s| s.parse().unwrap());
    let patience: usize = args.get(3).map_or(20, |s| s.parse().unwrap());
    let mut env = make("Pendulum-v1").unwrap();
    let mut rng = stream(0, "diag", 0);
    let mut data = Batch::new(3, 1, n);
    let mut obs = [0.0f32; 3];
    env.reset(&mut rng, &mut obs).unwrap();
    for r in 0..n {
        let a = uniform_range_f32(&mut rng, -1.0, 1.0);
        let mut next = [0.0f32; 3];
        let s = env.step(&[2.0 * a], &mut next).unwrap();
        data.obs[3 * r..3 * r + 3].copy_from_slice(&obs);
        data.act[r] = a;
        data.reward[r] = s.reward as f32;
        data.next_obs[3 * r..3 * r + 3].copy_from_slice(&next);
        obs = next;
        if s.truncated {
            env.reset(&mut rng, &mut obs).unwrap();
        }
    }
    let cfg = ModelConfig {
        members: 5,
        elites: 5,
        hidden: vec![128, 128],
        weight_decay: vec![2.5e-5, 5e-5, 1e-4],
        batch_size: batch,
        max_epochs_since_update: patience,
        ..ModelConfig::default()
    };
    let mut model = ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(0, "m", 0)).unwrap();
    let rep = model.train(&data, &mut stream(0, "t", 0)).unwrap();
    println!(
        "n {n} batch {batch}: {} epochs, {} steps, holdout mse {:?}, {:.2} s",
        rep.epochs, rep.gradient_steps, rep.final_holdout_mse, rep.seconds
    );
    // Per-dimension error of the mean on fresh random data, and predicted sigma.
    let m = 500;
    let mut o = vec![0.0f32; 3 * m];
    let mut a = vec![0.0f32; m];
    let mut truth = vec![0.0f32; 3 * m];
    let mut r_true = vec![0.0f32; m];
    for i in 0..m {
        env.reset(&mut rng, &mut obs).unwrap();
        let u = uniform_range_f32(&mut rng, -1.0, 1.0);
        let mut next = [0.0f32; 3];
        let s = env.step(&[2.0 * u], &mut next).unwrap();
        o[3 * i..3 * i + 3].copy_from_slice(&obs);
        a[i] = u;
        truth[3 * i..3 * i + 3].copy_from_slice(&next);
        r_true[i] = s.reward as f32;
    }
    let members: Vec<usize> = (0..m).map(|i| i % 5).collect();
    let (mut mean, mut lv) = (vec![0.0f32; 4 * m], vec![0.0f32; 4 * m]);
    model
        .predict_gaussian(&o, &a, m, &members, &mut mean, &mut lv)
        .unwrap();
    let mut err = [0.0f64; 4];
    let mut sig = [0.0f64; 4];
    for i in 0..m {
        err[0] += ((mean[4 * i] - r_true[i]) as f64).powi(2);
        for j in 0..3 {
            err[j + 1] += ((mean[4 * i + 1 + j] - truth[3 * i + j]) as f64).powi(2);
        }
        for j in 0..4 {
            sig[j] += (lv[4 * i + j] as f64 / 2.0).exp();
        }
    }
    println!(
        "rmse [r, cos, sin, thdot] = {:?}",
        err.map(|e| (e / m as f64).sqrt())
    );
    println!(
        "mean sigma                = {:?}",
        sig.map(|s| s / m as f64)
    );
    let mut pc = PlannerConfig {
        kind: PlannerKind::Cem,
        horizon: 25,
        particles: 5,
        ..PlannerConfig::default()
    };
    pc.cem.candidates = 400;
    pc.cem.elites = 40;
    let mut em = EnsembleModel::new(
        model,
        RewardSource::Known(reward_fn("Pendulum-v1").unwrap()),
        termination_fn("Pendulum-v1").map(mbpo_model::RolloutRule::Rule),
        &[-2.0],
        &[2.0],
    )
    .unwrap();
    let mut mpc = Mpc::new(build(&pc, 1).unwrap(), false);
    for ep in 0..2 {
        env.reset(&mut rng, &mut obs).unwrap();
        mpc.reset();
        let mut ret = 0.0;
        for _ in 0..200 {
            let mut act = [0.0f32];
            mpc.act(&mut em, &obs, &mut rng, &mut act).unwrap();
            ret += env.step(&[2.0 * act[0]], &mut obs).unwrap().reward;
        }
        println!(
            "episode {ep}: return {ret:.1} (predicted last {:.1})",
            mpc.planner().predicted_return()
        );
    }
}
