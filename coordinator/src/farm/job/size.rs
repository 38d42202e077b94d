//! A job's size: what it holds in the coordinator's memory, and whether a job of a
//! given shape fits before anything is allocated.

use tracer::film::Tile;

use super::{ACCUMULATION_BYTES_PER_PIXEL, Job, LAYER_BYTES_PER_PIXEL, MAX_UNITS, UNIT_BYTES};

impl Job {
    /// Checks, before anything is allocated, that a job of this shape fits: at most
    /// [`MAX_UNITS`] units, tiles within the wire's limit, and its [memory](Job::memory)
    /// within `max_bytes`; returns that memory. The error names the setting and the limit.
    pub fn check_size(
        (width, height): (u32, u32),
        spp: u32,
        (tile, batch): (u32, u32),
        layers: bool,
        max_bytes: u64,
    ) -> Result<u64, String> {
        if tile == 0 || tile > proto::wire::MAX_TILE_SIDE {
            return Err(format!("tile size {tile}: must be between 1 and {}", proto::wire::MAX_TILE_SIDE));
        }
        let side = Tile::new(0, 0, tile, tile);
        if proto::wire::result_bytes_bound(side, layers) > proto::MAX_MESSAGE_BYTES {
            return Err(format!(
                "tile size {tile}: a tile's result with the AOV layers would not fit in one message; use a \
                 smaller tile size"
            ));
        }
        if batch == 0 || batch > proto::wire::MAX_SAMPLES_PER_UNIT {
            return Err(format!("batch_spp {batch}: must be between 1 and {}", proto::wire::MAX_SAMPLES_PER_UNIT));
        }
        let too_large = |bytes: u64, units: u64| {
            format!(
                "a {width}×{height} image in {units} units needs {} MiB, more than this farm's limit of {} MiB \
                 (--max-job-memory-mb)",
                bytes >> 20,
                max_bytes >> 20
            )
        };
        let tiles = u64::from(width.div_ceil(tile)) * u64::from(height.div_ceil(tile));
        let units = tiles * u64::from(spp.div_ceil(batch));
        // The pixels alone first: that names the image's size, the likelier mistake.
        if Self::memory((width, height), 0, layers) > max_bytes {
            return Err(too_large(Self::memory((width, height), 0, layers), units));
        }
        if units > MAX_UNITS {
            return Err(format!(
                "{units} units of work ({tiles} tiles × {} batches of {batch} spp): more than the {MAX_UNITS} a job may \
                 have; raise the tile size or batch_spp",
                spp.div_ceil(batch)
            ));
        }
        let bytes = Self::memory((width, height), units, layers);
        if bytes > max_bytes {
            return Err(too_large(bytes, units));
        }
        Ok(bytes)
    }

    /// What a job of this shape holds in the coordinator's memory while it runs: its
    /// accumulations (52 bytes a pixel, 176 more with `layers`) and its units' records.
    pub fn memory((width, height): (u32, u32), units: u64, layers: bool) -> u64 {
        let per_pixel = ACCUMULATION_BYTES_PER_PIXEL + if layers { LAYER_BYTES_PER_PIXEL } else { 0 };
        u64::from(width) * u64::from(height) * per_pixel + units * UNIT_BYTES
    }
}
