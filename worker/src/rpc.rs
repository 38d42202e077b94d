//! The client side of the wire: connecting, bounding every call in time, and sorting
//! failures into the three cases the worker's machine treats differently.

use std::future::Future;
use std::time::Duration;

use anyhow::Context;
use proto::auth::{ClientAuth, Token};
use proto::farm_client::FarmClient;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Channel, ClientTlsConfig, Endpoint};
use tonic::{Code, Status};

pub type Client = FarmClient<InterceptedService<Channel, ClientAuth>>;

/// How a call failed, in the machine's terms.
pub type RpcFailure = crate::failure::Failure;

/// Does this message say that the worker id is unknown (rather than a job or unit)?
fn says_unknown_worker(message: &str) -> bool {
    let m = message.to_ascii_lowercase();
    ["unknown worker", "no such worker", "worker not found", "not registered", "re-register", "register again"]
        .iter()
        .any(|p| m.contains(p))
        || (m.starts_with("worker") && (m.contains("unknown") || m.contains("not found") || m.contains("expired")))
}

pub fn classify(status: Status) -> RpcFailure {
    match status.code() {
        Code::Unauthenticated => RpcFailure::UnknownWorker(status.message().to_string()),
        Code::NotFound if says_unknown_worker(status.message()) => {
            RpcFailure::UnknownWorker(status.message().to_string())
        }
        Code::InvalidArgument
        | Code::FailedPrecondition
        | Code::NotFound
        | Code::OutOfRange
        | Code::AlreadyExists
        | Code::PermissionDenied
        | Code::Unimplemented => {
            RpcFailure::Rejected { code: format!("{:?}", status.code()), message: status.message().to_string() }
        }
        // Unavailable, DeadlineExceeded, Cancelled, Unknown, Internal, Aborted,
        // ResourceExhausted, DataLoss, Ok: connection-level trouble or overload. Keep
        // the data and try again.
        _ => {
            let m = status.message();
            RpcFailure::Transport(if m.is_empty() { format!("{:?}", status.code()) } else { m.to_string() })
        }
    }
}

/// Runs one call with a time limit; a timeout counts as a transport failure.
pub async fn call<T>(
    limit: Duration,
    fut: impl Future<Output = Result<tonic::Response<T>, Status>>,
) -> Result<T, RpcFailure> {
    match tokio::time::timeout(limit, fut).await {
        Ok(Ok(r)) => Ok(r.into_inner()),
        Ok(Err(status)) => Err(classify(status)),
        Err(_) => Err(RpcFailure::Transport(format!("no answer within {limit:?}"))),
    }
}

/// How a worker proves itself to a farm: a token, a certificate (over TLS), or nothing
/// (a loopback farm without access control).
#[derive(Clone, Debug, Default)]
pub struct Credentials {
    pub token: Option<Token>,
    /// The farm's CA and this worker's certificate, from `--tls DIR`.
    pub tls: Option<ClientTlsConfig>,
}

impl Credentials {
    /// `TILEFARM_TOKEN` from the environment, and `<name>.pem`/`.key` from `tls_dir`.
    pub fn from_env_and(tls_dir: Option<&std::path::Path>, name: &str) -> anyhow::Result<Self> {
        let token = Token::from_env().map_err(anyhow::Error::msg)?;
        let tls = match tls_dir {
            Some(d) => Some(proto::tls::TlsDir::new(d).worker(name).map_err(anyhow::Error::msg)?),
            None => None,
        };
        Ok(Self { token, tls })
    }
}

/// A lazily connecting client: it (re)connects on demand, so a coordinator that is not
/// up yet, or restarts, is just a transport failure of the calls in between.
pub fn connect(url: &str, credentials: &Credentials) -> anyhow::Result<Client> {
    let url = proto::tls::url(url, credentials.tls.is_some()).map_err(anyhow::Error::msg)?;
    let mut endpoint = Endpoint::from_shared(url.clone())
        .with_context(|| format!("invalid coordinator address '{url}'"))?
        .connect_timeout(Duration::from_secs(3))
        .tcp_nodelay(true)
        .http2_keep_alive_interval(Duration::from_secs(20))
        .keep_alive_timeout(Duration::from_secs(20));
    if let Some(tls) = &credentials.tls {
        endpoint = endpoint.tls_config(tls.clone()).context("--tls")?;
    }
    Ok(FarmClient::with_interceptor(endpoint.connect_lazy(), ClientAuth::new(credentials.token.as_ref()))
        .max_decoding_message_size(proto::MAX_MESSAGE_BYTES)
        .max_encoding_message_size(proto::MAX_MESSAGE_BYTES))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failures_are_classified() {
        assert!(matches!(classify(Status::unavailable("tcp connect error")), RpcFailure::Transport(_)));
        assert!(matches!(classify(Status::deadline_exceeded("")), RpcFailure::Transport(_)));
        assert!(matches!(classify(Status::unknown("h2 protocol error")), RpcFailure::Transport(_)));
        assert!(matches!(classify(Status::unauthenticated("who are you")), RpcFailure::UnknownWorker(_)));
        assert!(matches!(classify(Status::not_found("unknown worker 7")), RpcFailure::UnknownWorker(_)));
        assert!(matches!(classify(Status::not_found("worker 7 is unknown")), RpcFailure::UnknownWorker(_)));
        assert!(matches!(classify(Status::not_found("unit 5 of job ab12 not found")), RpcFailure::Rejected { .. }));
        assert!(matches!(classify(Status::not_found("unknown job ab12")), RpcFailure::Rejected { .. }));
        assert!(matches!(classify(Status::invalid_argument("bad tile")), RpcFailure::Rejected { .. }));
        assert!(matches!(classify(Status::failed_precondition("lease lapsed")), RpcFailure::Rejected { .. }));
    }

    #[test]
    fn addresses_without_a_scheme_get_http() {
        // connect() is lazy: no network is touched here, but it needs a runtime.
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        rt.block_on(async {
            let none = Credentials::default();
            assert!(connect("127.0.0.1:1", &none).is_ok());
            assert!(connect("http://127.0.0.1:1", &none).is_ok());
            assert!(connect("http://bad host:1", &none).is_err());
        });
    }
}
