//! The Zenoh session of a host's gateway: where it listens or connects, with which credentials,
//! and the keys the two sides talk on.
//!
//! * Head: a Zenoh peer listening on `--listen` (loopback by default). Workers: Zenoh peers
//!   that listen nowhere and connect to it, retrying for ever (a worker may start before the
//!   head, and a head that restarts comes back on the same address). Multicast scouting and gossip are off: a
//!   gateway talks to the endpoints it was given and nothing else.
//! * Keys: a worker publishes on `mbpo/net/w2h/<worker session>` and the head on
//!   `mbpo/net/h2w/<worker session>`; the head subscribes to `mbpo/net/w2h/*`.
//! * Credentials (`--credentials DIR`, made by `mbpo certs`): `ca.pem`, `cert.pem`, `key.pem`
//!   for TLS with mutual authentication (`tls/<addr>:<port>` endpoints; a peer must hold a
//!   certificate of the run's CA), and `password` (`user:password`) for Zenoh's user/password
//!   authentication on any endpoint. A head listening on anything but loopback without them is
//!   refused: the run's data and weights would be open to anyone who can reach the port.

use std::net::IpAddr;
use std::path::{Path, PathBuf};

use zenoh::Wait;

/// Where a gateway listens or connects, and what proves it belongs to the run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NetOptions {
    /// A Zenoh endpoint: `tcp/<addr>:<port>` or `tls/<addr>:<port>`.
    pub endpoint: String,
    /// A directory made by `mbpo certs` (the head's or a worker's), if any.
    pub credentials: Option<PathBuf>,
}

/// The default port of a head.
pub const DEFAULT_PORT: u16 = 7447;

/// Why a gateway cannot open its session.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The endpoint is not `tcp/...` or `tls/...` with an address and port.
    #[error("endpoint `{endpoint}`: {problem} (expected tcp/<address>:<port> or tls/<address>:<port>, e.g. tcp/127.0.0.1:{DEFAULT_PORT})")]
    Endpoint {
        /// As given.
        endpoint: String,
        /// What is wrong.
        problem: String,
    },
    /// Listening beyond this host without credentials.
    #[error("listening on {endpoint} opens the run to every host that can reach it: give credentials (make them with `mbpo certs --out DIR`, then `--credentials DIR/head` here and `--credentials DIR/worker` on each worker), or listen on 127.0.0.1")]
    Unprotected {
        /// As given.
        endpoint: String,
    },
    /// A credentials file is missing or unreadable.
    #[error(
        "credentials: {path}: {problem} (make a credentials directory with `mbpo certs --out DIR`)"
    )]
    Credentials {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        problem: String,
    },
    /// Zenoh refused the configuration or could not open the session.
    #[error("zenoh: {0}")]
    Zenoh(String),
}

/// The address part of `endpoint` after checking its form.
fn endpoint_host(endpoint: &str) -> Result<(bool, String), SessionError> {
    let bad = |problem: &str| SessionError::Endpoint {
        endpoint: endpoint.to_string(),
        problem: problem.to_string(),
    };
    let (tls, rest) = if let Some(r) = endpoint.strip_prefix("tcp/") {
        (false, r)
    } else if let Some(r) = endpoint.strip_prefix("tls/") {
        (true, r)
    } else {
        return Err(bad("unknown protocol"));
    };
    let rest = rest.split('#').next().unwrap_or(rest);
    let (host, port) = rest.rsplit_once(':').ok_or_else(|| bad("no port"))?;
    port.parse::<u16>()
        .map_err(|_| bad("the port is not a number 0..65535"))?;
    let host = host.trim_start_matches('[').trim_end_matches(']');
    if host.is_empty() {
        return Err(bad("no address"));
    }
    Ok((tls, host.to_string()))
}

/// True when `host` names this host only (loopback).
fn is_loopback(host: &str) -> bool {
    host == "localhost" || host.parse::<IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

/// A credentials directory's files.
#[derive(Debug, Clone)]
struct Credentials {
    tls: Option<(PathBuf, PathBuf, PathBuf)>,
    user_password: Option<(String, String, PathBuf)>,
}

fn read_credentials(dir: &Path, need_tls: bool) -> Result<Credentials, SessionError> {
    let file = |name: &str| dir.join(name);
    let exists = |p: &Path| p.is_file();
    let (ca, cert, key) = (file("ca.pem"), file("cert.pem"), file("key.pem"));
    let tls = if exists(&ca) && exists(&cert) && exists(&key) {
        Some((ca, cert, key))
    } else if need_tls {
        let missing = [&ca, &cert, &key]
            .into_iter()
            .find(|p| !exists(p))
            .expect("one is missing");
        return Err(SessionError::Credentials {
            path: missing.clone(),
            problem: "missing; a tls/ endpoint needs ca.pem, cert.pem and key.pem".into(),
        });
    } else {
        None
    };
    let pw = file("password");
    let user_password = if exists(&pw) {
        let text = std::fs::read_to_string(&pw).map_err(|e| SessionError::Credentials {
            path: pw.clone(),
            problem: e.to_string(),
        })?;
        let line = text.lines().next().unwrap_or("").trim();
        let (user, password) = line
            .split_once(':')
            .filter(|(u, p)| !u.is_empty() && !p.is_empty())
            .ok_or_else(|| SessionError::Credentials {
                path: pw.clone(),
                problem: "expected one line `user:password`".into(),
            })?;
        Some((user.to_string(), password.to_string(), pw))
    } else {
        None
    };
    if tls.is_none() && user_password.is_none() {
        return Err(SessionError::Credentials {
            path: dir.to_path_buf(),
            problem: "holds neither ca.pem/cert.pem/key.pem nor password".into(),
        });
    }
    Ok(Credentials { tls, user_password })
}

fn set(c: &mut zenoh::Config, key: &str, json5: &str) -> Result<(), SessionError> {
    c.insert_json5(key, json5)
        .map_err(|e| SessionError::Zenoh(format!("setting {key} = {json5}: {e}")))
}

fn quoted(p: &Path) -> String {
    serde_json_string(&p.display().to_string())
}

fn serde_json_string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for ch in s.chars() {
        match ch {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// Which side of the link a session is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// The head: listens.
    Head,
    /// A worker: connects.
    Worker,
}

/// The Zenoh configuration of `side` for `opts` (checked: endpoint form, credentials, a head
/// beyond loopback only with credentials).
pub fn zenoh_config(side: Side, opts: &NetOptions) -> Result<zenoh::Config, SessionError> {
    let (tls, host) = endpoint_host(&opts.endpoint)?;
    let creds = match &opts.credentials {
        Some(dir) => Some(read_credentials(dir, tls)?),
        None if tls => {
            return Err(SessionError::Credentials {
                path: PathBuf::from("--credentials"),
                problem: format!(
                    "{} is a TLS endpoint but no credentials were given",
                    opts.endpoint
                ),
            })
        }
        None => None,
    };
    if side == Side::Head && creds.is_none() && !is_loopback(&host) {
        return Err(SessionError::Unprotected {
            endpoint: opts.endpoint.clone(),
        });
    }
    let mut c = zenoh::Config::default();
    set(&mut c, "scouting/multicast/enabled", "false")?;
    set(&mut c, "scouting/gossip/enabled", "false")?;
    // Links are watched by our own heartbeats; Zenoh's lease only closes dead sessions.
    let endpoint = serde_json_string(&opts.endpoint);
    match side {
        Side::Head => {
            set(&mut c, "mode", "\"peer\"")?;
            set(&mut c, "listen/endpoints", &format!("[{endpoint}]"))?;
        }
        Side::Worker => {
            // A peer that listens nowhere and connects to the head only. (A Zenoh client
            // would block in `open` until the head is up; a peer opens at once and connects
            // in the background, retrying: the head may start later, or restart.)
            set(&mut c, "mode", "\"peer\"")?;
            set(&mut c, "listen/endpoints", "[]")?;
            set(&mut c, "connect/endpoints", &format!("[{endpoint}]"))?;
            set(&mut c, "connect/timeout_ms", "-1")?;
            set(&mut c, "connect/exit_on_failure", "false")?;
        }
    }
    if let Some(creds) = creds {
        set_credentials(&mut c, side, &creds)?;
    }
    Ok(c)
}

/// The credentials' part of the Zenoh configuration of `side`: mutual TLS (the run's CA, this
/// side's certificate and key) and the user and password (the head checks them against its
/// dictionary file).
fn set_credentials(
    c: &mut zenoh::Config,
    side: Side,
    creds: &Credentials,
) -> Result<(), SessionError> {
    if let Some((ca, cert, key)) = &creds.tls {
        set(c, "transport/link/tls/root_ca_certificate", &quoted(ca))?;
        set(c, "transport/link/tls/enable_mtls", "true")?;
        // The certificates belong to the run, not to host names: a peer is checked by the CA
        // that signed it.
        set(c, "transport/link/tls/verify_name_on_connect", "false")?;
        let end = match side {
            Side::Head => "listen",
            Side::Worker => "connect",
        };
        set(
            c,
            &format!("transport/link/tls/{end}_private_key"),
            &quoted(key),
        )?;
        set(
            c,
            &format!("transport/link/tls/{end}_certificate"),
            &quoted(cert),
        )?;
    }
    if let Some((user, password, file)) = &creds.user_password {
        set(c, "transport/auth/usrpwd/user", &serde_json_string(user))?;
        set(
            c,
            "transport/auth/usrpwd/password",
            &serde_json_string(password),
        )?;
        if side == Side::Head {
            set(c, "transport/auth/usrpwd/dictionary_file", &quoted(file))?;
        }
    }
    Ok(())
}

/// Open the Zenoh session of `side`.
pub fn open(side: Side, opts: &NetOptions) -> Result<zenoh::Session, SessionError> {
    let config = zenoh_config(side, opts)?;
    zenoh::open(config)
        .wait()
        .map_err(|e| SessionError::Zenoh(format!("opening a session on {}: {e}", opts.endpoint)))
}

/// The key a worker with session `worker` publishes on.
pub fn worker_to_head(worker: u64) -> String {
    format!("mbpo/net/w2h/{worker:016x}")
}

/// The key the head answers worker `worker` on.
pub fn head_to_worker(worker: u64) -> String {
    format!("mbpo/net/h2w/{worker:016x}")
}

/// What the head subscribes to: every worker's key.
pub const FROM_ANY_WORKER: &str = "mbpo/net/w2h/*";

/// A random session id (a new one for every gateway process).
pub fn new_session_id() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    h.write_u32(std::process::id());
    h.finish() | 1
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts(endpoint: &str, credentials: Option<&Path>) -> NetOptions {
        NetOptions {
            endpoint: endpoint.into(),
            credentials: credentials.map(Path::to_path_buf),
        }
    }

    #[test]
    fn endpoints_are_checked_and_named_in_errors() {
        for bad in [
            "udp/1.2.3.4:7447",
            "tcp/1.2.3.4",
            "tcp/:7447",
            "tcp/1.2.3.4:99999",
        ] {
            let e = zenoh_config(Side::Worker, &opts(bad, None)).unwrap_err();
            assert!(e.to_string().contains(bad), "{e}");
        }
        assert!(zenoh_config(Side::Head, &opts("tcp/127.0.0.1:7447", None)).is_ok());
        assert!(zenoh_config(Side::Head, &opts("tcp/[::1]:7447", None)).is_ok());
        assert!(zenoh_config(Side::Worker, &opts("tcp/10.77.0.1:7447", None)).is_ok());
    }

    #[test]
    fn a_head_beyond_loopback_needs_credentials() {
        let e = zenoh_config(Side::Head, &opts("tcp/10.77.0.1:7447", None)).unwrap_err();
        assert!(matches!(e, SessionError::Unprotected { .. }));
        assert!(e.to_string().contains("mbpo certs"), "{e}");
        let e = zenoh_config(Side::Head, &opts("tls/127.0.0.1:7447", None)).unwrap_err();
        assert!(e.to_string().contains("no credentials"), "{e}");
    }

    #[test]
    fn a_password_file_is_read_and_checked() {
        let dir = std::env::temp_dir().join(format!("mbpo-net-cred-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let e = zenoh_config(Side::Head, &opts("tcp/10.77.0.1:7447", Some(&dir))).unwrap_err();
        assert!(e.to_string().contains("neither"), "{e}");
        std::fs::write(dir.join("password"), "no-colon\n").unwrap();
        let e = zenoh_config(Side::Head, &opts("tcp/10.77.0.1:7447", Some(&dir))).unwrap_err();
        assert!(e.to_string().contains("user:password"), "{e}");
        std::fs::write(dir.join("password"), "mbpo:s3cret\n").unwrap();
        assert!(zenoh_config(Side::Head, &opts("tcp/10.77.0.1:7447", Some(&dir))).is_ok());
        let e = zenoh_config(Side::Head, &opts("tls/10.77.0.1:7447", Some(&dir))).unwrap_err();
        assert!(e.to_string().contains("ca.pem"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
