//! Diagnostic: MPC on Pendulum-v1 with the exact dynamics as the planning model.
use mbpo_core::stream;
use mbpo_envs::{make, reward_fn};
use mbpo_plan::{build, Mpc, PlanError, PlannerConfig, PlannerKind, PlanningModel};

struct TruePendulum;
impl PlanningModel for TruePendulum {
    fn obs_dim(&self) -> usize {
        3
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
        _rng: &mut mbpo_core::Rng,
        reward: &mut [f32],
        next: &mut [f32],
    ) -> Result<(), PlanError> {
        let f = reward_fn("Pendulum-v1").unwrap();
        for i in 0..members.len() {
            let o = &obs[i * 3..i * 3 + 3];
            let u = (act[i] * 2.0).clamp(-2.0, 2.0);
            reward[i] = (f.value)(o, &[u], o);
            let th = o[1].atan2(o[0]);
            let thd = (o[2] + (15.0 * th.sin() + 3.0 * u) * 0.05).clamp(-8.0, 8.0);
            let th2 = th + thd * 0.05;
            next[i * 3] = th2.cos();
            next[i * 3 + 1] = th2.sin();
            next[i * 3 + 2] = thd;
        }
        Ok(())
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let h: usize = args.get(1).map_or(25, |s| s.parse().unwrap());
    let kind = match args.get(2).map_or("cem", |s| s.as_str()) {
        "mppi" => PlannerKind::Mppi,
        "grad" => PlannerKind::Grad,
        "random" => PlannerKind::Random,
        _ => PlannerKind::Cem,
    };
    let mut cfg = PlannerConfig {
        kind,
        horizon: h,
        particles: 1,
        ..PlannerConfig::default()
    };
    cfg.cem.candidates = 400;
    cfg.cem.elites = 40;
    cfg.mppi.candidates = 400;
    cfg.mppi.iterations = 3;
    cfg.mppi.temperature = 1.0;
    cfg.mppi.sigma = 0.5;
    cfg.mppi.beta = 0.7;
    let mut env = make("Pendulum-v1").unwrap();
    let mut rng = stream(0, "diag", 0);
    let mut mpc = Mpc::new(build(&cfg, 1).unwrap(), false);
    let mut model = TruePendulum;
    for ep in 0..3 {
        let mut obs = [0.0f32; 3];
        env.reset(&mut rng, &mut obs).unwrap();
        mpc.reset();
        let mut ret = 0.0;
        for _ in 0..200 {
            let mut a = [0.0f32];
            mpc.act(&mut model, &obs, &mut rng, &mut a).unwrap();
            let s = env.step(&[a[0] * 2.0], &mut obs).unwrap();
            ret += s.reward;
        }
        println!("episode {ep}: return {ret:.1}");
    }
}
