//! Running the gRPC server: both services on one listener, with a reaper that returns
//! lapsed leases to the queue even when no worker is asking for work.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use tokio::sync::oneshot;
use tokio_stream::StreamExt;
use tokio_stream::wrappers::TcpListenerStream;

use crate::edge::service::{FarmService, JobsService};
use crate::farm::Shared;

pub struct Server {
    pub addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<Result<(), tonic::transport::Error>>,
}

impl Server {
    /// Binds `listen` (port 0 asks the OS for a free port) and serves in the background;
    /// with a `token`, only to calls that bear it.
    pub async fn start(shared: Arc<Shared>, listen: &str, token: Option<proto::auth::Token>) -> anyhow::Result<Self> {
        let listener = tokio::net::TcpListener::bind(listen).await.with_context(|| format!("listening on {listen}"))?;
        let addr = listener.local_addr()?;
        let (stop, stopped) = oneshot::channel::<()>();
        let farm = proto::farm_server::FarmServer::new(FarmService(Arc::clone(&shared)))
            .max_decoding_message_size(proto::MAX_MESSAGE_BYTES)
            .max_encoding_message_size(proto::MAX_MESSAGE_BYTES);
        let jobs = proto::jobs_server::JobsServer::new(JobsService(Arc::clone(&shared)))
            .max_decoding_message_size(proto::MAX_MESSAGE_BYTES)
            .max_encoding_message_size(proto::MAX_MESSAGE_BYTES);
        let auth = proto::auth::ServerAuth::new(token);
        let farm = tonic::service::interceptor::InterceptedService::new(farm, auth.clone());
        let jobs = tonic::service::interceptor::InterceptedService::new(jobs, auth);
        let reaper = Arc::clone(&shared);
        tokio::spawn(async move {
            loop {
                tokio::time::sleep(Duration::from_millis(250)).await;
                reaper.farm().reap(Instant::now());
                if Arc::strong_count(&reaper) == 1 {
                    break;
                }
            }
        });
        let task = tokio::spawn(
            tonic::transport::Server::builder().add_service(farm).add_service(jobs).serve_with_incoming_shutdown(
                TcpListenerStream::new(listener).map(no_delay),
                async {
                    let _ = stopped.await;
                },
            ),
        );
        Ok(Self { addr, stop: Some(stop), task })
    }

    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// Stops accepting requests and waits (briefly) for the server to wind down.
    pub async fn stop(mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        let _ = tokio::time::timeout(Duration::from_secs(3), &mut self.task).await;
    }
}

/// Small request/response messages must not wait for Nagle's algorithm (~40 ms each).
fn no_delay(s: std::io::Result<tokio::net::TcpStream>) -> std::io::Result<tokio::net::TcpStream> {
    if let Ok(stream) = &s {
        let _ = stream.set_nodelay(true);
    }
    s
}
