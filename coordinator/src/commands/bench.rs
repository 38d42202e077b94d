//! `coordinator bench`: BVH build time, memory, ray throughput (primary, shadow,
//! diffuse bounce) and full-render speed, per scene. Figures are medians of repeated
//! runs, since the machines we run on are shared and noisy.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;
use glam::{Vec2, Vec3};
use tracer::accel::bvh8::{Bvh8, Bvh8Params};
use tracer::film::SampleRange;
use tracer::geometry::{Frame, Ray, offset_origin};
use tracer::integrator::Integrator;
use tracer::scene::Scene;

#[derive(Args)]
pub struct BenchArgs {
    /// Scenes to measure (default: the built-in Cornell box, every scenes/*/scene.toml
    /// found under the current directory, and a generated mesh).
    pub scenes: Vec<PathBuf>,
    /// Triangles in the generated displaced-sphere mesh (0 = leave it out).
    #[arg(long, default_value_t = 1_000_000)]
    pub mesh_triangles: usize,
    /// Rays per throughput measurement.
    #[arg(long, default_value_t = 500_000)]
    pub rays: usize,
    /// Repetitions of each measurement (the median is printed).
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// Samples per pixel of the full-render measurement.
    #[arg(long, default_value_t = 4)]
    pub spp: u32,
    /// Write the generated mesh (binary, see bench/embree_compare.py) and exit.
    #[arg(long)]
    pub export_mesh: Option<PathBuf>,
    /// Write `--rays` incoherent rays over the generated mesh (binary) and exit.
    #[arg(long)]
    pub export_rays: Option<PathBuf>,
}

/// `--export-mesh` / `--export-rays` (mesh seed 0, the kd-tree bench's): little-endian `TFMESH01 nverts ntris f32×3·nverts
/// u32×3·ntris` and `TFRAYS01 n (f32 ox oy oz dx dy dz tmax)×n`, the displaced sphere of
/// `--mesh-triangles` and `tracer::accel::incoherent_rays(bounds, --rays, 1)`: the data
/// of `KDTREE_QUICK=all,N,R,0,RAYS cargo bench -p tracer --bench kdtree`.
fn export(args: &BenchArgs) -> anyhow::Result<()> {
    let mesh = tracer::scene::generate::displaced_sphere(args.mesh_triangles, 0);
    if let Some(path) = &args.export_mesh {
        let mut b = b"TFMESH01".to_vec();
        b.extend((mesh.positions.len() as u32).to_le_bytes());
        b.extend((mesh.tris.len() as u32).to_le_bytes());
        b.extend(mesh.positions.iter().flat_map(|p| p.to_array()).flat_map(f32::to_le_bytes));
        b.extend(mesh.tris.iter().flat_map(|t| t.v).flat_map(u32::to_le_bytes));
        std::fs::write(path, b)?;
    }
    if let Some(path) = &args.export_rays {
        let bounds = tracer::geometry::Aabb::from_points(&mesh.positions);
        let mut b = b"TFRAYS01".to_vec();
        b.extend((args.rays as u32).to_le_bytes());
        for (r, tmax) in tracer::accel::incoherent_rays(bounds, args.rays, 1) {
            let v = [r.origin.to_array(), r.dir.to_array(), [tmax, 0.0, 0.0]].concat();
            b.extend(v[..7].iter().flat_map(|x| x.to_le_bytes()));
        }
        std::fs::write(path, b)?;
    }
    Ok(())
}

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    if args.export_mesh.is_some() || args.export_rays.is_some() {
        return export(&args);
    }
    let mut scenes: Vec<(String, Scene)> = Vec::new();
    if args.scenes.is_empty() {
        scenes.push(("cornell-box (built-in)".into(), crate::commands::builtin::load(None)?));
        if let Ok(dir) = std::fs::read_dir("scenes") {
            let mut paths: Vec<PathBuf> =
                dir.flatten().map(|e| e.path().join("scene.toml")).filter(|p| p.exists()).collect();
            paths.sort();
            for p in paths {
                scenes.push((p.display().to_string(), tracer::scene::load_scene(&p)?));
            }
        }
    } else {
        for p in &args.scenes {
            scenes.push((p.display().to_string(), tracer::scene::load_scene(p)?));
        }
    }
    if args.mesh_triangles > 0 {
        let t = Instant::now();
        let mesh = tracer::scene::generate::displaced_sphere(args.mesh_triangles, 7);
        let model = tracer::scene::obj::ObjModel {
            mesh,
            materials: vec![tracer::material::MaterialDesc::default_grey("generated")],
            ..Default::default()
        };
        let scene = tracer::scene::scene_from_bare_obj(model, tracer::scene::UpAxis::Y);
        eprintln!("generated mesh in {:.2}s", t.elapsed().as_secs_f64());
        scenes.push((format!("displaced sphere ({} triangles)", scene.geometry.triangle_count()), scene));
    }

    println!("threads: {} (ray throughput is measured on one thread: Mrays/s per core)", rayon::current_num_threads());
    for (name, mut scene) in scenes {
        // Throughput rays use a 256-wide film so that the figures compare across scenes.
        let aspect = scene.camera.width as f32 / scene.camera.height as f32;
        scene.camera.width = 256;
        scene.camera.height = (256.0 / aspect).round().max(1.0) as u32;
        bench_scene(&name, &scene, &args);
    }
    Ok(())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// A small deterministic generator for the benchmark's incoherent rays.
struct SplitMix(u64);

impl SplitMix {
    fn next_f32(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9E3779B97F4A7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }

    fn next_2d(&mut self) -> Vec2 {
        Vec2::new(self.next_f32(), self.next_f32())
    }
}

// Long on purpose: One scene's benchmark, its measurements in the order they are printed.
fn bench_scene(name: &str, scene: &Scene, args: &BenchArgs) {
    let repeat = args.repeat.max(1);
    let geom = &scene.geometry;
    let ntri = geom.triangle_count().max(1);
    println!("\n== {name}");

    let builds: Vec<f64> = (0..repeat)
        .map(|_| {
            let t = Instant::now();
            let tree = Bvh8::build(geom, &Bvh8Params::default());
            std::hint::black_box(&tree);
            t.elapsed().as_secs_f64()
        })
        .collect();
    let stats = scene.accel.stats();
    // What the scene holds for its geometry after loading (allocated bytes): the compact
    // mesh (materials, shading-normal and uv indices and the normals and uvs where the
    // mesh has them), the triangle corners (the only copy of the positions), the tree.
    let gb = geom.bytes();
    let tree_bytes = scene.accel.heap_bytes();
    println!(
        "BVH build: {:.3} ms (median of {repeat}); {} nodes of 8 ({:.2} children each), {} leaves ({:.2} primitives \
         each), depth {}",
        median(builds) * 1e3,
        stats.nodes,
        stats.mean_children,
        stats.leaves,
        stats.mean_leaf_prims,
        stats.max_depth
    );
    if let Some(p) = &scene.packed {
        println!(
            "rays are traced by packed brute force ({} triangles in blocks of 8, {} B, {}), not the BVH",
            p.len(),
            p.bytes(),
            p.instruction_set()
        );
    }
    let per_tri = |b: usize| b as f64 / ntri as f64;
    let mut extra = String::new();
    if gb.spheres > 0 {
        extra += &format!(" + spheres {} B", gb.spheres);
    }
    let packed_bytes = scene.packed.as_ref().map_or(0, |p| p.bytes());
    if packed_bytes > 0 {
        extra += &format!(" + packed blocks {:.1} B/tri", per_tri(packed_bytes));
    }
    println!(
        "memory: mesh {:.1} B/tri + corners {:.1} B/tri + tree {:.1} B/tri{extra} = {:.1} B/tri",
        per_tri(gb.mesh),
        per_tri(gb.corners),
        per_tri(tree_bytes),
        per_tri(gb.total() + tree_bytes + packed_bytes)
    );

    // Primary rays: one per pixel, jittered, repeated to reach the requested count.
    let cam = &scene.camera;
    let mut rng = SplitMix(1);
    let primary: Vec<Ray> = (0..args.rays)
        .map(|i| {
            let p = i % (cam.width * cam.height) as usize;
            let film = Vec2::new((p % cam.width as usize) as f32, (p / cam.width as usize) as f32) + rng.next_2d();
            cam.generate_ray(film, rng.next_2d())
        })
        .collect();
    let mut hits = Vec::with_capacity(primary.len());
    let primary_rate = rate(repeat, primary.len(), || {
        hits.clear();
        for r in &primary {
            hits.push(scene.intersect(r, f32::INFINITY).map(|h| (r, h)));
        }
    });
    let points: Vec<(Vec3, Vec3)> = hits
        .iter()
        .flatten()
        .map(|(r, h)| {
            let si = scene.interaction(r, h);
            let n = if si.ng.dot(r.dir) > 0.0 { -si.ng } else { si.ng };
            (si.p, n)
        })
        .collect();
    println!("primary rays: {primary_rate:.2} Mrays/s ({} of {} hit)", points.len(), primary.len());
    let packet_rays: Vec<(Ray, f32)> = primary.iter().map(|r| (*r, f32::INFINITY)).collect();
    packet_rate(scene, "primary", repeat, &packet_rays, false);
    if points.is_empty() {
        return;
    }

    // Shadow rays: from visible points to random points in the scene's bounds (any hit).
    let (lo, hi) = (scene.center - Vec3::splat(scene.radius), scene.center + Vec3::splat(scene.radius));
    let shadow: Vec<(Ray, f32)> = (0..args.rays)
        .map(|i| {
            let (p, n) = points[i % points.len()];
            let q = lo + (hi - lo) * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let o = offset_origin(p, n, q - p);
            let d = q - o;
            let dist = d.length().max(1e-6);
            (Ray::new(o, d / dist), dist)
        })
        .collect();
    let mut blocked = 0usize;
    let shadow_rate = rate(repeat, shadow.len(), || {
        blocked = shadow.iter().filter(|(r, t)| scene.occluded(r, *t)).count();
    });
    println!("shadow rays (any hit): {shadow_rate:.2} Mrays/s ({blocked} blocked)");
    let mut found = 0usize;
    let shadow_closest = rate(repeat, shadow.len(), || {
        found = shadow.iter().filter(|(r, t)| scene.intersect(r, *t).is_some()).count();
    });
    println!("  the same shadow rays, closest hit within their length: {shadow_closest:.2} Mrays/s ({found} hit)");
    packet_rate(scene, "shadow", repeat, &shadow, true);

    // Diffuse bounce rays: cosine-distributed around the normals of visible points.
    let bounce: Vec<Ray> = (0..args.rays)
        .map(|i| {
            let (p, n) = points[i % points.len()];
            let local = tracer::sampling::sample_cosine_hemisphere(rng.next_2d());
            let d = Frame::from_normal(n).to_world(local).normalize();
            Ray::new(offset_origin(p, n, d), d)
        })
        .collect();
    let mut nhit = 0usize;
    let bounce_rate = rate(repeat, bounce.len(), || {
        nhit = bounce.iter().filter(|r| scene.intersect(r, f32::INFINITY).is_some()).count();
    });
    println!("diffuse bounce rays (closest hit): {bounce_rate:.2} Mrays/s ({nhit} hit)");
    let packet_rays: Vec<(Ray, f32)> = bounce.iter().map(|r| (*r, f32::INFINITY)).collect();
    packet_rate(scene, "diffuse bounce", repeat, &packet_rays, false);

    // Full render, all threads.
    let spp = args.spp.max(1);
    let mut rays = 0u64;
    let mut samples = 0u64;
    let times: Vec<f64> = (0..repeat)
        .map(|_| {
            let t = Instant::now();
            let (_, s) = tracer::render::render_image(scene, Integrator::Path, SampleRange::new(0, spp), 16, &|_| {});
            rays = s.rays;
            samples = s.samples;
            t.elapsed().as_secs_f64()
        })
        .collect();
    let secs = median(times);
    println!(
        "render {}×{} at {spp} spp, max_depth {}: {:.3} s, {:.3} M samples/s, {:.2} M rays/s (all threads)",
        scene.camera.width,
        scene.camera.height,
        scene.settings.max_depth,
        secs,
        samples as f64 / secs / 1e6,
        rays as f64 / secs / 1e6
    );
}

/// For scenes that the renderer traces in packets of eight (brute force with AVX2,
/// `tracer::accel::ray_packets`): the same rays, eight at a time in the order given, as the
/// path renderer traces them (each packet's rays from eight independent paths).
fn packet_rate(scene: &Scene, what: &str, repeat: usize, rays: &[(Ray, f32)], any_hit: bool) {
    #[cfg(target_arch = "x86_64")]
    if let Some(packed) = scene.packed.as_ref().filter(|p| p.packets()) {
        use tracer::accel::ray_packets::{PACKET, RayPacket};
        let packets: Vec<RayPacket> = rays
            .chunks(PACKET)
            .map(|c| {
                let mut p = RayPacket::default();
                for (l, (r, t)) in c.iter().enumerate() {
                    p.set(l, r, *t);
                }
                p
            })
            .collect();
        let mut n = 0u32;
        let r = rate(repeat, rays.len(), || {
            n = packets
                .iter()
                .map(|p| {
                    if any_hit {
                        packed.occluded8(&scene.geometry, p)
                    } else {
                        packed.intersect8(&scene.geometry, p).found
                    }
                })
                .map(u32::count_ones)
                .sum();
        });
        let verdict = if any_hit { "blocked" } else { "hit" };
        println!("  {what} rays in packets of {PACKET}: {r:.2} Mrays/s ({n} {verdict})");
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (scene, what, repeat, rays, any_hit);
}

/// Median throughput in Mrays/s of `f`, which traces `n` rays.
fn rate(repeat: usize, n: usize, mut f: impl FnMut()) -> f64 {
    let times: Vec<f64> = (0..repeat)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .collect();
    n as f64 / median(times) / 1e6
}
