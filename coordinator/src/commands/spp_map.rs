//! `--spp-map FILE.exr`: the samples per pixel each tile of a previous render reached,
//! read from its EXR's `samples` channel, to render the same pixels again.

use std::path::Path;

use anyhow::{Context, bail};
use proto::domain::SppMap;

/// The map of the render that wrote `path`, cut into tiles of `tile`: every pixel of a
/// tile must have the same count (a render's tiles do), else its tiles were others.
pub fn read(path: &Path, tile: u32) -> anyhow::Result<SppMap> {
    let shown = path.display();
    let image = tracer::output::read_exr(path).with_context(|| format!("--spp-map {shown}"))?;
    let (w, h) = (image.width, image.height);
    let tile = tile.max(1);
    let mut tile_spp = Vec::with_capacity(SppMap::tile_count(w, h, tile));
    for y0 in (0..h).step_by(tile as usize) {
        for x0 in (0..w).step_by(tile as usize) {
            let (x1, y1) = ((x0 + tile).min(w), (y0 + tile).min(h));
            let count = |x: u32, y: u32| image.counts[(y * w + x) as usize];
            let first = count(x0, y0);
            let other = (y0..y1).flat_map(|y| (x0..x1).map(move |x| (x, y))).find(|&(x, y)| count(x, y) != first);
            if let Some((x, y)) = other {
                bail!(
                    "--spp-map {shown}: pixels ({x0}, {y0}) and ({x}, {y}) of one {tile}-pixel tile have {first} and {} \
                     samples; give the --tile of the render that wrote it",
                    count(x, y)
                );
            }
            tile_spp.push(first);
        }
    }
    let map = SppMap { width: w, height: h, tile_size: tile, tile_spp };
    map.check().map_err(|e| anyhow::anyhow!("--spp-map {shown}: {e}"))?;
    if map.most() == 0 {
        bail!("--spp-map {shown}: no pixel has a sample");
    }
    Ok(map)
}
