//! A farm's TLS folder, as `coordinator certs init DIR` writes it, and the rustls
//! configurations (through tonic) each side builds from it:
//!
//! - the coordinator: its certificate, and the CA that worker certificates must chain
//!   to (mTLS; a client without a certificate may still connect, with a token);
//! - a worker: the CA to trust, and its own certificate and key;
//! - a user's client: the CA to trust (and a token, from elsewhere).
//!
//! Every certificate the farm's CA signs for the coordinator carries [`SERVER_NAME`], and
//! clients check that name, so a farm can be reached by any address (an IP, a tunnel)
//! without re-issuing certificates; worker certificates are for client authentication
//! only, so one cannot pose as the coordinator.

use std::path::PathBuf;

use tonic::transport::{Certificate, ClientTlsConfig, Identity, ServerTlsConfig};

use crate::auth::{Access, Caller, Role, Token};

/// The name clients verify in the coordinator's certificate.
pub const SERVER_NAME: &str = "tilefarm-coordinator";
pub const CA_CERT: &str = "ca.pem";
pub const CA_KEY: &str = "ca.key";
pub const SERVER_CERT: &str = "server.pem";
pub const SERVER_KEY: &str = "server.key";
/// A worker's certificate and key are `<name>.pem` and `<name>.key`; this is the name
/// `worker --tls DIR` uses unless told another.
pub const WORKER: &str = "worker";
/// The token file whose bearer is an admin; every other `<name>.token` is user `<name>`.
pub const ADMIN_TOKEN: &str = "admin.token";
/// Largest certificate or key file read.
const MAX_PEM_BYTES: u64 = 1 << 20;
/// Most token files a folder may hold.
const MAX_TOKENS: usize = 10_000;

/// A farm's TLS folder.
#[derive(Clone, Debug)]
pub struct TlsDir(PathBuf);

impl TlsDir {
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self(dir.into())
    }

    fn read(&self, name: &str) -> Result<Vec<u8>, String> {
        let path = self.0.join(name);
        let meta = std::fs::metadata(&path)
            .map_err(|e| format!("{}: {e} (made by `coordinator certs init`)", path.display()))?;
        if !meta.is_file() || meta.len() > MAX_PEM_BYTES {
            return Err(format!("{}: not a certificate or key file", path.display()));
        }
        std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))
    }

    fn ca(&self) -> Result<Certificate, String> {
        Ok(Certificate::from_pem(self.read(CA_CERT)?))
    }

    /// The coordinator's side: its certificate, and worker certificates checked
    /// against the CA (optional, so that users can connect with a token alone).
    pub fn server(&self) -> Result<ServerTlsConfig, String> {
        let identity = Identity::from_pem(self.read(SERVER_CERT)?, self.read(SERVER_KEY)?);
        Ok(ServerTlsConfig::new().identity(identity).client_ca_root(self.ca()?).client_auth_optional(true))
    }

    /// A worker's side: the CA, and the certificate `name` (`<name>.pem`, `<name>.key`).
    pub fn worker(&self, name: &str) -> Result<ClientTlsConfig, String> {
        let identity = Identity::from_pem(self.read(&format!("{name}.pem"))?, self.read(&format!("{name}.key"))?);
        Ok(self.client()?.identity(identity))
    }

    /// A user's side: the CA only.
    pub fn client(&self) -> Result<ClientTlsConfig, String> {
        Ok(ClientTlsConfig::new().ca_certificate(self.ca()?).domain_name(SERVER_NAME))
    }

    /// The farm's access rules: worker certificates, `admin.token` as admin and every
    /// other `<name>.token` as user `<name>`.
    pub fn access(&self) -> Result<Access, String> {
        let mut access = Access::default().with_worker_certificates();
        let entries = std::fs::read_dir(&self.0).map_err(|e| format!("{}: {e}", self.0.display()))?;
        let mut names: Vec<String> = entries
            .filter_map(|e| e.ok())
            .filter_map(|e| e.file_name().into_string().ok())
            .filter(|n| n.ends_with(".token"))
            .take(MAX_TOKENS + 1)
            .collect();
        if names.len() > MAX_TOKENS {
            return Err(format!("{}: more than {MAX_TOKENS} token files", self.0.display()));
        }
        names.sort();
        for name in names {
            let token = Token::from_file(&self.0.join(&name))?;
            let caller = if name == ADMIN_TOKEN {
                Caller::admin()
            } else {
                Caller { role: Role::User, name: name.trim_end_matches(".token").to_string() }
            };
            access = access.with_token(token, caller);
        }
        Ok(access)
    }
}

/// The URL to reach `address` at: `https://` with TLS, `http://` without (when no
/// scheme is given); a scheme that contradicts the choice is an error.
pub fn url(address: &str, tls: bool) -> Result<String, String> {
    let a = address.trim();
    match (a.split_once("://").map(|(s, _)| s), tls) {
        (None, false) => Ok(format!("http://{a}")),
        (None, true) => Ok(format!("https://{a}")),
        (Some("http"), false) | (Some("https"), true) => Ok(a.to_string()),
        (Some("https"), false) => Err(format!("{a}: an https:// farm needs --tls DIR (its CA)")),
        (Some("http"), true) => {
            Err(format!("{a}: --tls was given, so the address must be https:// (or have no scheme)"))
        }
        (Some(s), _) => Err(format!("{a}: unknown scheme {s}://")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_get_the_scheme_tls_calls_for() {
        assert_eq!(url("10.0.0.5:7878", false).unwrap(), "http://10.0.0.5:7878");
        assert_eq!(url("10.0.0.5:7878", true).unwrap(), "https://10.0.0.5:7878");
        assert_eq!(url("https://h:1", true).unwrap(), "https://h:1");
        assert!(url("http://h:1", true).is_err());
        assert!(url("https://h:1", false).is_err());
        assert!(url("ftp://h:1", false).is_err());
    }

    #[test]
    fn a_missing_folder_says_how_to_make_one() {
        let e = TlsDir::new("/nonexistent/tls").server().unwrap_err();
        assert!(e.contains("/nonexistent/tls/server.pem") && e.contains("certs init"), "{e}");
    }
}
