//! Spike: Zenoh pub/sub throughput and round-trip latency between two processes.
//! `zenoh_spike listen tcp/10.77.0.1:7447` on one side, `zenoh_spike connect tcp/10.77.0.1:7447` on the other.
use std::time::{Duration, Instant};
use zenoh::qos::CongestionControl;
use zenoh::Wait;

fn config(mode: &str, endpoint: &str) -> zenoh::Config {
    let mut c = zenoh::Config::default();
    c.insert_json5("mode", "\"peer\"").unwrap();
    c.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    let key = if mode == "listen" {
        "listen/endpoints"
    } else {
        "connect/endpoints"
    };
    c.insert_json5(key, &format!("[\"{endpoint}\"]")).unwrap();
    c
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (mode, endpoint) = (args[1].as_str(), args[2].as_str());
    let session = zenoh::open(config(mode, endpoint)).wait().unwrap();
    if mode == "listen" {
        // Echo side: every message on spike/req goes back on spike/rep; counts bytes.
        let rep = session
            .declare_publisher("spike/rep")
            .congestion_control(CongestionControl::Block)
            .wait()
            .unwrap();
        let sub = session.declare_subscriber("spike/req").wait().unwrap();
        let mut bytes = 0usize;
        let mut n = 0usize;
        let mut t0 = None;
        while let Ok(s) = sub.recv() {
            let p = s.payload().to_bytes();
            if p[0] == 1 {
                rep.put(p.to_vec()).wait().unwrap();
            } else if p[0] == 2 {
                t0.get_or_insert_with(Instant::now);
                bytes += p.len();
                n += 1;
            } else if p[0] == 3 {
                let dt = t0
                    .map(|t: Instant| t.elapsed().as_secs_f64())
                    .unwrap_or(0.0);
                println!(
                    "received {n} msgs {bytes} bytes in {dt:.3}s: {:.1} MB/s {:.0} msg/s",
                    bytes as f64 / dt / 1e6,
                    n as f64 / dt
                );
                rep.put(vec![3u8]).wait().unwrap();
                bytes = 0;
                n = 0;
                t0 = None;
            }
        }
    } else {
        let req = session
            .declare_publisher("spike/req")
            .congestion_control(CongestionControl::Block)
            .wait()
            .unwrap();
        let sub = session.declare_subscriber("spike/rep").wait().unwrap();
        std::thread::sleep(Duration::from_secs(1));
        for &size in &[64usize, 1024, 65_536, 300_000, 1_200_000] {
            // Round trips.
            let mut lat = Vec::new();
            let reps = if size > 100_000 { 200 } else { 1000 };
            let mut msg = vec![0u8; size];
            msg[0] = 1;
            for _ in 0..reps {
                let t = Instant::now();
                req.put(msg.clone()).wait().unwrap();
                let _ = sub.recv().unwrap();
                lat.push(t.elapsed().as_secs_f64() * 1e3);
            }
            lat.sort_by(|a, b| a.partial_cmp(b).unwrap());
            println!(
                "size {size}: round trip p50 {:.3} ms p99 {:.3} ms",
                lat[lat.len() / 2],
                lat[lat.len() * 99 / 100]
            );
            // One-way stream.
            msg[0] = 2;
            let count = (200_000_000 / size).clamp(100, 100_000);
            let t = Instant::now();
            for _ in 0..count {
                req.put(msg.clone()).wait().unwrap();
            }
            req.put(vec![3u8]).wait().unwrap();
            let _ = sub.recv().unwrap();
            let dt = t.elapsed().as_secs_f64();
            println!(
                "size {size}: {count} msgs in {dt:.3}s = {:.1} MB/s, {:.0} msg/s (sender side)",
                (count * size) as f64 / dt / 1e6,
                count as f64 / dt
            );
        }
    }
}
