//! Two "hosts" on one machine for the multi-host tests: two network namespaces joined by a veth
//! pair with addresses of the test's own (10.77.<n>.1 and 10.77.<n>.2), each process started
//! in one with a private tmpfs on /dev/shm, so the hosts share nothing but the link. Nothing is
//! sent to any other address. Needs root and iproute2 (`ip`); [`TwoHosts::create`] says
//! plainly why it cannot make them otherwise.

use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU8, Ordering};

/// One namespace.
#[derive(Debug, Clone)]
pub struct Host {
    /// The namespace's name.
    pub ns: String,
    /// Its address on the link.
    pub addr: String,
    /// Its end of the veth pair.
    pub veth: String,
}

/// Two namespaces joined by a veth pair; removed on drop.
#[derive(Debug)]
pub struct TwoHosts {
    /// Where the head runs.
    pub head: Host,
    /// Where a worker runs.
    pub worker: Host,
}

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("running `ip`: {e} (install iproute2)"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "`ip {}` failed: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

static NEXT: AtomicU8 = AtomicU8::new(0);

impl TwoHosts {
    /// Two fresh namespaces, or why they cannot be made here (not root, no `ip`).
    pub fn create() -> Result<TwoHosts, String> {
        // SAFETY: geteuid has no preconditions.
        if unsafe { libc::geteuid() } != 0 {
            return Err("network namespaces need root".into());
        }
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let pid = std::process::id() % 10_000;
        let tag = format!("mb{pid}x{n}");
        let subnet = 100 + (pid % 100) as u16 + u16::from(n); // distinct per process and pair
        let subnet = subnet % 250;
        let head = Host {
            ns: format!("{tag}h"),
            addr: format!("10.77.{subnet}.1"),
            veth: format!("{tag}vh"),
        };
        let worker = Host {
            ns: format!("{tag}w"),
            addr: format!("10.77.{subnet}.2"),
            veth: format!("{tag}vw"),
        };
        let hosts = TwoHosts { head, worker };
        hosts.setup()?;
        Ok(hosts)
    }

    fn setup(&self) -> Result<(), String> {
        let (h, w) = (&self.head, &self.worker);
        ip(&["netns", "add", &h.ns])?;
        ip(&["netns", "add", &w.ns])?;
        ip(&[
            "link", "add", &h.veth, "type", "veth", "peer", "name", &w.veth,
        ])?;
        for host in [h, w] {
            ip(&["link", "set", &host.veth, "netns", &host.ns])?;
            ip(&[
                "-n",
                &host.ns,
                "addr",
                "add",
                &format!("{}/24", host.addr),
                "dev",
                &host.veth,
            ])?;
            ip(&["-n", &host.ns, "link", "set", &host.veth, "up"])?;
            ip(&["-n", &host.ns, "link", "set", "lo", "up"])?;
        }
        Ok(())
    }

    /// `program args` inside `host`'s namespace with a private /dev/shm.
    pub fn command(&self, host: &Host, program: &Path, args: &[&str]) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", &host.ns, "sh", "-c"])
            .arg("mount -t tmpfs -o size=1g mbpo-shm /dev/shm && exec \"$0\" \"$@\"")
            .arg(program)
            .args(args)
            .stdin(Stdio::null());
        c
    }

    /// Take the link down (`false`) or up again: the worker's end.
    pub fn set_link(&self, up: bool) {
        let state = if up { "up" } else { "down" };
        ip(&[
            "-n",
            &self.worker.ns,
            "link",
            "set",
            &self.worker.veth,
            state,
        ])
        .expect("setting the link");
    }
}

impl Drop for TwoHosts {
    fn drop(&mut self) {
        // Deleting a namespace deletes its end of the veth pair, and so the pair. It fails
        // ("busy") while processes just killed are still leaving the namespace's mounts: try
        // for up to 5 s.
        for ns in [&self.head.ns, &self.worker.ns] {
            for _ in 0..50 {
                if ip(&["netns", "del", ns]).is_ok() {
                    break;
                }
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
        }
    }
}
