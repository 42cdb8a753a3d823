//! A corpus of bad configs, each refused with a message that names the key (the full dotted
//! key), the value found and what is allowed -- never a panic, never a silent default: ranges,
//! NaN and infinity, types, lengths, cross-key rules, unknown keys and names, and files that
//! are missing, a directory, empty or binary.

use std::path::{Path, PathBuf};

use mbpo_train::ExperimentConfig;

/// A directory of the test `name` alone (tests run at once and each removes its own).
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mbpo-bad-configs-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Load `text` as a config file and return its error message.
fn refusal(dir: &Path, n: usize, text: &str) -> String {
    let path = dir.join(format!("bad-{n}.toml"));
    std::fs::write(&path, text).unwrap();
    match ExperimentConfig::load(&path) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.to_string(),
    }
}

/// (config text, fragments its refusal must contain).
const CASES: &[(&str, &[&str])] = &[
    ("steps = 0", &["`steps`", "a positive number", "found 0"]),
    (
        "[eval]\nevery = 0",
        &["`eval.every`", "a positive number", "found 0"],
    ),
    (
        "[eval]\ntarget_return = inf",
        &["`eval.target_return`", "a finite number", "inf"],
    ),
    (
        "[sac]\nbatch_size = 0",
        &["`sac.batch_size`", "a positive number"],
    ),
    (
        "[sac]\nactor_lr = nan",
        &["`sac.actor_lr`", "a positive number", "NaN"],
    ),
    (
        "[sac]\ncritic_lr = -1e-3",
        &["`sac.critic_lr`", "a positive number", "-0.001"],
    ),
    (
        "[sac]\nalpha_lr = inf",
        &["`sac.alpha_lr`", "a positive number", "inf"],
    ),
    (
        "[sac]\ninit_alpha = 0.0",
        &["`sac.init_alpha`", "a positive number"],
    ),
    (
        "[sac]\nthreads = 0",
        &["`sac.threads`", "a positive number"],
    ),
    ("[sac]\ngamma = 1.5", &["`sac.gamma`", "in (0, 1]", "1.5"]),
    ("[sac]\ngamma = nan", &["`sac.gamma`", "in (0, 1]", "NaN"]),
    ("[sac]\ntau = 0.0", &["`sac.tau`", "in (0, 1]", "found 0"]),
    (
        "[sac]\nhidden = []",
        &["`sac.hidden`", "a non-empty list of positive widths", "[]"],
    ),
    (
        "[sac]\nhidden = [256, 0]",
        &["`sac.hidden`", "positive widths", "[256, 0]"],
    ),
    (
        "[sac]\nlog_std_min = 3.0",
        &["`sac.log_std_min`", "below sac.log_std_max", "found 3"],
    ),
    ("[sac]\ngamma = \"high\"", &["gamma", "string", "f32"]),
    ("[sac]\nhidden = 256", &["hidden", "integer", "sequence"]),
    ("[sac]\ngama = 0.9", &["gama", "unknown field"]),
    ("seed = -1", &["seed", "-1"]),
    (
        "algo = \"ppo\"",
        &["unknown algorithm 'ppo'", "sac, mbpo, mpc"],
    ),
    (
        "env = \"CartPole-v1\"",
        &["`env`", "Pendulum-v1", "CartPole-v1"],
    ),
    // Python Gymnasium envs: the id, the termination rule, the [gym] table.
    (
        "env = \"gym:\"",
        &["`env`", "gym:<registered id>", "\"gym:\""],
    ),
    (
        "algo = \"mbpo\"\ntermination = \"sometimes\"",
        &[
            "`termination`",
            "\"learned\", \"never\"",
            "Hopper-v5",
            "\"sometimes\"",
        ],
    ),
    (
        "algo = \"mbpo\"\ntermination = \"python:my_rules\"",
        &[
            "`termination`",
            "python:<module>:<function>",
            "\"python:my_rules\"",
        ],
    ),
    (
        "[gym]\nmax_episode_steps = 50",
        &["`gym`", "Python envs", "Pendulum-v1"],
    ),
    (
        "env = \"gym:Pendulum-v1\"\n[gym]\npath = [\"/nonexistent/envs\"]",
        &["`gym.path`", "folders that exist", "/nonexistent/envs"],
    ),
    (
        "env = \"gym:Pendulum-v1\"\n[gym.kwargs]\ng = nan",
        &["`gym.kwargs.g`", "finite numbers", "NaN"],
    ),
    (
        "env = \"gym:Pendulum-v1\"\n[gym]\nmax_episode_steps = 0",
        &["`gym.max_episode_steps`", "a positive number"],
    ),
    (
        "env = \"gym:dmc_env:make\"\n[gym]\nname = \"dmc/walker walk\"",
        &["`gym.name`", "a name for files", "\"dmc/walker walk\""],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nepoch_length = 0",
        &["`mbpo.epoch_length`", "a positive number"],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nmodel_train_freq = 0",
        &["`mbpo.model_train_freq`", "a positive number"],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nrollouts_per_step = 0",
        &["`mbpo.rollouts_per_step`", "a positive number"],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nupdates_per_step = 0",
        &["`mbpo.updates_per_step`", "a positive number"],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nreal_ratio = 1.5",
        &["`mbpo.real_ratio`", "in [0, 1]", "1.5"],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nreal_ratio = nan",
        &["`mbpo.real_ratio`", "in [0, 1]", "NaN"],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nrollout_keep_fraction = 0",
        &["`mbpo.rollout_keep_fraction`", "in (0, 1]", "found 0"],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nrollout_keep_fraction = 1.25",
        &["`mbpo.rollout_keep_fraction`", "in (0, 1]", "1.25"],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nrollout_keep_fraction = nan",
        &["`mbpo.rollout_keep_fraction`", "in (0, 1]", "NaN"],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nrollout_schedule = [100, 20, 1, 15]",
        &[
            "`mbpo.rollout_schedule`",
            "e_min <= e_max",
            "[100, 20, 1, 15]",
        ],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nrollout_schedule = [20, 100, 0, 15]",
        &["`mbpo.rollout_schedule`", "1 <= k_min", "[20, 100, 0, 15]"],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\nrollout_schedule = [20, 100, 1]",
        &["rollout_schedule", "3"],
    ),
    (
        "[checkpoint]\nkeep = 0",
        &["`checkpoint.keep`", "a positive number", "found 0"],
    ),
    (
        "[checkpoint]\nevery = 1000\nkeep_every = 2500",
        &[
            "`checkpoint.keep_every`",
            "a multiple of checkpoint.every (1000)",
            "found 2500",
        ],
    ),
    (
        "algo = \"mbpo\"\n[model]\nmembers = 7\nelites = 9",
        &["`model.elites`", "between 1 and members (7)", "found 9"],
    ),
    (
        "algo = \"mbpo\"\n[model]\nmembers = 0",
        &["`model.members`", "at least 1", "found 0"],
    ),
    (
        "algo = \"mbpo\"\n[model]\nhidden = [200, 0]",
        &["`model.hidden`", "positive widths", "[200, 0]"],
    ),
    (
        "algo = \"mbpo\"\n[model]\nweight_decay = [1e-5]",
        &[
            "`model.weight_decay`",
            "one value per dense layer",
            "1 values",
        ],
    ),
    (
        "algo = \"mbpo\"\n[model]\nholdout_ratio = 0.0",
        &["`model.holdout_ratio`", "in (0, 1)", "found 0"],
    ),
    (
        "algo = \"mbpo\"\n[model]\nthreads = 0",
        &["`model.threads`", "1 to 64", "found 0"],
    ),
    (
        "algo = \"mpc\"\n[mpc]\nmodel_train_freq = 0",
        &["`mpc.model_train_freq`", "a positive number", "found 0"],
    ),
    (
        "algo = \"mpc\"\n[mpc]\ninit_random_steps = 0",
        &["`mpc.init_random_steps`", "at least 5", "found 0"],
    ),
    (
        "algo = \"mbpo\"\n[mbpo]\ninit_random_steps = 3",
        &["`mbpo.init_random_steps`", "at least 5", "found 3"],
    ),
];

#[test]
fn every_bad_config_is_refused_naming_its_key_value_and_what_is_allowed() {
    assert!(CASES.len() >= 30);
    let dir = scratch("cases");
    for (n, (text, fragments)) in CASES.iter().enumerate() {
        let err = refusal(&dir, n, text);
        for f in *fragments {
            assert!(
                err.contains(f),
                "config:\n{text}\nrefusal: {err}\nmissing: {f}"
            );
        }
    }
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn config_files_that_are_missing_a_directory_empty_or_binary_are_refused_by_name() {
    let dir = scratch("files");
    std::fs::create_dir_all(&dir).unwrap();
    let empty = dir.join("empty.toml");
    std::fs::write(&empty, "  \n").unwrap();
    let binary = dir.join("binary.toml");
    std::fs::write(&binary, [0xff, 0xfe, 0x00, 0x81]).unwrap();
    let cases = [
        (dir.join("missing.toml"), "No such file"),
        (dir.clone(), "Is a directory"),
        (empty, "is empty"),
        (binary, "UTF-8"),
    ];
    for (path, want) in cases {
        for err in [
            ExperimentConfig::load(&path).unwrap_err().to_string(),
            ExperimentConfig::resolve(Some(&path), &[])
                .unwrap_err()
                .to_string(),
        ] {
            assert!(
                err.contains(&path.display().to_string()) && err.contains(want),
                "{err}"
            );
        }
    }
    let _ = std::fs::remove_dir_all(dir);
}
