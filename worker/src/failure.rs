//! How a call to the coordinator failed, in the three cases the worker treats
//! differently (below both the state machine and the client that sorts failures).

/// How a call to the coordinator failed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Failure {
    /// The coordinator could not be reached (or the call timed out or broke off): the
    /// same call may succeed later, so keep what was being sent and retry.
    Transport(String),
    /// The coordinator does not know this worker id (it restarted, or expired us):
    /// register again.
    UnknownWorker(String),
    /// The coordinator understood and refused the call; retrying will not help.
    Rejected { code: String, message: String },
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Failure::Transport(m) => write!(f, "coordinator unreachable: {m}"),
            Failure::UnknownWorker(m) => write!(f, "unknown worker: {m}"),
            Failure::Rejected { code, message } => write!(f, "{code}: {message}"),
        }
    }
}
