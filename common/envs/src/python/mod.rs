//! Python Gymnasium environments: `env = "gym:<id or entry point>"`.
//!
//! A [`PythonEnv`] owns one Python process that hosts the environment (`host.py`, embedded in
//! this crate) and drives it over the child's stdin/stdout with fixed-size binary frames: one
//! write and one read per step, blocking (no polling). The host redirects the environment's own
//! prints to stderr, so they reach the actor's log and never the protocol.
//!
//! What a Python env cannot do and the Rust side therefore does not offer: restoring a state
//! ([`Env::restorable`] is `None`; a resumed actor starts a new episode). What it adds: the
//! process may die ([`EnvError::PythonExited`]); the next [`Env::reset`] starts a new one.
//!
//! Seeding: every reset passes `seed=<u64 drawn from the caller's stream>`, so a run's episodes
//! are the same wherever the Python env itself is deterministic, also after a resume.

use std::io::{Read, Write};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use mbpo_core::Rng;
use rand::RngCore;
use serde::{Deserialize, Serialize};

use crate::{BoxSpace, Env, EnvError, ObsPart, Step};

/// The prefix of a Python Gymnasium environment's id in a config (`gym:Pendulum-v1`).
pub const GYM_PREFIX: &str = "gym:";

/// The host script the Python process runs.
const HOST_PY: &str = include_str!("host.py");
const REQUEST_HEAD: usize = 16;
const RESPONSE_HEAD: usize = 24;

/// How to start a Python Gymnasium environment.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct GymSpec {
    /// What follows `gym:`: a registered id (`Pendulum-v1`, `my_pkg:MyEnv-v0`) or an entry
    /// point (`my_pkg.envs:MyEnv`, a `gymnasium.Env` class or a function returning one).
    pub target: String,
    /// Keyword arguments for `gymnasium.make` or the entry point.
    pub kwargs: serde_json::Map<String, serde_json::Value>,
    /// The interpreter (`None`: [`default_python`]).
    pub python: Option<PathBuf>,
    /// A time limit for an env without one, or to override the registered one.
    pub max_episode_steps: Option<usize>,
    /// Folders put before `PYTHONPATH` (where the env's module is).
    pub path: Vec<PathBuf>,
}

impl GymSpec {
    /// The spec of `id` (`gym:...`) with no keyword arguments and the default interpreter;
    /// `None` when `id` is not a `gym:` id.
    pub fn from_id(id: &str) -> Option<Self> {
        let target = id.strip_prefix(GYM_PREFIX)?;
        Some(Self {
            target: target.to_string(),
            ..Self::default()
        })
    }

    /// The interpreter this spec runs.
    pub fn interpreter(&self) -> PathBuf {
        self.python.clone().unwrap_or_else(default_python)
    }
}

/// The default interpreter: `$MBPO_PYTHON`, else the project venv made by
/// `deploy/setup_python.sh` (Gymnasium and NumPy installed), else `python3` from `PATH`.
pub fn default_python() -> PathBuf {
    if let Some(p) = std::env::var_os("MBPO_PYTHON") {
        return PathBuf::from(p);
    }
    let venv = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../.venv/bin/python"
    ));
    match venv.exists() {
        true => venv,
        false => PathBuf::from("python3"),
    }
}

/// What the host reports about its environment when it starts.
#[derive(Debug, Clone, PartialEq, Deserialize)]
struct Description {
    id: String,
    max_episode_steps: usize,
    obs_low: Vec<Option<f64>>,
    obs_high: Vec<Option<f64>>,
    act_low: Vec<f64>,
    act_high: Vec<f64>,
    obs_layout: Vec<ObsPart>,
}

/// Why the host could not make the environment (its hello frame).
#[derive(Debug, Deserialize)]
struct StartFailure {
    kind: String,
    message: String,
}

/// The running Python process.
struct Host {
    child: Child,
    to: ChildStdin,
    from: ChildStdout,
}

/// A Python Gymnasium environment in its own process (see the module docs).
pub struct PythonEnv {
    spec: GymSpec,
    id: &'static str,
    obs_space: BoxSpace,
    act_space: BoxSpace,
    max_episode_steps: usize,
    obs_layout: Vec<ObsPart>,
    host: Option<Host>,
    elapsed: usize,
    request: Vec<u8>,
    response: Vec<u8>,
    obs_f64: Vec<f64>,
    restarts: u64,
}

impl PythonEnv {
    /// Start the Python process and make the environment (not reset yet).
    pub fn start(spec: GymSpec) -> Result<Self, EnvError> {
        let id: &'static str = Box::leak(format!("{GYM_PREFIX}{}", spec.target).into_boxed_str());
        let (host, d) = spawn(&spec, id)?;
        let obs_space = BoxSpace::new(
            d.obs_low
                .iter()
                .map(|v| v.map_or(f32::NEG_INFINITY, |v| v as f32))
                .collect(),
            d.obs_high
                .iter()
                .map(|v| v.map_or(f32::INFINITY, |v| v as f32))
                .collect(),
        );
        let act_space = BoxSpace::new(
            d.act_low.iter().map(|&v| v as f32).collect(),
            d.act_high.iter().map(|&v| v as f32).collect(),
        );
        let (o, a) = (obs_space.dim(), act_space.dim());
        if o == 0 || a == 0 {
            return Err(EnvError::PythonStart {
                env: id.to_string(),
                message: format!(
                    "the environment has {o} observation and {a} action values; both must be \
                     at least one"
                ),
            });
        }
        tracing::info!(
            "{id}: Python env {} up ({} observation values, {} actions, time limit {})",
            d.id,
            o,
            a,
            d.max_episode_steps
        );
        Ok(Self {
            spec,
            id,
            obs_space,
            act_space,
            max_episode_steps: d.max_episode_steps,
            obs_layout: d.obs_layout,
            host: Some(host),
            elapsed: 0,
            request: vec![0; REQUEST_HEAD + 8 * a],
            response: vec![0; RESPONSE_HEAD + 8 * o],
            obs_f64: vec![0.0; o],
            restarts: 0,
        })
    }

    /// Python processes started after the first one (each after the previous one exited).
    pub fn restarts(&self) -> u64 {
        self.restarts
    }

    /// Send one request and read the response into `self.response` / `self.obs_f64`.
    fn call(&mut self, call: &'static str) -> Result<Step, EnvError> {
        let host = self
            .host
            .as_mut()
            .ok_or_else(|| exited(self.id, call, "not running"))?;
        let sent = host.to.write_all(&self.request);
        let got = sent.and_then(|()| host.from.read_exact(&mut self.response));
        if got.is_err() {
            let status = reap(self.host.take().expect("checked above"));
            return Err(exited(self.id, call, &status));
        }
        let r = &self.response;
        let field = |at: usize| u64::from_le_bytes(r[at..at + 8].try_into().expect("8 bytes"));
        if r[0] != 0 {
            let mut traceback = vec![0; field(16) as usize];
            let host = self.host.as_mut().expect("still running");
            if host.from.read_exact(&mut traceback).is_err() {
                let status = reap(self.host.take().expect("still running"));
                return Err(exited(self.id, call, &status));
            }
            return Err(EnvError::PythonException {
                env: self.id.to_string(),
                call,
                traceback: String::from_utf8_lossy(&traceback).into_owned(),
            });
        }
        let step = Step {
            reward: f64::from_bits(field(8)),
            terminated: r[1] != 0,
            truncated: r[2] != 0,
        };
        for (i, v) in self.obs_f64.iter_mut().enumerate() {
            *v = f64::from_bits(field(RESPONSE_HEAD + 8 * i));
        }
        Ok(step)
    }

    fn write_obs(&self, obs: &mut [f32]) {
        for (o, &v) in obs.iter_mut().zip(&self.obs_f64) {
            *o = v as f32;
        }
    }
}

impl Env for PythonEnv {
    fn id(&self) -> &'static str {
        self.id
    }
    fn observation_space(&self) -> &BoxSpace {
        &self.obs_space
    }
    fn action_space(&self) -> &BoxSpace {
        &self.act_space
    }
    fn max_episode_steps(&self) -> usize {
        self.max_episode_steps
    }
    fn elapsed_steps(&self) -> usize {
        self.elapsed
    }
    fn observation_f64(&self) -> Option<&[f64]> {
        Some(&self.obs_f64)
    }
    fn observation_parts(&self) -> &[ObsPart] {
        &self.obs_layout
    }

    /// A new episode, `reset(seed=<next u64 of rng>)`; starts a new Python process first if
    /// the previous one exited (the new one must describe the same spaces).
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) -> Result<(), EnvError> {
        let seed = rng.next_u64();
        if self.host.is_none() {
            let (host, d) = spawn(&self.spec, self.id)?;
            let same =
                d.act_low.len() == self.act_space.dim() && d.obs_low.len() == self.obs_space.dim();
            if !same {
                return Err(EnvError::PythonStart {
                    env: self.id.to_string(),
                    message: "the restarted Python process describes other spaces than the \
                              first one"
                        .into(),
                });
            }
            self.host = Some(host);
            self.restarts += 1;
            tracing::warn!(
                "{}: Python process restarted ({} so far)",
                self.id,
                self.restarts
            );
        }
        self.request.fill(0);
        self.request[0] = b'r';
        self.request[1] = 1;
        self.request[8..16].copy_from_slice(&seed.to_le_bytes());
        self.call("reset")?;
        self.elapsed = 0;
        self.write_obs(obs);
        Ok(())
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<Step, EnvError> {
        self.request[0] = b's';
        for (i, &a) in action.iter().enumerate() {
            let at = REQUEST_HEAD + 8 * i;
            self.request[at..at + 8].copy_from_slice(&(a as f64).to_le_bytes());
        }
        let step = self.call("step")?;
        self.elapsed += 1;
        self.write_obs(obs);
        Ok(step)
    }
}

impl Drop for PythonEnv {
    fn drop(&mut self) {
        if let Some(mut host) = self.host.take() {
            // Ask the env to quit (it may close files or connections), then wait for it.
            self.request.fill(0);
            self.request[0] = b'q';
            let _ = host.to.write_all(&self.request);
            reap(host);
        }
    }
}

fn exited(env: &str, call: &'static str, status: &str) -> EnvError {
    EnvError::PythonExited {
        env: env.to_string(),
        call,
        status: status.to_string(),
    }
}

/// Close the host's pipe, wait up to 2 s for it to exit (killing it after that) and describe
/// how it ended.
fn reap(mut host: Host) -> String {
    drop(host.to);
    let deadline = Instant::now() + Duration::from_secs(2);
    loop {
        match host.child.try_wait() {
            Ok(Some(status)) => return status.to_string(),
            Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(5)),
            _ => {
                let _ = host.child.kill();
                let _ = host.child.wait();
                return "closed its pipe and was killed".into();
            }
        }
    }
}

/// Start the host process and read its description of the environment.
fn spawn(spec: &GymSpec, id: &'static str) -> Result<(Host, Description), EnvError> {
    let request = serde_json::json!({
        "env": spec.target,
        "kwargs": spec.kwargs,
        "max_episode_steps": spec.max_episode_steps,
    });
    let (host, body) = start_host(spec, request, id)?;
    let d: Description = serde_json::from_slice(&body).map_err(|e| EnvError::PythonStart {
        env: id.to_string(),
        message: format!("unreadable description from the host: {e}"),
    })?;
    Ok((host, d))
}

/// Start `host.py` with `request` (argv) under `spec`'s interpreter and path, and read its
/// hello: the body of a success, or the start error (naming the fix) of a failure.
fn start_host(
    spec: &GymSpec,
    request: serde_json::Value,
    id: &str,
) -> Result<(Host, Vec<u8>), EnvError> {
    let python = spec.interpreter();
    let fail = |message: String| EnvError::PythonStart {
        env: id.to_string(),
        message,
    };
    let child = spawn_host(spec, &python, &request, &fail)?;
    read_hello(child, &python, &fail)
}

/// The host process: `python -c HOST_PY request` with the config's path in PYTHONPATH, piped,
/// killed when this process dies.
fn spawn_host(
    spec: &GymSpec,
    python: &Path,
    request: &serde_json::Value,
    fail: &dyn Fn(String) -> EnvError,
) -> Result<Child, EnvError> {
    let mut search = spec.path.clone();
    search.extend(
        std::env::var_os("PYTHONPATH")
            .iter()
            .flat_map(std::env::split_paths),
    );
    let pythonpath = std::env::join_paths(&search).map_err(|e| {
        fail(format!(
            "a folder of the config's gym.path cannot be put in PYTHONPATH: {e}"
        ))
    })?;
    let mut command = Command::new(python);
    let parent = std::process::id();
    // SAFETY: runs in the child between fork and exec and calls only async-signal-safe
    // functions (prctl, getppid, _exit). A Python process whose actor died (SIGKILL included)
    // is killed too, instead of stepping on as an orphan (an env stuck in `step` never reads
    // the closed pipe).
    unsafe {
        command.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if libc::getppid() as u32 != parent {
                libc::_exit(1); // the actor died before the prctl
            }
            Ok(())
        });
    }
    command
        .env("PYTHONPATH", pythonpath)
        .arg("-c")
        .arg(HOST_PY)
        .arg(request.to_string())
        .env("PYTHONUNBUFFERED", "1")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|e| {
            fail(format!(
                "cannot start the Python interpreter {}: {e}; set `python` in the config's [gym] \
                 table or MBPO_PYTHON, or run `bash deploy/setup_python.sh` to make the project venv",
                python.display()
            ))
        })
}

/// Read the host's hello: the description's bytes, or the start failure it reports (or the
/// exit it died of), as an error that names the fix.
fn read_hello(
    mut child: Child,
    python: &Path,
    fail: &dyn Fn(String) -> EnvError,
) -> Result<(Host, Vec<u8>), EnvError> {
    let to = child.stdin.take().expect("piped");
    let mut from = child.stdout.take().expect("piped");
    let mut head = [0u8; 16];
    if from.read_exact(&mut head).is_err() {
        let status = reap(Host { child, to, from });
        return Err(fail(format!(
            "the Python process ({}) {status} before describing the environment; its error is \
             in the log above",
            python.display()
        )));
    }
    let n = u64::from_le_bytes(head[8..16].try_into().expect("8 bytes")) as usize;
    let mut body = vec![0; n];
    let read = from.read_exact(&mut body);
    let host = Host { child, to, from };
    if read.is_err() {
        let status = reap(host);
        return Err(fail(format!(
            "the Python process {status} while describing the environment"
        )));
    }
    if head[0] != 0 {
        let _ = reap(host);
        let f: StartFailure = serde_json::from_slice(&body)
            .map_err(|e| fail(format!("unreadable start failure from the host: {e}")))?;
        return Err(fail(match f.kind.as_str() {
            "import" => format!(
                "cannot import the environment's module with {}:\n{}\nInstall the package into \
                 that interpreter (`{} -m pip install ...`) or add its folder to PYTHONPATH",
                python.display(),
                f.message.trim_end(),
                python.display()
            ),
            "make" => format!("cannot make the environment:\n{}", f.message.trim_end()),
            _ => f.message,
        }));
    }
    Ok((host, body))
}

/// A termination rule written in Python (`termination = "python:module:function"`): the
/// function gets NumPy float32 arrays `obs`, `act`, `next_obs` of n rows each and returns n
/// booleans, one call per batch of model transitions. Its own process, as an env's.
pub struct PythonTermination {
    id: String,
    host: Host,
    obs_dim: usize,
    act_dim: usize,
    request: Vec<u8>,
    reply: Vec<u8>,
}

impl PythonTermination {
    /// Import `target` (`module:function`) in a new Python process of `spec`'s interpreter and
    /// path (its `target` is not used).
    pub fn start(
        target: &str,
        spec: &GymSpec,
        obs_dim: usize,
        act_dim: usize,
    ) -> Result<Self, EnvError> {
        let id = format!("python:{target}");
        let request = serde_json::json!({
            "termination": target,
            "obs_dim": obs_dim,
            "act_dim": act_dim,
        });
        let (host, _) = start_host(spec, request, &id)?;
        tracing::info!("{id}: termination rule up");
        Ok(Self {
            id,
            host,
            obs_dim,
            act_dim,
            request: Vec::new(),
            reply: Vec::new(),
        })
    }

    /// `done` of `n` transitions (row-major `obs`, `act`, `next_obs`) into `out`.
    pub fn done_batch(
        &mut self,
        obs: &[f32],
        act: &[f32],
        next_obs: &[f32],
        n: usize,
        out: &mut [bool],
    ) -> Result<(), EnvError> {
        let (o, a) = (self.obs_dim, self.act_dim);
        self.request.clear();
        self.request.extend_from_slice(&(n as u64).to_le_bytes());
        for part in [&obs[..n * o], &act[..n * a], &next_obs[..n * o]] {
            self.request
                .extend(part.iter().flat_map(|v| v.to_le_bytes()));
        }
        let exited = |status: &str| exited(&self.id, "termination", status);
        let mut head = [0u8; 16];
        let sent = self.host.to.write_all(&self.request);
        if sent
            .and_then(|()| self.host.from.read_exact(&mut head))
            .is_err()
        {
            return Err(exited("its pipe closed"));
        }
        let m = u64::from_le_bytes(head[8..16].try_into().expect("8 bytes")) as usize;
        self.reply.resize(m, 0);
        if self.host.from.read_exact(&mut self.reply).is_err() {
            return Err(exited("its pipe closed"));
        }
        if head[0] != 0 {
            return Err(EnvError::PythonException {
                env: self.id.clone(),
                call: "termination",
                traceback: String::from_utf8_lossy(&self.reply).into_owned(),
            });
        }
        for (o, &b) in out[..n].iter_mut().zip(&self.reply) {
            *o = b != 0;
        }
        Ok(())
    }
}

impl Drop for PythonTermination {
    fn drop(&mut self) {
        // A rule keeps no state worth a clean exit.
        let _ = self.host.child.kill();
        let _ = self.host.child.wait();
    }
}
