use mbpo_core::stream;
use mbpo_nn::{Activation, Adam, AdamConfig, EnsembleCache, EnsembleMlp, Init, Mlp};
use std::time::Instant;

fn main() {
    let e = 7;
    let dims = [23, 200, 200, 200, 200, 36];
    let ens = EnsembleMlp::new(e, Mlp::new(&dims, Activation::Silu, Activation::Identity));
    let b = 256;
    let mut rng = stream(0, "p", 0);
    let mut pe = vec![0.0; ens.num_params()];
    ens.init(&mut pe, Init::TruncatedNormal, &mut rng);
    let xe: Vec<f32> = (0..e * b * 23)
        .map(|i| ((i % 13) as f32 - 6.0) * 0.1)
        .collect();
    let dye = vec![0.01f32; e * b * 36];
    let mut ge = vec![0.0; pe.len()];
    let mut c = EnsembleCache::new(&ens, b);
    let mut adam = Adam::new(pe.len(), AdamConfig::default());
    let fl: f64 = dims
        .windows(2)
        .map(|w| 2.0 * (b * w[0] * w[1]) as f64)
        .sum::<f64>()
        * e as f64;
    let iters = 60;
    for _ in 0..5 {
        ens.forward(&pe, &xe, b, &mut c);
    }
    let t = Instant::now();
    for _ in 0..iters {
        ens.forward(&pe, &xe, b, &mut c);
    }
    let s = t.elapsed().as_secs_f64();
    println!("forward {:.1} GFLOP/s", fl * iters as f64 / s / 1e9);
    let t = Instant::now();
    for _ in 0..iters {
        ens.forward(&pe, &xe, b, &mut c);
        ens.backward(&pe, &xe, &mut c, &dye, Some(&mut ge), None);
    }
    let s = t.elapsed().as_secs_f64();
    println!(
        "fwd+bwd {:.1} GFLOP/s (3x fwd flops)",
        3.0 * fl * iters as f64 / s / 1e9
    );
    let t = Instant::now();
    for _ in 0..iters {
        adam.step(&mut pe, &ge);
    }
    println!(
        "adam {:.3} ms",
        t.elapsed().as_secs_f64() * 1e3 / iters as f64
    );
    println!(
        "roofline {:.1}",
        mbpo_nn::bench::gemm_gflops(256, 200, 200, std::time::Duration::from_secs(1))
    );
}
