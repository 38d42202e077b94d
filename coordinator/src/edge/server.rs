//! Running the gRPC server: both services and the standard health service on one
//! listener, with a reaper that returns lapsed leases to the queue even when no worker
//! is asking for work.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use proto::auth::{Access, ServerAuth, Service};
use tokio::sync::oneshot;
use tonic::service::Interceptor;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::ServerTlsConfig;

use crate::edge::conn::{Accepted, Gate, Limits};
use crate::edge::service::{FarmService, JobsService, Registrations};
use crate::farm::Shared;

pub struct Server {
    pub addr: SocketAddr,
    scheme: &'static str,
    stop: Option<oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<Result<(), tonic::transport::Error>>,
}

impl Server {
    /// Binds `listen` (port 0 asks the OS for a free port) and serves in the background,
    /// to the callers `access` admits, over TLS when `tls` is given, holding connections
    /// to `limits`.
    pub async fn start(
        shared: Arc<Shared>,
        listen: &str,
        access: Access,
        tls: Option<ServerTlsConfig>,
        limits: Limits,
    ) -> anyhow::Result<Self> {
        let listener = tokio::net::TcpListener::bind(listen).await.with_context(|| format!("listening on {listen}"))?;
        let addr = listener.local_addr()?;
        let (stop, stopped) = oneshot::channel::<()>();
        let registrations = if access.is_open() { Registrations::EachItsOwn } else { Registrations::ByIdentity };
        let farm = proto::farm_server::FarmServer::new(FarmService(Arc::clone(&shared), registrations))
            .max_decoding_message_size(proto::MAX_MESSAGE_BYTES)
            .max_encoding_message_size(proto::MAX_MESSAGE_BYTES);
        let jobs = proto::jobs_server::JobsServer::new(JobsService(Arc::clone(&shared)))
            .max_decoding_message_size(proto::MAX_MESSAGE_BYTES)
            .max_encoding_message_size(proto::MAX_MESSAGE_BYTES);
        let access = Arc::new(access);
        let gate = Gate::new("gRPC", limits.max_pending);
        let admit = |service| Admit { auth: ServerAuth::new(Arc::clone(&access), service), gate: Arc::clone(&gate) };
        let farm = InterceptedService::new(farm, admit(Service::Workers));
        let jobs = InterceptedService::new(jobs, admit(Service::Jobs));
        // A peer that stops answering pings (gone without closing) gives its connection up.
        let mut builder = tonic::transport::Server::builder()
            .http2_keepalive_interval(Some(limits.idle))
            .http2_keepalive_timeout(Some(KEEPALIVE_ANSWER));
        let scheme = if let Some(tls) = tls {
            builder = builder.tls_config(tls.timeout(limits.handshake)).context("the TLS configuration")?;
            "https"
        } else {
            "http"
        };
        let reaper = Arc::clone(&shared);
        tokio::spawn(async move {
            loop {
                tokio::time::sleep(Duration::from_millis(250)).await;
                reaper.farm().reap(Instant::now());
                reaper.arbitrate();
                if Arc::strong_count(&reaper) == 1 {
                    break;
                }
            }
        });
        // The standard health service (grpc.health.v1), open to every caller as probes
        // expect: "" and both services report SERVING while the server runs.
        let (reporter, health) = tonic_health::server::health_reporter();
        for name in ["", "tilefarm.v1.Farm", "tilefarm.v1.Jobs"] {
            reporter.set_service_status(name, tonic_health::ServingStatus::Serving).await;
        }
        let task =
            tokio::spawn(builder.add_service(health).add_service(farm).add_service(jobs).serve_with_incoming_shutdown(
                Accepted::new(listener, gate, Some(limits.idle)),
                async {
                    let _ = stopped.await;
                },
            ));
        Ok(Self { addr, scheme, stop: Some(stop), task })
    }

    pub fn url(&self) -> String {
        format!("{}://{}", self.scheme, self.addr)
    }

    /// Stops accepting requests and waits (briefly) for the server to wind down.
    pub async fn stop(mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        let _ = tokio::time::timeout(Duration::from_secs(3), &mut self.task).await;
    }
}

/// How long a keepalive ping may go unanswered before the connection is closed.
const KEEPALIVE_ANSWER: Duration = Duration::from_secs(20);

/// The farm's access control, which also marks the connection of a call it lets
/// through as authenticated: the connection no longer counts against the listener's
/// cap on pending connections, nor expires for not authenticating.
#[derive(Clone)]
struct Admit {
    auth: ServerAuth,
    gate: Arc<Gate>,
}

impl Interceptor for Admit {
    fn call(&mut self, request: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        let request = self.auth.call(request)?;
        if let Some(peer) = request.remote_addr() {
            self.gate.prove(peer);
        }
        Ok(request)
    }
}
