//! Access tokens on the wire: a client sends `authorization: Bearer <token>` with every
//! call ([`ClientAuth`]); a farm configured with a token refuses any call without it,
//! comparing in constant time ([`ServerAuth`]). `render` makes a random token for each
//! run ([`Token::random`]), so that another user of the machine cannot reach its
//! loopback farm.

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
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
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

/// Lets through only calls that bear the farm's token (every call, when it has none).
#[derive(Clone, Debug, Default)]
pub struct ServerAuth(Option<Token>);

impl ServerAuth {
    pub fn new(token: Option<Token>) -> Self {
        Self(token)
    }
}

impl tonic::service::Interceptor for ServerAuth {
    fn call(&mut self, request: Request<()>) -> Result<Request<()>, Status> {
        let Some(expected) = &self.0 else { return Ok(request) };
        let given = request.metadata().get("authorization").and_then(|v| v.to_str().ok()).unwrap_or("");
        let given = given.strip_prefix("Bearer ").unwrap_or("");
        // Equal lengths compared in constant time; a length mismatch says only that.
        if bool::from(given.as_bytes().ct_eq(expected.secret().as_bytes())) {
            Ok(request)
        } else {
            Err(Status::permission_denied(
                "this farm needs an access token (--token or TILEFARM_TOKEN), and the call had none or another",
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tonic::service::Interceptor;

    #[test]
    fn only_calls_bearing_the_token_pass() {
        let token = Token::random().unwrap();
        assert_eq!(token.secret().len(), 64);
        assert_ne!(token.secret(), Token::random().unwrap().secret());
        let mut server = ServerAuth::new(Some(token.clone()));
        let signed = ClientAuth::new(Some(&token)).call(Request::new(())).unwrap();
        assert!(server.call(signed).is_ok());
        let unsigned = ClientAuth::new(None).call(Request::new(())).unwrap();
        assert_eq!(server.call(unsigned).unwrap_err().code(), tonic::Code::PermissionDenied);
        let other = Token::new("not-the-token").unwrap();
        let wrong = ClientAuth::new(Some(&other)).call(Request::new(())).unwrap();
        assert!(server.call(wrong).is_err());
        // A farm without a token lets everything through.
        assert!(ServerAuth::new(None).call(Request::new(())).is_ok());
        assert!(Token::new("has space").is_err() && Token::new("").is_err());
    }
}
