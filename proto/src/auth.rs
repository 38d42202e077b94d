//! Who may call a farm. A client sends `authorization: Bearer <token>` with every call
//! ([`ClientAuth`]); a worker on a TLS farm instead presents its client certificate. The
//! farm's [`Access`] maps each token (compared in constant time) or verified certificate
//! to a [`Caller`] with a [`Role`], and [`ServerAuth`] lets a call through only when that
//! role may use the service. `render` makes a random token for each run
//! ([`Token::random`]), so that another user of the machine cannot reach its loopback
//! farm.

use std::sync::Arc;

use subtle::ConstantTimeEq;
use tonic::metadata::MetadataValue;
use tonic::{Request, Status};

/// The environment variable clients and workers read their token from.
pub const TOKEN_ENV: &str = "TILEFARM_TOKEN";
/// Longest token accepted (from a file, the environment or the wire).
pub const MAX_TOKEN_BYTES: usize = 4096;

/// A secret that grants access to a farm.
#[derive(Clone)]
pub struct Token(Arc<str>);

impl std::fmt::Debug for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Token(…)")
    }
}

impl Token {
    /// Checks a token as given (trimmed): printable ASCII, without spaces, not empty, at
    /// most [`MAX_TOKEN_BYTES`].
    pub fn new(text: &str) -> Result<Self, String> {
        let t = text.trim();
        if t.is_empty() || t.len() > MAX_TOKEN_BYTES || !t.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(format!("an access token is 1 to {MAX_TOKEN_BYTES} printable ASCII characters without spaces"));
        }
        Ok(Self(t.into()))
    }

    /// 256 random bits, as 64 hex digits.
    pub fn random() -> Result<Self, String> {
        let mut bytes = [0u8; 32];
        getrandom::fill(&mut bytes).map_err(|e| format!("no randomness for an access token: {e}"))?;
        Ok(Self(bytes.iter().map(|b| format!("{b:02x}")).collect::<String>().into()))
    }

    /// The token in the environment ([`TOKEN_ENV`]), if set.
    pub fn from_env() -> Result<Option<Self>, String> {
        match std::env::var(TOKEN_ENV) {
            Ok(t) if !t.trim().is_empty() => Token::new(&t).map(Some).map_err(|e| format!("{TOKEN_ENV}: {e}")),
            _ => Ok(None),
        }
    }

    /// The token in a file (its first line).
    pub fn from_file(path: &std::path::Path) -> Result<Self, String> {
        use std::io::Read;
        let mut text = String::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(MAX_TOKEN_BYTES as u64 + 2).read_to_string(&mut text))
            .map_err(|e| format!("{}: {e}", path.display()))?;
        Token::new(text.lines().next().unwrap_or("")).map_err(|e| format!("{}: {e}", path.display()))
    }

    pub fn secret(&self) -> &str {
        &self.0
    }
}

/// Adds the token (if any) to every call.
#[derive(Clone, Debug, Default)]
pub struct ClientAuth(Option<MetadataValue<tonic::metadata::Ascii>>);

impl ClientAuth {
    pub fn new(token: Option<&Token>) -> Self {
        Self(token.map(|t| format!("Bearer {}", t.secret()).parse().expect("a checked token is valid ASCII metadata")))
    }
}

impl tonic::service::Interceptor for ClientAuth {
    fn call(&mut self, mut request: Request<()>) -> Result<Request<()>, Status> {
        if let Some(v) = &self.0 {
            request.metadata_mut().insert("authorization", v.clone());
        }
        Ok(request)
    }
}

/// What a caller may do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Role {
    /// A worker certificate: the worker service only.
    Worker,
    /// A user token: submit jobs, and watch, fetch or cancel its own.
    User,
    /// An admin token (or a farm without access control): everything.
    Admin,
}

/// Who made a call, as the farm's access control found it; the services read it from
/// the request's extensions.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Caller {
    pub role: Role,
    /// A user's name (its token file's stem), `admin`, or a worker certificate's
    /// fingerprint (`cert:` and 16 hex digits).
    pub name: String,
}

impl Caller {
    pub fn admin() -> Self {
        Self { role: Role::Admin, name: "admin".into() }
    }

    /// May this caller see and change the jobs `owner` submitted?
    pub fn may_touch(&self, owner: Option<&str>) -> bool {
        self.role == Role::Admin || (self.role == Role::User && owner == Some(self.name.as_str()))
    }
}

/// The caller of a request that passed [`ServerAuth`] (an admin when no access
/// control ran, as in unit tests of the services).
pub fn caller<T>(request: &Request<T>) -> Caller {
    request.extensions().get::<Caller>().cloned().unwrap_or_else(Caller::admin)
}

/// Which of the farm's two services a [`ServerAuth`] guards.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Service {
    /// Register, lease, heartbeat, submit results, fetch assets.
    Workers,
    /// Upload, submit, watch, fetch, cancel, list.
    Jobs,
}

/// A farm's access rules: its tokens with the caller each stands for, and whether a
/// verified client certificate (mTLS, checked by rustls against the farm's CA) makes a
/// worker. With no tokens and no TLS, everyone is an admin: only for loopback.
#[derive(Clone, Debug, Default)]
pub struct Access {
    tokens: Vec<(Token, Caller)>,
    worker_certificates: bool,
}

impl Access {
    /// Everyone may do everything (a loopback farm without tokens).
    pub fn open() -> Self {
        Self::default()
    }

    pub fn with_token(mut self, token: Token, caller: Caller) -> Self {
        self.tokens.push((token, caller));
        self
    }

    /// Callers presenting a client certificate the TLS layer verified are workers.
    pub fn with_worker_certificates(mut self) -> Self {
        self.worker_certificates = true;
        self
    }

    pub fn has_tokens(&self) -> bool {
        !self.tokens.is_empty()
    }

    pub fn is_open(&self) -> bool {
        self.tokens.is_empty() && !self.worker_certificates
    }

    /// Who bears `bearer` (the `authorization` header's value) with `certificate` (the
    /// verified leaf certificate's DER, if any).
    pub fn identify(&self, bearer: Option<&str>, certificate: Option<&[u8]>) -> Result<Caller, Status> {
        if self.is_open() {
            return Ok(Caller::admin());
        }
        if let Some(given) = bearer {
            let given = given.strip_prefix("Bearer ").unwrap_or("");
            // Every token is compared, each in constant time, so the time taken says
            // nothing about which token (if any) came close.
            let mut found = None;
            for (token, caller) in &self.tokens {
                if bool::from(given.as_bytes().ct_eq(token.secret().as_bytes())) {
                    found = Some(caller);
                }
            }
            return found.cloned().ok_or_else(|| {
                Status::permission_denied("this access token is not one of this farm's (--token or TILEFARM_TOKEN)")
            });
        }
        match certificate {
            Some(der) if self.worker_certificates => Ok(Caller { role: Role::Worker, name: fingerprint(der) }),
            _ => Err(Status::permission_denied(
                "this farm needs an access token (--token or TILEFARM_TOKEN), or for workers a certificate \
                 (--tls DIR), and the call had neither",
            )),
        }
    }

    /// May `caller` use `service`?
    pub fn permit(caller: &Caller, service: Service) -> Result<(), Status> {
        match (service, caller.role) {
            (_, Role::Admin) | (Service::Workers, Role::Worker) | (Service::Jobs, Role::User) => Ok(()),
            (Service::Jobs, Role::Worker) => {
                Err(Status::permission_denied("a worker certificate may use only the worker service"))
            }
            (Service::Workers, Role::User) => {
                Err(Status::permission_denied("a user token may not join the farm as a worker"))
            }
        }
    }
}

/// A certificate's identity: `cert:` and the first 16 hex digits of its SHA-256.
pub fn fingerprint(der: &[u8]) -> String {
    use sha2::Digest;
    format!("cert:{}", &hex::encode(sha2::Sha256::digest(der))[..16])
}

/// Lets through only calls whose caller [`Access`] knows and may use the service, and
/// records the [`Caller`] in the request for the service to check ownership with.
#[derive(Clone, Debug)]
pub struct ServerAuth {
    access: Arc<Access>,
    service: Service,
}

impl ServerAuth {
    pub fn new(access: Arc<Access>, service: Service) -> Self {
        Self { access, service }
    }
}

impl tonic::service::Interceptor for ServerAuth {
    fn call(&mut self, mut request: Request<()>) -> Result<Request<()>, Status> {
        let bearer = request.metadata().get("authorization").map(|v| v.to_str().unwrap_or(""));
        let certs = request.peer_certs();
        let leaf = certs.as_ref().and_then(|c| c.first()).map(|c| c.as_ref());
        let caller = self.access.identify(bearer, leaf)?;
        Access::permit(&caller, self.service)?;
        request.extensions_mut().insert(caller);
        Ok(request)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tonic::service::Interceptor;

    fn call(auth: &mut ServerAuth, token: Option<&Token>) -> Result<Caller, Status> {
        let signed = ClientAuth::new(token).call(Request::new(())).unwrap();
        auth.call(signed).map(|r| caller(&r))
    }

    #[test]
    fn only_calls_bearing_a_known_token_pass_with_their_role() {
        let admin = Token::random().unwrap();
        let alice = Token::random().unwrap();
        assert_eq!(admin.secret().len(), 64);
        assert_ne!(admin.secret(), alice.secret());
        let access = Arc::new(
            Access::default()
                .with_token(admin.clone(), Caller::admin())
                .with_token(alice.clone(), Caller { role: Role::User, name: "alice".into() }),
        );
        let mut jobs = ServerAuth::new(Arc::clone(&access), Service::Jobs);
        let mut workers = ServerAuth::new(Arc::clone(&access), Service::Workers);
        assert_eq!(call(&mut jobs, Some(&admin)).unwrap(), Caller::admin());
        assert_eq!(call(&mut workers, Some(&admin)).unwrap().role, Role::Admin);
        assert_eq!(call(&mut jobs, Some(&alice)).unwrap().name, "alice");
        // A user may not join as a worker.
        assert_eq!(call(&mut workers, Some(&alice)).unwrap_err().code(), tonic::Code::PermissionDenied);
        assert_eq!(call(&mut jobs, None).unwrap_err().code(), tonic::Code::PermissionDenied);
        let other = Token::new("not-the-token").unwrap();
        assert!(call(&mut jobs, Some(&other)).is_err());
        // A farm without access control lets everything through, as an admin.
        let mut open = ServerAuth::new(Arc::new(Access::open()), Service::Jobs);
        assert_eq!(call(&mut open, None).unwrap(), Caller::admin());
        assert!(Token::new("has space").is_err() && Token::new("").is_err());
    }

    #[test]
    fn a_verified_certificate_makes_a_worker_that_may_not_submit() {
        let access = Access::default().with_worker_certificates();
        let w = access.identify(None, Some(b"some der")).unwrap();
        assert_eq!(w.role, Role::Worker);
        assert!(w.name.starts_with("cert:") && w.name.len() == 21);
        assert_eq!(Access::permit(&w, Service::Jobs).unwrap_err().code(), tonic::Code::PermissionDenied);
        assert!(Access::permit(&w, Service::Workers).is_ok());
        // Without certificates configured, a certificate is no credential.
        let tokens_only = Access::default().with_token(Token::random().unwrap(), Caller::admin());
        assert!(tokens_only.identify(None, Some(b"some der")).is_err());
    }

    #[test]
    fn users_touch_only_their_own_jobs() {
        let alice = Caller { role: Role::User, name: "alice".into() };
        assert!(alice.may_touch(Some("alice")));
        assert!(!alice.may_touch(Some("bob")) && !alice.may_touch(None));
        assert!(Caller::admin().may_touch(Some("bob")) && Caller::admin().may_touch(None));
        let worker = Caller { role: Role::Worker, name: "cert:00".into() };
        assert!(!worker.may_touch(Some("cert:00")));
    }
}
