//! What a user reads after `mbpo train` and `mbpo plot`: the run directory's log file and
//! TensorBoard event file, and the two PNGs.

use mbpo_integration_tests::bin_dir;
use mbpo_train::run_dir::{read_eval_curve, TENSORBOARD_DIR};
use mbpo_train::tensorboard::read;
use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn train(seed: u64, out: &Path) {
    let output = Command::new(bin_dir().join("mbpo"))
        .current_dir(repo())
        .args(["train", "--config", "deploy/configs/pendulum-tiny.toml"])
        .args(["--steps", "400", "--seed", &seed.to_string(), "--out"])
        .arg(out)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

#[test]
fn train_writes_log_and_tensorboard_files_and_plot_writes_both_pngs() {
    let dir = std::env::temp_dir().join(format!("mbpo-outputs-{}", std::process::id()));
    let runs = [dir.join("tiny-s0"), dir.join("tiny-s1")];
    for (seed, run) in runs.iter().enumerate() {
        train(seed as u64, run);
    }

    // The log file has what stderr had: the evaluation lines.
    let log = std::fs::read_to_string(runs[0].join("logs/train.log")).unwrap();
    assert!(log.contains("seed 0: step 400 eval"), "{log}");

    // One event file whose eval/return equals metrics.csv's (as f32), step = env steps.
    let tb: Vec<PathBuf> = std::fs::read_dir(runs[0].join(TENSORBOARD_DIR))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(tb.len(), 1, "{tb:?}");
    let from_tb: Vec<(u64, f32)> = read::file(&tb[0])
        .unwrap()
        .into_iter()
        .flat_map(|e| {
            let step = e.step as u64;
            e.scalars
                .into_iter()
                .filter(|(tag, _)| tag == "eval/return")
                .map(move |(_, v)| (step, v))
        })
        .collect();
    let from_csv: Vec<(u64, f32)> = read_eval_curve(&runs[0].join("metrics.csv"))
        .unwrap()
        .into_iter()
        .map(|(s, r)| (s, r as f32))
        .collect();
    assert_eq!(from_csv.len(), 2);
    assert_eq!(from_tb, from_csv);

    // `mbpo plot` writes the learning curve and the loss panels next to it.
    let out = dir.join("curves.png");
    let plot = Command::new(bin_dir().join("mbpo"))
        .arg("plot")
        .args(&runs)
        .arg("--out")
        .arg(&out)
        .args(["--table-every", "200"])
        .output()
        .unwrap();
    assert!(
        plot.status.success(),
        "{}",
        String::from_utf8_lossy(&plot.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&plot.stdout).unwrap();
    assert_eq!(report["groups"], serde_json::json!([["tiny", 2]]));
    let losses = dir.join("curves-losses.png");
    assert_eq!(report["losses"], losses.display().to_string());
    for png in [&out, &losses] {
        let bytes = std::fs::read(png).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{}", png.display());
    }
    // ... and the eval returns as a markdown table: each seed's row holds its metrics.csv
    // returns; these runs are not MBPO on a task with a paper curve, so there is none.
    let table = dir.join("curves.md");
    assert_eq!(report["table"], table.display().to_string());
    assert_eq!(report["reference"], serde_json::Value::Null);
    let table = std::fs::read_to_string(&table).unwrap();
    let curve = read_eval_curve(&runs[0].join("metrics.csv")).unwrap();
    let [(s1, r1), (s2, r2)] = curve[..] else {
        panic!("two evaluations expected: {curve:?}")
    };
    assert_eq!(
        (s1, s2),
        (200, 400),
        "--table-every 200 puts a column at each"
    );
    let (best, best_at) = if r2 > r1 { (r2, s2) } else { (r1, s1) };
    let row = format!(
        "| seed 0 | {r1:.0} | {r2:.0} | {:.0} (200-400) | {best:.0} ({best_at}) |",
        (r1 + r2) / 2.0
    );
    assert!(table.contains(&row), "{row} not in\n{table}");
    assert!(table.contains("| median |"), "{table}");
    std::fs::remove_dir_all(dir).unwrap();
}
