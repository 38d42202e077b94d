//! What every handler of the HTTP side shares: the farm and who may call.

use std::collections::VecDeque;
use std::sync::atomic::AtomicUsize;
use std::sync::{Arc, Mutex};

use proto::auth::Access;
use tracer::output::views::{View, ViewImage};

use crate::farm::Shared;

#[derive(Clone)]
pub(super) struct App {
    pub(super) shared: Arc<Shared>,
    pub(super) access: Arc<Access>,
    /// The dashboard's latest PNGs, shared by every page that shows the same merge at
    /// the same exposure and view (each is encoded once, however many pages are open).
    pub(super) images: Arc<Mutex<ImageCache>>,
    /// Event streams open now (each polls the farm; bounded).
    pub(super) event_streams: Arc<AtomicUsize>,
}

/// Which image: (job, results merged, the exposure's bits, the view).
pub(super) type ImageKey = (String, u64, u32, View);

/// A few recent tone-mapped images, by [`ImageKey`].
#[derive(Default)]
pub(super) struct ImageCache {
    entries: VecDeque<(ImageKey, Arc<ViewImage>)>,
}

impl ImageCache {
    const KEPT: usize = 8;

    pub(super) fn get(&self, key: &ImageKey) -> Option<Arc<ViewImage>> {
        self.entries.iter().find(|(k, _)| k == key).map(|(_, v)| Arc::clone(v))
    }

    pub(super) fn put(&mut self, key: ImageKey, png: Arc<ViewImage>) {
        if self.entries.len() == Self::KEPT {
            self.entries.pop_front();
        }
        self.entries.push_back((key, png));
    }
}
