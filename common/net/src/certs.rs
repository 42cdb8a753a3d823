//! `mbpo certs --out DIR`: the credentials of one run (or one cluster): a fresh certificate
//! authority, a certificate for the head and one for the workers signed by it, and a random
//! user/password.
//!
//! ```text
//! DIR/head/    ca.pem cert.pem key.pem password    -> mbpo run --listen tls/... --credentials DIR/head
//! DIR/worker/  ca.pem cert.pem key.pem password    -> mbpo join tls/...   --credentials DIR/worker
//! ```
//!
//! With a `tls/` endpoint both sides prove they hold a certificate of this CA (mutual TLS) and
//! the traffic is encrypted; with `tcp/` the password alone admits peers. The CA's private key
//! is not kept: a new worker host gets a copy of `DIR/worker`, and new credentials mean a new
//! `mbpo certs`. Keys and the password are written readable by their owner only.

use std::io::Read;
use std::path::Path;

use rcgen::{BasicConstraints, CertificateParams, DnType, IsCa, Issuer, KeyPair, KeyUsagePurpose};

use crate::GatewayError;

fn failed(what: &str, e: impl std::fmt::Display) -> GatewayError {
    GatewayError::Failed(format!("making credentials: {what}: {e}"))
}

fn write(path: &Path, text: &str, private: bool) -> Result<(), GatewayError> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let io = |source| GatewayError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mode = if private { 0o600 } else { 0o644 };
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(mode)
        .open(path)
        .map_err(io)?;
    f.write_all(text.as_bytes()).map_err(io)
}

/// A random hex string of `bytes` bytes from the kernel.
fn random_hex(bytes: usize) -> Result<String, GatewayError> {
    let mut buf = vec![0u8; bytes];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| f.read_exact(&mut buf))
        .map_err(|e| failed("reading /dev/urandom", e))?;
    Ok(buf.iter().map(|b| format!("{b:02x}")).collect())
}

/// Make `out/head` and `out/worker` (see the module doc). `out` must not hold them yet.
pub fn make_credentials(out: &Path) -> Result<(), GatewayError> {
    for part in ["head", "worker"] {
        let dir = out.join(part);
        if dir.exists() {
            return Err(GatewayError::Failed(format!(
                "{} exists: credentials are never overwritten (remove it, or choose another --out)",
                dir.display()
            )));
        }
    }
    let ca_key = KeyPair::generate().map_err(|e| failed("CA key", e))?;
    let mut ca_params =
        CertificateParams::new(Vec::<String>::new()).map_err(|e| failed("CA", e))?;
    ca_params
        .distinguished_name
        .push(DnType::CommonName, "mbpo run CA");
    ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    ca_params.key_usages = vec![
        KeyUsagePurpose::KeyCertSign,
        KeyUsagePurpose::CrlSign,
        KeyUsagePurpose::DigitalSignature,
    ];
    let ca_cert = ca_params
        .self_signed(&ca_key)
        .map_err(|e| failed("CA certificate", e))?;
    let issuer = Issuer::new(ca_params, ca_key);
    let password = format!("mbpo:{}", random_hex(24)?);
    for part in ["head", "worker"] {
        let key = KeyPair::generate().map_err(|e| failed("key", e))?;
        let mut params = CertificateParams::new(vec![format!("mbpo-{part}")])
            .map_err(|e| failed("certificate", e))?;
        params
            .distinguished_name
            .push(DnType::CommonName, format!("mbpo {part}"));
        let cert = params
            .signed_by(&key, &issuer)
            .map_err(|e| failed("signing", e))?;
        let dir = out.join(part);
        std::fs::create_dir_all(&dir).map_err(|source| GatewayError::Io {
            path: dir.clone(),
            source,
        })?;
        write(&dir.join("ca.pem"), &ca_cert.pem(), false)?;
        write(&dir.join("cert.pem"), &cert.pem(), false)?;
        write(&dir.join("key.pem"), &key.serialize_pem(), true)?;
        write(&dir.join("password"), &format!("{password}\n"), true)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use zenoh::Wait;

    use super::*;
    use crate::session::{open, NetOptions, Side};

    fn scratch(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("mbpo-certs-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    /// A message from `worker` reaches `head` over `endpoint` within 10 s.
    fn talks(endpoint: &str, head: &Path, worker: &Path) -> bool {
        let h = open(
            Side::Head,
            &NetOptions {
                endpoint: endpoint.into(),
                credentials: Some(head.to_path_buf()),
            },
        )
        .unwrap();
        let sub = h.declare_subscriber("mbpo/test").wait().unwrap();
        let w = open(
            Side::Worker,
            &NetOptions {
                endpoint: endpoint.into(),
                credentials: Some(worker.to_path_buf()),
            },
        )
        .unwrap();
        let t = std::time::Instant::now();
        while t.elapsed() < Duration::from_secs(10) {
            w.put("mbpo/test", "hello").wait().unwrap();
            if let Ok(Some(_)) = sub.recv_timeout(Duration::from_millis(200)) {
                return true;
            }
        }
        false
    }

    /// Mutual TLS on loopback: a worker with the run's credentials gets through, one with
    /// another run's does not; the files are private where they must be, never overwritten.
    #[test]
    fn the_runs_certificates_admit_its_workers_only() {
        let (a, b) = (scratch("a"), scratch("b"));
        make_credentials(&a).unwrap();
        make_credentials(&b).unwrap();
        assert!(make_credentials(&a).is_err(), "overwrote credentials");
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(a.join("worker/key.pem"))
            .unwrap()
            .permissions()
            .mode();
        assert_eq!(mode & 0o077, 0, "key readable by others: {mode:o}");
        assert!(talks(
            "tls/127.0.0.1:17461",
            &a.join("head"),
            &a.join("worker")
        ));
        assert!(
            !talks("tls/127.0.0.1:17462", &a.join("head"), &b.join("worker")),
            "a worker of another CA got through"
        );
        // tcp with the password only: the right one passes, a wrong one does not.
        assert!(talks(
            "tcp/127.0.0.1:17463",
            &a.join("head"),
            &a.join("worker")
        ));
        let pw_only = scratch("pw");
        std::fs::create_dir_all(&pw_only).unwrap();
        std::fs::write(pw_only.join("password"), "mbpo:wrong\n").unwrap();
        assert!(!talks("tcp/127.0.0.1:17464", &a.join("head"), &pw_only));
        for d in [a, b, pw_only] {
            let _ = std::fs::remove_dir_all(d);
        }
    }
}
