//! Several machines (issue 21): the head in one network namespace, a worker in another, joined
//! by a veth pair of the test's own addresses, each with its own /dev/shm, so the two share
//! nothing but the link (`mbpo_integration_tests::netns`). Real TCP, real Zenoh, the real
//! binaries. Needs root; elsewhere each test says so and passes without running.

use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use mbpo_integration_tests::netns::TwoHosts;
use mbpo_integration_tests::*;
use mbpo_train::train_mbpo;

const TIMEOUT: Duration = Duration::from_secs(600);

/// The two hosts, or `None` after saying plainly why they cannot be made here.
fn hosts(test: &str) -> Option<TwoHosts> {
    match TwoHosts::create() {
        Ok(h) => Some(h),
        Err(why) => {
            eprintln!("SKIPPED {test}: cannot make network namespaces here: {why}");
            None
        }
    }
}

/// A credentials directory with the run's user/password (the head's and the worker's alike).
fn credentials(dir: &Path, password: &str) -> PathBuf {
    let d = dir.join(format!("credentials-{password}"));
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("password"), format!("mbpo:{password}\n")).unwrap();
    d
}

/// A head's mode and actors.
struct Actors {
    mode: &'static str,
    local: u16,
    remote: u16,
    /// `--restart on-failure`.
    restart: bool,
    /// `--remote-roles` (empty: none).
    remote_roles: &'static str,
}

const fn pipelined(local: u16, remote: u16) -> Actors {
    Actors {
        mode: "pipelined",
        local,
        remote,
        restart: false,
        remote_roles: "",
    }
}

struct Run {
    child: Child,
    out: PathBuf,
}

/// `mbpo run` in the head namespace, listening on the head's link address.
fn start_head(hosts: &TwoHosts, dir: &Path, input: &Path, creds: &Path, run: Actors) -> Run {
    start_head_on(hosts, "tcp", dir, input, creds, run)
}

/// [`start_head`] on a `proto` (tcp or tls) endpoint.
fn start_head_on(
    hosts: &TwoHosts,
    proto: &str,
    dir: &Path,
    input: &Path,
    creds: &Path,
    run: Actors,
) -> Run {
    let out = dir.join("run");
    let (local, remote) = (run.local.to_string(), run.remote.to_string());
    let root = short_root(dir, "h");
    let listen = format!("{proto}/{}:7447", hosts.head.addr);
    let mut args = vec![
        "run",
        "--config",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--ipc-root",
        root.to_str().unwrap(),
        "--listen",
        &listen,
        "--credentials",
        creds.to_str().unwrap(),
        "--quiet",
        "--mode",
        run.mode,
        "--actors",
        &local,
        "--remote-actors",
        &remote,
    ];
    if run.restart {
        args.extend(["--restart", "on-failure"]);
    }
    if !run.remote_roles.is_empty() {
        args.extend(["--remote-roles", run.remote_roles]);
    }
    let child = hosts
        .command(&hosts.head, &bin_dir().join("mbpo"), &args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawning mbpo run");
    Run { child, out }
}

/// `mbpo join` in the worker namespace; its stderr goes to `<dir>/<name>.log`.
fn start_worker(
    hosts: &TwoHosts,
    dir: &Path,
    name: &str,
    creds: Option<&Path>,
    actors: u16,
) -> Child {
    start_worker_on(hosts, "tcp", dir, name, creds, actors)
}

/// [`start_worker`] joining a `proto` (tcp or tls) endpoint.
fn start_worker_on(
    hosts: &TwoHosts,
    proto: &str,
    dir: &Path,
    name: &str,
    creds: Option<&Path>,
    actors: u16,
) -> Child {
    let actors = actors.to_string();
    start_worker_offering(hosts, proto, dir, name, creds, &["--actors", &actors])
}

/// `mbpo join` offering what `offer` says (`--actors N`, `--roles R`).
fn start_worker_offering(
    hosts: &TwoHosts,
    proto: &str,
    dir: &Path,
    name: &str,
    creds: Option<&Path>,
    offer: &[&str],
) -> Child {
    let head = format!("{proto}/{}:7447", hosts.head.addr);
    let root = short_root(dir, name);
    let work = dir.join(format!("work-{name}"));
    let mut args = vec!["join", &head];
    args.extend(offer);
    args.extend([
        "--name",
        name,
        "--ipc-root",
        root.to_str().unwrap(),
        "--dir",
        work.to_str().unwrap(),
    ]);
    if let Some(c) = creds {
        args.extend(["--credentials", c.to_str().unwrap()]);
    }
    let log = std::fs::File::create(dir.join(format!("{name}.log"))).unwrap();
    hosts
        .command(&hosts.worker, &bin_dir().join("mbpo"), &args)
        .stdout(Stdio::piped())
        .stderr(log)
        .spawn()
        .expect("spawning mbpo join")
}

/// An iceoryx2 base directory short enough for its sockets (the scratch dir's is too long).
fn short_root(dir: &Path, who: &str) -> PathBuf {
    let test = dir.file_name().unwrap().to_str().unwrap();
    let tag: String = test
        .split('-')
        .nth(3)
        .unwrap_or("x")
        .chars()
        .take(4)
        .collect();
    ipc_root(&format!("{tag}{}", &who[..who.len().min(3)]))
}

fn text(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_default()
}

/// The head's run, once it ends: completed, with the final policy and evaluation of the
/// sequential run `seq` (`what` names the run in the failure); its summary.
fn completed_as(head: Run, seq: &mbpo_train::Summary, what: &str) -> serde_json::Value {
    let o = wait_output(head.child, TIMEOUT);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&head.out);
    assert_eq!(s["status"], "completed");
    assert_eq!(
        s["policy_sha256"],
        seq.policy_sha256.as_str(),
        "{what} != sequential"
    );
    assert_eq!(s["final_eval_return"], seq.final_eval_return);
    s
}

/// Wait until `path` contains `needle` (at most `timeout`).
fn wait_for_text(path: &Path, needle: &str, timeout: Duration) -> bool {
    let t = Instant::now();
    while t.elapsed() < timeout {
        if text(path).contains(needle) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    false
}

/// One local and two remote actors, pipelined, over mutual TLS with `mbpo certs`'
/// credentials: the run completes and every transition of the remote actors reached every
/// consumer on the head exactly once.
#[test]
fn pipelined_run_with_remote_actors_loses_nothing() {
    let Some(hosts) = hosts("pipelined_run_with_remote_actors_loses_nothing") else {
        return;
    };
    let dir = scratch("net-pipelined");
    let input = write_config(&tiny_config(600), &dir);
    let certs = dir.join("certs");
    let made = std::process::Command::new(bin_dir().join("mbpo"))
        .args(["certs", "--out", certs.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    let head = start_head_on(
        &hosts,
        "tls",
        &dir,
        &input,
        &certs.join("head"),
        pipelined(1, 2),
    );
    let worker = start_worker_on(&hosts, "tls", &dir, "w1", Some(&certs.join("worker")), 2);
    let o = wait_output(head.child, TIMEOUT);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&head.out);
    assert_eq!(s["status"], "completed");
    assert_no_loss(&s, 600);
    let w = wait_output(worker, TIMEOUT);
    assert!(w.status.success(), "{}", text(&dir.join("w1.log")));
    let report: serde_json::Value = serde_json::from_slice(&w.stdout).unwrap();
    assert_eq!(
        report["slots"],
        serde_json::json!(["actor-1", "actor-2"]),
        "{report}"
    );
    // The summary counts the worker host.
    assert_eq!(s["hosts"]["w1"]["actors"], serde_json::json!([1, 2]), "{s}");
    assert_eq!(s["hosts"]["w1"]["restarts"], 0, "{s}");
    // What the progress line shows: who holds the remote slots.
    let live = mbpo_runtime::LiveHosts::read(&head.out).expect("hosts-live.json");
    assert_eq!(live.progress_text(1), "hosts: head 1, w1 2", "{live:?}");
    // The remote actors' logs reached the head (no shared filesystem).
    for slot in [1, 2] {
        let log = head
            .out
            .join("logs")
            .join("w1")
            .join(format!("actor-{slot}.log"));
        assert!(text(&log).contains("done: "), "{}", log.display());
    }
    let _ = std::fs::remove_dir_all(dir);
}

/// Lockstep with its one actor on the worker equals `mbpo train --mode sequential`.
#[test]
fn lockstep_with_a_remote_actor_equals_sequential() {
    let test = "lockstep_with_a_remote_actor_equals_sequential";
    lockstep_with_a_remote_actor(test, tiny_config(400), train_mbpo);
}

/// [`lockstep_with_a_remote_actor_equals_sequential`] for TD-MPC2: its latent-planning actor
/// on the worker receives the world model's parameters over the link.
#[test]
fn tdmpc_lockstep_with_a_remote_actor_equals_sequential() {
    let test = "tdmpc_lockstep_with_a_remote_actor_equals_sequential";
    let cfg = tiny_tdmpc_config(300);
    lockstep_with_a_remote_actor(test, cfg, mbpo_train::tdmpc::train_tdmpc);
}

/// `cfg` in lockstep with its one actor on a worker host ends as `train` does in one process.
fn lockstep_with_a_remote_actor(
    test: &str,
    cfg: mbpo_train::ExperimentConfig,
    train: fn(
        &mbpo_train::ExperimentConfig,
        &Path,
    ) -> Result<mbpo_train::Summary, mbpo_train::TrainError>,
) {
    let Some(hosts) = hosts(test) else {
        return;
    };
    let dir = scratch(&format!("net-{}", &test[..12]));
    let input = write_config(&cfg, &dir);
    let creds = credentials(&dir, "right");
    bin_dir();
    let head = start_head(
        &hosts,
        &dir,
        &input,
        &creds,
        Actors {
            mode: "lockstep",
            local: 0,
            remote: 1,
            restart: false,
            remote_roles: "",
        },
    );
    let worker = start_worker(&hosts, &dir, "w1", Some(&creds), 1);
    let seq = train(&cfg, &dir.join("sequential")).unwrap();
    completed_as(head, &seq, "remote lockstep");
    assert!(wait_output(worker, TIMEOUT).status.success());
    let _ = std::fs::remove_dir_all(dir);
}

/// Lockstep with its evaluator on the worker (`--remote-roles evaluator`, `mbpo join --actors 0
/// --roles evaluator`) and its actor on the head equals `mbpo train --mode sequential`: the
/// gateways carry the evaluator's channels -- the policy and control commands to it, its
/// reports and its acknowledgements (which hold the learner back in lockstep) to the head --
/// and its checkpoint files reach the head's run directory.
#[test]
fn lockstep_with_the_evaluator_on_a_worker_equals_sequential() {
    let Some(hosts) = hosts("lockstep_with_the_evaluator_on_a_worker_equals_sequential") else {
        return;
    };
    let dir = scratch("net-remote-eval");
    let mut cfg = tiny_config(400);
    cfg.checkpoint.every = 200;
    let input = write_config(&cfg, &dir);
    let creds = credentials(&dir, "right");
    bin_dir();
    let run = Actors {
        mode: "lockstep",
        local: 1,
        remote: 0,
        restart: false,
        remote_roles: "evaluator",
    };
    let head = start_head(&hosts, &dir, &input, &creds, run);
    let offer = ["--actors", "0", "--roles", "evaluator"];
    let worker = start_worker_offering(&hosts, "tcp", &dir, "w1", Some(&creds), &offer);
    let seq = train_mbpo(&cfg, &dir.join("sequential")).unwrap();
    let out = head.out.clone();
    let s = completed_as(head, &seq, "lockstep with a remote evaluator");
    assert_eq!(
        s["hosts"]["w1"]["roles"],
        serde_json::json!(["evaluator"]),
        "{s}"
    );
    assert_eq!(s["hosts"]["w1"]["actors"], serde_json::json!([]), "{s}");
    // No evaluator ran on the head; its files came over the link.
    assert!(!out.join("logs").join("evaluator.log").exists());
    let log = out.join("logs").join("w1").join("evaluator.log");
    assert!(
        text(&log).contains("eval after step 400"),
        "{}",
        log.display()
    );
    // Every checkpoint (the two newest are kept) holds the remote evaluator's file.
    let kept: Vec<_> = std::fs::read_dir(out.join("checkpoints"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(kept.len(), 2, "{kept:?}");
    for dir in kept {
        let file = dir.join("evaluator");
        assert!(file.is_file(), "{}", file.display());
    }
    let w = wait_output(worker, TIMEOUT);
    assert!(w.status.success(), "{}", text(&dir.join("w1.log")));
    let report: serde_json::Value = serde_json::from_slice(&w.stdout).unwrap();
    assert_eq!(
        report["slots"],
        serde_json::json!(["evaluator"]),
        "{report}"
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// The link goes down for 5 s in the middle of a run: the run waits (the hosts share nothing
/// else), then completes with every transition once.
#[test]
fn a_link_down_for_5_s_stalls_the_run_and_loses_nothing() {
    let Some(hosts) = hosts("a_link_down_for_5_s_stalls_the_run_and_loses_nothing") else {
        return;
    };
    let dir = scratch("net-linkdown");
    // Long enough that the link goes down well before the end (1000 steps take ~3 s here).
    let steps = 4000;
    let input = write_config(&tiny_config(steps), &dir);
    let creds = credentials(&dir, "right");
    bin_dir();
    let head = start_head(&hosts, &dir, &input, &creds, pipelined(0, 1));
    let worker = start_worker(&hosts, &dir, "w1", Some(&creds), 1);
    let gateway_log = head.out.join("logs").join("gateway.log");
    assert!(
        wait_for_text(&gateway_log, "joined: actor-0", Duration::from_secs(120)),
        "the worker never joined: {}",
        text(&gateway_log)
    );
    std::thread::sleep(Duration::from_secs(1));
    hosts.set_link(false);
    std::thread::sleep(Duration::from_secs(5));
    hosts.set_link(true);
    let o = wait_output(head.child, TIMEOUT);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&head.out);
    assert_eq!(s["status"], "completed");
    assert_no_loss(&s, steps);
    assert_eq!(s["restarts"], 0, "the link's outage cost a restart: {s}");
    let log = text(&gateway_log);
    assert!(
        log.contains("worker w1: nothing heard"),
        "the head never missed the worker: {log}"
    );
    assert!(log.contains("worker w1: heard again"), "{log}");
    assert!(wait_output(worker, TIMEOUT).status.success());
    let _ = std::fs::remove_dir_all(dir);
}

/// The worker host's processes are SIGKILLed mid-run and `mbpo join` starts again: the head
/// restarts the pipeline from its newest checkpoint, the worker rejoins, nothing is lost.
#[test]
fn a_worker_killed_and_started_again_rejoins_and_nothing_is_lost() {
    let Some(hosts) = hosts("a_worker_killed_and_started_again_rejoins_and_nothing_is_lost") else {
        return;
    };
    let dir = scratch("net-kill");
    let (head, mut worker, creds) = restartable_run_past_its_first_checkpoint(&hosts, &dir);
    // SIGKILL every process of the worker host: `ip netns exec`'s tree.
    let victims = mbpo_runtime::processes_mentioning(dir.join("work-w1").to_str().unwrap());
    assert!(!victims.is_empty(), "no worker processes found");
    let killed = kill_tree(worker.id() as i32);
    let _ = worker.wait();
    assert!(
        killed >= 2,
        "killed {killed} process(es): the gateway and its actor at least"
    );
    let worker = start_worker(&hosts, &dir, "w1", Some(&creds), 1);
    let o = wait_output(head.child, TIMEOUT);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&head.out);
    assert_eq!(s["status"], "completed");
    assert_no_loss(&s, 1000);
    assert!(s["restarts"].as_u64().unwrap_or(0) >= 1, "{s}");
    assert!(
        s["hosts"]["w1"]["restarts"].as_u64().unwrap_or(0) >= 1,
        "{s}"
    );
    assert!(
        wait_output(worker, TIMEOUT).status.success(),
        "{}",
        text(&dir.join("w1.log"))
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// A process of the head host (its SAC learner) is SIGKILLed mid-run: the supervisor rolls
/// the pipeline back to its newest checkpoint and the remote actors, told to stop for the
/// rollback and not for the end of the run, stay in it: the worker joins the next attempt and
/// the run completes with nothing lost. (Before, the rollback's Stop ended the worker as if the
/// run were over, and the next attempt waited for a worker that had left.)
#[test]
fn a_head_process_killed_mid_run_rolls_back_with_the_worker_still_in() {
    head_process_killed_mid_run("learner", "mbpo-sac-learner");
}

/// The head's own gateway is SIGKILLed mid-run, so no Stop reaches the worker at all: the new
/// attempt's gateway refuses the heartbeats of the old attempt's worker, and the worker takes
/// that as the head having restarted and joins at once, not after `--head-timeout` (60 s).
#[test]
fn the_head_gateway_killed_mid_run_is_restarted_and_the_worker_rejoins_at_once() {
    let log = head_process_killed_mid_run("gateway", "mbpo-gateway");
    assert!(log.contains("the head restarted"), "{log}");
    assert!(
        !log.contains("--head-timeout"),
        "the worker waited for the old head to go silent: {log}"
    );
}

/// Kill the head's process `victim` (its command line names `binary`) after the first
/// checkpoint of a pipelined run with one local and one remote actor and `--restart
/// on-failure`; the run must complete with nothing lost, the worker in the next attempt.
/// Returns the worker's log.
fn head_process_killed_mid_run(victim: &str, binary: &str) -> String {
    let test = format!("head process {victim} killed");
    let Some(hosts) = hosts(&test) else {
        return String::new();
    };
    let dir = scratch(&format!("net-{victim}kill"));
    let (head, worker, _) = restartable_run_past_its_first_checkpoint(&hosts, &dir);
    let pids: Vec<i32> = mbpo_runtime::processes_mentioning(head.out.to_str().unwrap())
        .iter()
        .filter(|p| p.contains(binary))
        .filter_map(|p| p.split(':').next()?.parse().ok())
        .collect();
    assert_eq!(pids.len(), 1, "the head's {victim}: {pids:?}");
    // SAFETY: kill(2) of a process this test's run started.
    unsafe { libc::kill(pids[0], libc::SIGKILL) };
    let o = wait_output(head.child, TIMEOUT);
    let worker_log = || text(&dir.join("w1.log"));
    assert!(
        o.status.success(),
        "{}\nworker:\n{}",
        String::from_utf8_lossy(&o.stderr),
        worker_log()
    );
    let s = summary(&head.out);
    assert_eq!(s["status"], "completed");
    assert_no_loss(&s, 1000);
    assert!(s["restarts"].as_u64().unwrap_or(0) >= 1, "{s}");
    let w = wait_output(worker, TIMEOUT);
    assert!(w.status.success(), "{}", worker_log());
    // The worker's report (its last stdout line) and the head's account (hosts.json, in the
    // summary) agree: a killed gateway's attempt is in the account too.
    let stdout = String::from_utf8_lossy(&w.stdout);
    let report: serde_json::Value =
        serde_json::from_str(stdout.lines().last().unwrap_or_default()).unwrap_or_default();
    let attempts = report["attempts"].as_u64().unwrap_or(0);
    assert!(
        attempts >= 2,
        "the worker did not join the attempt after the rollback: {stdout}\n{}",
        worker_log()
    );
    assert_eq!(
        s["hosts"]["w1"]["attempts"].as_u64(),
        Some(attempts),
        "the head's account of the worker's attempts: {s}\nworker: {stdout}"
    );
    let log = worker_log();
    let _ = std::fs::remove_dir_all(dir);
    log
}

/// A pipelined run of 1000 steps (checkpoints every 200) with one local and one remote actor
/// and `--restart on-failure`, its worker joined, once its first checkpoint (which holds the
/// remote actor's file) is complete: the head, the worker and their credentials.
fn restartable_run_past_its_first_checkpoint(
    hosts: &TwoHosts,
    dir: &Path,
) -> (Run, Child, PathBuf) {
    let mut cfg = tiny_config(1000);
    cfg.checkpoint.every = 200;
    let input = write_config(&cfg, dir);
    let creds = credentials(dir, "right");
    bin_dir();
    let head = start_head(
        hosts,
        dir,
        &input,
        &creds,
        Actors {
            mode: "pipelined",
            local: 1,
            remote: 1,
            restart: true,
            remote_roles: "",
        },
    );
    let worker = start_worker(hosts, dir, "w1", Some(&creds), 1);
    let checkpoints = head.out.join("checkpoints");
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(300) {
        let complete = std::fs::read_dir(&checkpoints)
            .map(|d| d.flatten().any(|e| e.path().join("COMPLETE").is_file()))
            .unwrap_or(false);
        if complete {
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    (head, worker, creds)
}

/// SIGKILL `pid` and every descendant; returns how many.
fn kill_tree(pid: i32) -> usize {
    let mut all = vec![pid];
    let mut i = 0;
    while i < all.len() {
        let children =
            std::fs::read_to_string(format!("/proc/{}/task/{}/children", all[i], all[i]))
                .unwrap_or_default();
        all.extend(
            children
                .split_whitespace()
                .filter_map(|c| c.parse::<i32>().ok()),
        );
        i += 1;
    }
    for p in &all {
        // SAFETY: kill(2) with a pid of a process this test started (or its descendant).
        unsafe { libc::kill(*p, libc::SIGKILL) };
    }
    all.len()
}

/// Peers with a wrong password or none are refused (they never join, nothing of theirs
/// reaches the run) and the run completes with the right one.
#[test]
fn a_peer_without_the_credentials_is_refused_and_the_run_goes_on() {
    let Some(hosts) = hosts("a_peer_without_the_credentials_is_refused_and_the_run_goes_on") else {
        return;
    };
    let dir = scratch("net-creds");
    let input = write_config(&tiny_config(400), &dir);
    let creds = credentials(&dir, "right");
    let wrong = credentials(&dir, "wrong");
    bin_dir();
    let head = start_head(&hosts, &dir, &input, &creds, pipelined(0, 1));
    let intruder = start_worker(&hosts, &dir, "intruder", Some(&wrong), 1);
    let anonymous = start_worker(&hosts, &dir, "anonymous", None, 1);
    // Both were refused while the head listened (a worker says so after 5 s without an
    // answer), before the good worker starts the run; a fixed wait raced that 5 s.
    for name in ["intruder", "anonymous"] {
        let log = dir.join(format!("{name}.log"));
        assert!(
            wait_for_text(&log, "no answer from the head", TIMEOUT),
            "{name} did not say why it was not let in: {}",
            text(&log)
        );
    }
    let good = start_worker(&hosts, &dir, "good", Some(&creds), 1);
    let o = wait_output(head.child, TIMEOUT);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&head.out);
    assert_eq!(s["status"], "completed");
    assert_no_loss(&s, 400);
    let gateway = text(&head.out.join("logs").join("gateway.log"));
    assert!(gateway.contains("worker good"), "{gateway}");
    assert!(
        !gateway.contains("intruder") && !gateway.contains("anonymous"),
        "{gateway}"
    );
    assert!(wait_output(good, TIMEOUT).status.success());
    for (child, name) in [(intruder, "intruder"), (anonymous, "anonymous")] {
        let log = text(&dir.join(format!("{name}.log")));
        assert!(!log.contains("joined run"), "{name} joined: {log}");
        assert!(
            log.contains("no answer from the head"),
            "{name} did not say why: {log}"
        );
        kill_tree(child.id() as i32);
    }
    let _ = std::fs::remove_dir_all(dir);
}
