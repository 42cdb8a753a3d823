//! Scheduling of a paced run (`actor.control_hz`, `actor.realtime_priority`): a paced actor
//! takes SCHED_FIFO at a modest priority and a core of its own, so nothing on the default
//! scheduler -- the learning roles, anything else on the machine -- delays its steps: a
//! runnable SCHED_FIFO thread always runs first. The environment's own process (a Python env's
//! host) is started after it and inherits both. The learning roles stay on the default
//! scheduler, below it.
//!
//! Linux applies a policy to the calling thread and to the threads and processes it starts
//! afterwards, so the actor calls this first, before it makes its environment. Where the system
//! refuses (not root and no CAP_SYS_NICE, RLIMIT_RTPRIO below the priority) the actor says so
//! once in its log, with the fix, and runs on as it was.

/// What a role got.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Scheduling {
    /// SCHED_FIFO at `priority`, pinned to `cpu` (`None`: the system refused the pinning).
    RealTime {
        /// Its priority.
        priority: u32,
        /// The core it runs on.
        cpu: Option<usize>,
    },
    /// The default scheduler: not asked for, or refused (`why`, with the fix).
    Default {
        /// Why not real time (empty when not asked for).
        why: String,
    },
}

/// Make the calling thread a paced actor's: SCHED_FIFO at `priority` on core `cpu` (0: the
/// default scheduler, nothing changed).
pub fn paced_actor(priority: u32, cpu: usize) -> Scheduling {
    if priority == 0 {
        return Scheduling::Default { why: String::new() };
    }
    let param = libc::sched_param {
        sched_priority: priority as i32,
    };
    // SAFETY: sched_setscheduler reads the param; pid 0 is the calling thread.
    if unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) } != 0 {
        let err = std::io::Error::last_os_error();
        return Scheduling::Default {
            why: refusal(priority, &err),
        };
    }
    Scheduling::RealTime {
        priority,
        cpu: pin(cpu).then_some(cpu),
    }
}

/// Whether the actors of a run with `cfg` in `mode` run under SCHED_FIFO on cores of their own:
/// paced (`actor.control_hz`), pipelined, and `actor.realtime_priority` above 0.
pub fn actors_run_real_time(cfg: &mbpo_train::ExperimentConfig, mode: crate::Mode) -> bool {
    let a = &cfg.actor;
    a.control_hz > 0.0 && mode == crate::Mode::Pipelined && a.realtime_priority > 0
}

/// The core a launcher pins the `i`-th of its pinned processes to, keeping off the cores of the
/// run's `real_time_actors` (actor k's is [`actor_cpu`]`(k)`) while any other core is left.
pub fn launcher_cpu(i: usize, real_time_actors: u16) -> usize {
    let n = online_cores();
    let taken: Vec<usize> = (0..real_time_actors).map(actor_cpu).collect();
    let free: Vec<usize> = (0..n).filter(|c| !taken.contains(c)).collect();
    match free.is_empty() {
        true => i % n,
        false => free[i % free.len()],
    }
}

/// The machine's online cores (not this process's affinity).
fn online_cores() -> usize {
    // SAFETY: sysconf reads a system value.
    let online = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
    usize::try_from(online).unwrap_or(1).max(1)
}

/// The core actor `index` of a run paces on: the last cores first (the first ones keep the
/// supervisor and the learning roles' first threads). Counted over the machine's online cores,
/// not this process's affinity: the launcher may have pinned the process to one core already
/// (a Python env's roles), and the actor then moves to its own.
pub fn actor_cpu(index: u16) -> usize {
    let n = online_cores();
    n - 1 - usize::from(index) % n
}

/// Pin the calling thread to `cpu`; false if refused.
fn pin(cpu: usize) -> bool {
    // SAFETY: a zeroed cpu_set_t is the empty set; CPU_SET writes within it (cpu is below the
    // core count, far below CPU_SETSIZE); sched_setaffinity reads it.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0
    }
}

/// Why SCHED_FIFO at `priority` was refused, and what to do.
fn refusal(priority: u32, err: &std::io::Error) -> String {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes the struct it is given.
    unsafe { libc::getrlimit(libc::RLIMIT_RTPRIO, &mut limit) };
    format!(
        "SCHED_FIFO priority {priority} refused ({err}; RLIMIT_RTPRIO {}): this actor runs on the default scheduler, so the learning roles can delay its steps. Fix: run as root, or `sudo setcap cap_sys_nice+ep <the mbpo-actor binary>`, or allow real-time priorities to your user (`@realtime - rtprio 99` in /etc/security/limits.conf), or set actor.realtime_priority = 0 to silence this",
        limit.rlim_cur
    )
}

impl std::fmt::Display for Scheduling {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Scheduling::RealTime { priority, cpu } => {
                write!(f, "SCHED_FIFO priority {priority}")?;
                match cpu {
                    Some(c) => write!(f, " on CPU {c}"),
                    None => write!(f, " (pinning refused)"),
                }
            }
            Scheduling::Default { .. } => f.write_str("the default scheduler"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a thread of its own (the policy stays with it): as root the thread gets SCHED_FIFO
    /// and its core; without the right the refusal names the fix. Priority 0 changes nothing.
    #[test]
    fn a_paced_actor_gets_real_time_or_says_why_not() {
        let got = std::thread::spawn(|| {
            let s = paced_actor(5, actor_cpu(0));
            // SAFETY: sched_getscheduler of the calling thread.
            let policy = unsafe { libc::sched_getscheduler(0) };
            (s, policy)
        })
        .join()
        .unwrap();
        match got {
            (Scheduling::RealTime { priority: 5, cpu }, policy) => {
                assert_eq!(policy, libc::SCHED_FIFO);
                assert_eq!(cpu, Some(actor_cpu(0)));
            }
            (Scheduling::Default { why }, policy) => {
                assert_ne!(policy, libc::SCHED_FIFO);
                assert!(why.contains("refused") && why.contains("setcap"), "{why}");
            }
            other => panic!("{other:?}"),
        }
        // A process already pinned to one core still counts the machine's cores.
        let cores = online_cores();
        assert_eq!(actor_cpu(0), cores - 1);
        assert_eq!(actor_cpu(cores as u16), cores - 1);
        // The launcher keeps other processes off a real-time actor's core while it can.
        if cores > 1 {
            assert!((0..2 * cores).all(|i| launcher_cpu(i, 1) != actor_cpu(0)));
        }
        assert!((0..2 * cores).all(|i| launcher_cpu(i, cores as u16) < cores));
        let off = std::thread::spawn(|| paced_actor(0, 0)).join().unwrap();
        assert_eq!(off, Scheduling::Default { why: String::new() });
    }
}
