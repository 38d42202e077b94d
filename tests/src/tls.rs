//! A farm over TLS with access control, for the tests that need one: its folder from
//! `certs init`, its tokens, channels that trust its CA (presenting a worker
//! certificate or not), and workers that join it with their certificates.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use tonic::transport::{Certificate, Channel, ClientTlsConfig, Endpoint, Identity};

use crate::{Coordinator, Proc, bin, run};

/// `coordinator certs init DIR EXTRA…`, which must succeed.
pub fn certs_init(dir: &Path, extra: &[&str]) {
    let out =
        run(Command::new(bin("coordinator")).args(["certs", "init"]).arg(dir).args(extra), Duration::from_secs(60));
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// The token of `name` (`NAME.token` in the farm's folder).
pub fn token(tls: &Path, name: &str) -> String {
    std::fs::read_to_string(tls.join(format!("{name}.token"))).unwrap().trim().to_string()
}

/// A channel to `url` trusting the CA in `tls`, presenting worker certificate `cert`
/// (`NAME` of `NAME.pem`/`NAME.key` there) if given.
pub async fn channel(url: &str, tls: &Path, cert: Option<&str>) -> Result<Channel, tonic::transport::Error> {
    let ca = Certificate::from_pem(std::fs::read(tls.join("ca.pem")).unwrap());
    let mut config = ClientTlsConfig::new().ca_certificate(ca).domain_name("tilefarm-coordinator");
    if let Some(name) = cert {
        let pem = std::fs::read(tls.join(format!("{name}.pem"))).unwrap();
        let key = std::fs::read(tls.join(format!("{name}.key"))).unwrap();
        config = config.identity(Identity::from_pem(pem, key));
    }
    Endpoint::from_shared(url.to_string()).unwrap().tls_config(config).unwrap().connect().await
}

/// `request` bearing `token`.
pub fn bearer<T>(mut request: tonic::Request<T>, token: &str) -> tonic::Request<T> {
    request.metadata_mut().insert("authorization", format!("Bearer {token}").parse().unwrap());
    request
}

/// A one-thread worker joining `coord` with certificate `name` of `tls`.
pub fn worker(coord: &Coordinator, tls: &Path, name: &str, cache: &Path) -> Proc {
    let mut cmd = Command::new(bin("worker"));
    cmd.args(["--coordinator", &coord.url, "--threads", "1", "--tls"])
        .arg(tls)
        .args(["--tls-name", name, "--cache"])
        .arg(cache)
        .stdin(Stdio::null());
    Proc::spawn("worker", &mut cmd)
}

/// A worker's registration as a hand-written client sends it.
pub fn register_request(hostname: &str) -> proto::RegisterRequest {
    proto::RegisterRequest {
        protocol_version: proto::PROTOCOL_VERSION,
        threads: 1,
        hostname: hostname.into(),
        version: "0".into(),
    }
}
