//! Which unit next. Units are numbered in progressive order — every tile's first batch,
//! then every tile's second batch, … — so that a preview refines evenly over the image,
//! and leasing takes the lowest pending number.

use tracer::film::{SampleRange, Tile};

/// `(tile index, sample range)` of every unit, in progressive order.
pub fn progressive_units(tiles: &[Tile], spp: u32, batch_spp: u32) -> Vec<(usize, SampleRange)> {
    let batch = batch_spp.max(1);
    let mut units = Vec::new();
    let mut start = 0;
    while start < spp {
        let range = SampleRange::new(start, start.saturating_add(batch).min(spp));
        units.extend((0..tiles.len()).map(|t| (t, range)));
        start = range.end;
    }
    units
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn last_batch_is_partial() {
        let tiles = Tile::grid(4, 4, 4);
        let u = progressive_units(&tiles, 10, 4);
        let ranges: Vec<_> = u.iter().map(|(_, r)| (r.start, r.end)).collect();
        assert_eq!(ranges, [(0, 4), (4, 8), (8, 10)]);
    }
}
