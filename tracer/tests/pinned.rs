//! The bundled scenes' images, pinned by SHA-256 of their pixels' bits and sample
//! counts. A restructuring or a speed-up must not change a single bit; a change that
//! means to (a fixed bias, a new estimator) updates these hashes and says why in its
//! commit. Printed on failure, so the new values can be read off.

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};
use tracer::film::SampleRange;
use tracer::integrator::Integrator;
use tracer::render::render_image;
use tracer::scene::{Overrides, load_scene};

/// Small and quick, but through every route: the packed brute force (cornell-box,
/// veach-mis, glass, cube, room) and the kd-tree (cup), eight-path packets and scalar.
const PINNED: [(&str, &str); 6] = [
    ("cornell-box", "f57e2375db677bb4fe95f5046b0146c54ca2492a22d65bc517f8f5a184dbce33"),
    ("veach-mis", "ead71022fd586a286e63ba565ac800c72fd6d38abdf2495bd06f512dac9143c7"),
    ("glass", "2627e429356b9ff089fd1ab61c0e902ee06ec5fd0461d2d7aa2165d6bb407813"),
    ("cup", "03dc74bd5a1b7900ceb4d3146429022aa2a904076faac59b32b2c95e38c1caa2"),
    ("room", "248b6303b84618ea6db0fc430ac31ae74324d32bc81d0090b422d56a848a6902"),
    ("cube", "81583fecf2798cd1157338200ee4f9f2e98088f5d48ede405d6a900c4bffd047"),
];

fn bundled(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes").join(name).join("scene.toml")
}

fn image_hash(name: &str) -> String {
    let mut scene = load_scene(&bundled(name)).unwrap();
    Overrides { width: Some(48), spp: Some(4), ..Default::default() }.apply(&mut scene).unwrap();
    let (image, _) = render_image(&scene, Integrator::Path, SampleRange::new(0, 4), 16, &|_| {});
    let mut h = Sha256::new();
    for (p, c) in image.pixels.iter().zip(&image.counts) {
        for v in [p.x, p.y, p.z] {
            h.update(v.to_bits().to_le_bytes());
        }
        h.update(c.to_le_bytes());
    }
    format!("{:x}", h.finalize())
}

#[test]
fn bundled_scenes_render_the_pinned_bits() {
    let got: Vec<(&str, String)> = PINNED.iter().map(|(name, _)| (*name, image_hash(name))).collect();
    let mismatched: Vec<String> = PINNED
        .iter()
        .zip(&got)
        .filter(|((_, want), (_, have))| want != have)
        .map(|((name, want), (_, have))| format!("{name}: pinned {want}, rendered {have}"))
        .collect();
    assert!(mismatched.is_empty(), "images changed:\n{}", mismatched.join("\n"));
}
