//! What every handler of the HTTP side shares: the farm and who may call.

use std::sync::Arc;

use proto::auth::Access;

use crate::farm::Shared;

#[derive(Clone)]
pub(super) struct App {
    pub(super) shared: Arc<Shared>,
    pub(super) access: Arc<Access>,
}
