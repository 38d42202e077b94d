//! Eight paths in flight: the path integrator with eight samples' paths advanced
//! together. In scenes traced by brute force ([`PackedTriangles`]) the ray queries of
//! the eight paths are answered together by the packet queries of `accel/ray_packets.rs`;
//! elsewhere (the kd-tree) one by one.
//!
//! Each lane holds one sample's path. A round traces the closest hits of all lanes'
//! segments at once, lets the paths scatter at their hits, traces the shadow rays of all
//! lanes' light samples at once, and adds their contributions. A path that ends leaves
//! its radiance in the film and its lane takes the tile's next sample.
//!
//! Scattering takes one of two routes per lane. The common case, a diffuse or glossy
//! surface without texture in a scene of at most 16 lights, runs
//! eight lanes at once ([`scatter_wide`]): the one-path code's operations in the same
//! order, on the eight-lane types of `simd.rs`, with each step's wide twin next to its
//! scalar original. Every other lane runs the one-path [`PathState::scatter`] itself. Either
//! way a sample's radiance is the same bits as with [`li`](super::path::li) (the
//! render-variant test in `render.rs` holds them equal), and the film's fixed-point sums
//! do not depend on the order in which samples end.

use glam::{Vec2, Vec3};

use super::path::{Options, PathState, ShadowQuery, Strategy, area_light_emission, emitter_weight, transmittance};
use super::{RayCount, aov};
use crate::accel::ray_packets::{PACKET, PacketHits, RayPacket};
use crate::accel::triangle_blocks::PackedTriangles;
use crate::bsdf::Bsdf;
use crate::bsdf::blinn_phong::{BlinnPhong, BlinnPhongW};
use crate::bsdf::lambert::LambertW;
use crate::film::{Accumulation, FirstHit, SampleRange, Tile};
use crate::geometry::{FrameW, Ray, offset_origin_wide};
use crate::material::Material;
use crate::sampler::{Sampler, SamplerLanes};
use crate::sampling::wide;
use crate::scene::Scene;
use crate::simd::{F8, M8, Simd, U8, V2w, V3w, W, each};

/// Eight paths' state: lane by lane a [`PathState`].
struct Paths {
    origin: V3w,
    dir: V3w,
    l: V3w,
    beta: V3w,
    prev_pdf: F8,
    prev_delta: M8,
    prev_p: V3w,
    depth: U8,
}

impl Paths {
    #[inline(always)]
    fn get(&self, l: usize) -> PathState {
        PathState {
            ray: Ray::new(self.origin.get(l), self.dir.get(l)),
            l: self.l.get(l),
            beta: self.beta.get(l),
            prev_pdf: self.prev_pdf.0[l],
            prev_delta: self.prev_delta.0[l] != 0,
            prev_p: self.prev_p.get(l),
            depth: self.depth.0[l],
        }
    }

    #[inline(always)]
    fn set(&mut self, l: usize, s: &PathState) {
        self.origin.set(l, s.ray.origin);
        self.dir.set(l, s.ray.dir);
        self.l.set(l, s.l);
        self.beta.set(l, s.beta);
        self.prev_pdf.0[l] = s.prev_pdf;
        self.prev_delta.0[l] = u32::from(s.prev_delta).wrapping_neg();
        self.prev_p.set(l, s.prev_p);
        self.depth.0[l] = s.depth;
    }
}

/// Eight lanes' light samples waiting for shadow rays: lane by lane a [`ShadowQuery`].
struct Shadows {
    /// Lanes with a light sample.
    pending: u32,
    /// Of those, the lanes with a shadow ray (the others' samples lie at the shading
    /// point itself and are visible without one).
    traced: u32,
    origin: V3w,
    dir: V3w,
    tmax: F8,
    unshadowed: V3w,
    weight: F8,
    pdf: F8,
}

impl Shadows {
    #[inline(always)]
    fn put(&mut self, l: usize, q: &ShadowQuery) {
        self.pending |= 1 << l;
        if let Some((ray, tmax)) = q.ray {
            self.traced |= 1 << l;
            self.origin.set(l, ray.origin);
            self.dir.set(l, ray.dir);
            self.tmax.0[l] = tmax;
        }
        self.unshadowed.set(l, q.unshadowed);
        self.weight.0[l] = q.weight;
        self.pdf.0[l] = q.pdf;
    }

    #[inline(always)]
    fn get(&self, l: usize) -> ShadowQuery {
        ShadowQuery {
            ray: (self.traced & (1 << l) != 0).then(|| (Ray::new(self.origin.get(l), self.dir.get(l)), self.tmax.0[l])),
            unshadowed: self.unshadowed.get(l),
            weight: self.weight.0[l],
            pdf: self.pdf.0[l],
        }
    }
}

/// The lanes of a round: those holding a path, and of those the ones whose first
/// segment (the camera ray) is being scattered and whose first-hit layers are wanted.
#[derive(Clone, Copy)]
struct Lanes {
    live: u32,
    fresh: u32,
}

/// What the wide route needs of a material.
#[derive(Clone, Copy)]
struct WideMaterial {
    /// Diffuse or glossy, opaque, untextured: the wide route takes it.
    ok: bool,
    /// The Blinn-Phong lobes of a glossy material; `None` for a diffuse one.
    glossy: Option<BlinnPhong>,
    kd: Vec3,
    emissive: bool,
    /// The albedo layer's value.
    albedo: Vec3,
}

impl WideMaterial {
    fn of(scene: &Scene) -> Vec<WideMaterial> {
        scene
            .materials
            .iter()
            .map(|m| {
                let (glossy, kd) = match m.bsdf {
                    Bsdf::Diffuse { kd } => (None, kd),
                    Bsdf::Glossy { kd, ks, exponent } => (Some(BlinnPhong::new(kd, ks, exponent)), Vec3::ZERO),
                    _ => (None, Vec3::ZERO),
                };
                let albedo = aov::albedo(&m.bsdf);
                WideMaterial { ok: Self::takes(scene, m), glossy, kd, emissive: m.is_emissive(), albedo }
            })
            .collect()
    }

    /// Whether the wide route takes surfaces of material `m` in `scene`.
    fn takes(scene: &Scene, m: &Material) -> bool {
        scene.lights.wide_ok()
            && !scene.has_cutouts
            && matches!(m.bsdf, Bsdf::Diffuse { .. } | Bsdf::Glossy { .. })
            && m.opacity >= 1.0
            && m.kd_texture.is_none()
            && m.maps.is_empty()
            && m.mix.is_none()
    }
}

/// How a round's rays are traced: by the packet queries where the scene is traced by
/// brute force and the CPU has AVX2, else one by one with the scene's own queries (the
/// kd-tree); the same answers either way.
enum Queries<'a> {
    Packets(&'a PackedTriangles),
    OneByOne,
}

impl Queries<'_> {
    #[inline(always)]
    fn intersect(&self, scene: &Scene, rays: &RayPacket) -> PacketHits {
        match self {
            Queries::Packets(packed) => packed.intersect8(&scene.geometry, rays),
            Queries::OneByOne => {
                let mut out = PacketHits { t: [0.0; W], u: [0.0; W], v: [0.0; W], prim: [0; W], found: 0 };
                for l in each(rays.active) {
                    if let Some(h) = scene.intersect(&rays.ray(l), rays.tmax[l]) {
                        (out.t[l], out.u[l], out.v[l], out.prim[l]) = (h.t, h.u, h.v, h.prim);
                        out.found |= 1 << l;
                    }
                }
                out
            }
        }
    }

    #[inline(always)]
    fn occluded(&self, scene: &Scene, rays: &RayPacket) -> u32 {
        match self {
            Queries::Packets(packed) => packed.occluded8(&scene.geometry, rays),
            Queries::OneByOne => {
                each(rays.active).fold(0, |m, l| m | (u32::from(scene.occluded(&rays.ray(l), rays.tmax[l])) << l))
            }
        }
    }
}

/// Whether eight paths at a time beat one: where the scene is traced by brute force
/// with AVX2 (packet queries), or some of its surfaces take the wide route (lights
/// chosen per point, no cutouts, a diffuse or glossy untextured material). Otherwise
/// every lane would run the one-path code anyway, with the lanes' bookkeeping on top.
pub(crate) fn pays(scene: &Scene) -> bool {
    scene.packed.as_ref().is_some_and(|p| p.packets()) || scene.materials.iter().any(|m| WideMaterial::takes(scene, m))
}

/// Every sample of every pixel of `tile` with the path integrator, eight at a time.
/// Inlined into the render loop's instruction-set variants (`render.rs`), like [`li`].
///
/// [`li`]: super::path::li
#[inline(always)]
// Long on purpose: The eight-path loop: refill idle lanes, trace, scatter, trace shadows, retire; one inlined loop so the packet state stays in registers.
pub(crate) fn render_unit(
    simd: Simd,
    scene: &Scene,
    opt: &Options,
    tile: Tile,
    samples: SampleRange,
) -> (Accumulation, RayCount) {
    let queries = match &scene.packed {
        Some(packed) if packed.packets() => Queries::Packets(packed),
        _ => Queries::OneByOne,
    };
    let layers = scene.settings.aovs;
    let mut acc = Accumulation::with_layers(tile, layers);
    // With layers: each lane's first hit, taken from its camera ray's intersection.
    let mut firsts = [FirstHit::default(); PACKET];
    let mut fresh = 0u32;
    let mut count = RayCount::default();
    let cam = &scene.camera;
    let seed = scene.settings.seed;
    let materials = WideMaterial::of(scene);
    let per_pixel = u64::from(samples.len());
    let total = tile.pixel_count() as u64 * per_pixel;
    let mut next = 0u64;
    let zero = simd.v3(Vec3::ZERO);
    let mut paths = Paths {
        origin: zero,
        dir: simd.v3(Vec3::Z),
        l: zero,
        beta: zero,
        prev_pdf: simd.zero(),
        prev_delta: simd.none(),
        prev_p: zero,
        depth: simd.splat_u(0),
    };
    let mut samplers = SamplerLanes::new(simd);
    let mut pixels = [0usize; PACKET];
    // Lanes holding a path. Lanes are arrays with masks, not options: which lanes hold
    // a path, have a shadow ray or end is random, and branches on it mispredict.
    let mut live = 0u32;
    loop {
        // Idle lanes take the next samples, pixel by pixel.
        let mut idle = !live & ((1 << PACKET) - 1);
        // Pinhole lanes' film positions; their directions are made eight at once below.
        let (mut film_x, mut film_y, mut born) = ([0.0; PACKET], [0.0; PACKET], 0u32);
        while idle != 0 && next < total {
            let l = idle.trailing_zeros() as usize;
            idle &= idle - 1;
            let (pixel, s) = ((next / per_pixel) as u32, (next % per_pixel) as u32);
            next += 1;
            let (x, y) = (tile.x0 + pixel % tile.width, tile.y0 + pixel / tile.width);
            let mut sampler = Sampler::new(seed, x, y, samples.start + s);
            // Box filter: uniform positions within the pixel (as `render.rs`'s loop).
            let film = Vec2::new(x as f32, y as f32) + sampler.next_2d();
            if cam.has_lens() {
                let lens = sampler.next_2d();
                paths.set(l, &PathState::new(cam.generate_ray(film, lens)));
            } else {
                (film_x[l], film_y[l]) = (film.x, film.y);
                born |= 1 << l;
                paths.set(l, &PathState::new(Ray::new(cam.position, Vec3::Z)));
            }
            samplers.set(l, &sampler);
            pixels[l] = pixel as usize;
            live |= 1 << l;
            fresh |= 1 << l;
        }
        if born != 0 {
            let dirs = cam.pinhole_dirs(V2w { x: simd.f8(film_x), y: simd.f8(film_y) });
            paths.dir = simd.mask(born).select3(dirs, paths.dir);
        }
        if live == 0 {
            return (acc, count);
        }

        // Idle lanes hold an old ray, which is harmless; the mask leaves them out.
        let rays = RayPacket {
            origin: [paths.origin.x.0, paths.origin.y.0, paths.origin.z.0],
            dir: [paths.dir.x.0, paths.dir.y.0, paths.dir.z.0],
            tmax: [f32::INFINITY; PACKET],
            active: live,
        };
        count.rays += u64::from(live.count_ones());
        let hits = queries.intersect(scene, &rays);
        let lanes = Lanes { live, fresh: if layers { fresh } else { 0 } };
        fresh = 0;

        let mut shadows = Shadows {
            pending: 0,
            traced: 0,
            origin: zero,
            dir: zero,
            tmax: simd.zero(),
            unshadowed: zero,
            weight: simd.zero(),
            pdf: simd.one(),
        };
        let go_on = scatter(scene, &materials, &mut paths, &mut samplers, &hits, lanes, opt, &mut shadows, &mut firsts);

        // With stochastic opacity a shadow ray walks through the surfaces, one lane
        // alone; samples at the shading point need no ray.
        let packet = if scene.has_cutouts { 0 } else { shadows.traced };
        for l in each(shadows.pending & !packet) {
            let q = shadows.get(l);
            let mut path = paths.get(l);
            path.add_light(&q, transmittance(scene, &q, &mut count));
            paths.set(l, &path);
        }
        if packet != 0 {
            let rays = RayPacket {
                origin: [shadows.origin.x.0, shadows.origin.y.0, shadows.origin.z.0],
                dir: [shadows.dir.x.0, shadows.dir.y.0, shadows.dir.z.0],
                tmax: shadows.tmax.0,
                active: packet,
            };
            count.rays += u64::from(packet.count_ones());
            let blocked = queries.occluded(scene, &rays);
            // `PathState::add_light` with transmittance 1 for the lanes not blocked.
            let lit = simd.mask(packet & !blocked);
            let add = shadows.unshadowed * (1.0 * shadows.weight / shadows.pdf);
            paths.l = lit.select3(paths.l + add, paths.l);
        }

        let ended = live & !go_on;
        for l in each(ended) {
            acc.add_sample_at(pixels[l], opt.limit(paths.l.get(l)), &firsts[l]);
        }
        live &= go_on;
    }
}

/// The lanes `live` scatter at their hits: the lanes the wide route takes run
/// [`scatter_wide`], the others [`PathState::scatter`] one by one. Fills `shadows` and
/// returns the lanes whose paths go on.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn scatter(
    scene: &Scene,
    materials: &[WideMaterial],
    paths: &mut Paths,
    samplers: &mut SamplerLanes,
    hits: &PacketHits,
    lanes: Lanes,
    opt: &Options,
    shadows: &mut Shadows,
    firsts: &mut [FirstHit; PACKET],
) -> u32 {
    let Lanes { live, fresh } = lanes;
    // Camera rays that escaped: nothing there.
    for l in each(fresh & !hits.found) {
        firsts[l] = FirstHit::default();
    }
    let g = &scene.geometry;
    let ntri = g.triangle_count();
    let (mut tri, mut sph, mut one, mut go_on) = (0u32, 0u32, 0u32, 0u32);
    let simd = paths.depth.simd();
    let mut material = simd.splat_u(0);
    for l in each(live & hits.found) {
        let prim = hits.prim[l] as usize;
        let lane = 1 << l;
        if prim >= g.prim_count() {
            // A copy of an instanced mesh: the one-path code moves it to the world.
            one |= lane;
            continue;
        }
        let (m, sphere) = if prim < ntri { (g.material(prim), false) } else { (g.spheres[prim - ntri].material, true) };
        material.0[l] = m;
        let wide = materials[m as usize].ok;
        match (wide, sphere) {
            (true, false) => tri |= lane,
            (true, true) => sph |= lane,
            (false, _) => one |= lane,
        }
    }
    // Misses: the environment or area lights (a lane alone), or, in scenes without
    // either, the end.
    if scene.lights.environment().is_some() || scene.lights.has_areas() {
        one |= live & !hits.found;
    }
    // Area lights on the wide lanes' segments, as `PathState::scatter` begins (lane by
    // lane: they are few).
    if scene.lights.has_areas() {
        for l in each(tri | sph) {
            let depth = paths.depth.0[l];
            if depth == 0 {
                continue;
            }
            let ray = Ray::new(paths.origin.get(l), paths.dir.get(l));
            let prev = (depth, paths.prev_delta.0[l] != 0, paths.prev_pdf.0[l], paths.prev_p.get(l));
            if let Some(e) = area_light_emission(scene, &ray, hits.t[l], prev, opt) {
                paths.l.set(l, paths.l.get(l) + paths.beta.get(l) * e);
            }
        }
    }
    for l in each(one) {
        let (mut path, mut sampler) = (paths.get(l), samplers.get(l));
        let first = (fresh & (1 << l) != 0).then(|| &mut firsts[l]);
        let (q, go) = path.scatter(scene, hits.get(l), &mut sampler, opt, first);
        paths.set(l, &path);
        samplers.set(l, &sampler);
        if let Some(q) = q {
            shadows.put(l, &q);
        }
        go_on |= u32::from(go) << l;
    }
    if tri | sph != 0 {
        let hit = (simd.u8(hits.prim), simd.f8(hits.t), simd.f8(hits.u), simd.f8(hits.v));
        go_on |= scatter_wide(
            scene,
            materials,
            paths,
            samplers,
            hit,
            simd.mask(tri),
            simd.mask(sph),
            material,
            opt,
            shadows,
            (fresh, firsts),
        );
    }
    go_on
}

/// [`PathState::scatter`] for the lanes `tri | sph` at once: hits on triangles and on
/// spheres, with diffuse or glossy untextured materials, in a
/// scene whose lights are chosen per point ([`crate::light::LightSet::wide_ok`]). The same steps and
/// operations, on eight lanes (see the module comment); returns the lanes whose paths
/// go on.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
// Long on purpose: The twin of path.rs's `scatter`, step for step in the same order, so that the two can be read side by side; one inlined function keeps the lanes in registers.
fn scatter_wide(
    scene: &Scene,
    materials: &[WideMaterial],
    paths: &mut Paths,
    samplers: &mut SamplerLanes,
    hit: (U8, F8, F8, F8),
    tri: M8,
    sph: M8,
    material: U8,
    opt: &Options,
    shadows: &mut Shadows,
    (fresh, firsts): (u32, &mut [FirstHit; PACKET]),
) -> u32 {
    let (use_nee, use_bsdf_hits) = match opt.strategy {
        Strategy::Mis => (true, true),
        Strategy::LightOnly => (true, false),
        Strategy::BsdfOnly => (false, true),
    };
    let lanes = tri | sph;
    let simd = lanes.simd();
    let (p, ng, ns) = scene.interaction_wide(paths.origin, paths.dir, hit, tri, sph);
    let wo = -paths.dir;
    let mat = |l: usize| &materials[material.0[l] as usize];
    // The first-hit layers (as `aov::surface`), from this interaction.
    for l in each(fresh & lanes.bits()) {
        let depth = hit.1.0[l] * paths.dir.get(l).length();
        firsts[l] = FirstHit { albedo: mat(l).albedo, normal: ns.get(l), depth: Some(depth) };
    }

    // One-sided emission: only the front face emits. (Rare: lane by lane.)
    let front = ng.dot(wo).gt(0.0);
    for l in each((lanes & front).bits()) {
        if !mat(l).emissive {
            continue;
        }
        let (prev_p, dir, pl) = (paths.prev_p.get(l), paths.dir.get(l), p.get(l));
        let w = emitter_weight(paths.depth.0[l], paths.prev_delta.0[l] != 0, opt.strategy, paths.prev_pdf.0[l], || {
            // What NEE at prev_p would have had for this light (0 if it never could).
            scene
                .lights
                .light_of_prim(hit.0.0[l])
                .map_or(0.0, |li| scene.lights.pmf_at(prev_p, li) * scene.lights.pdf_li(li, prev_p, dir, pl))
        });
        let emission = scene.materials[material.0[l] as usize].emission;
        paths.l.set(l, paths.l.get(l) + paths.beta.get(l) * emission * w);
    }

    paths.depth = lanes.select_u(paths.depth.map(|d| d + 1), paths.depth);
    let alive = if opt.max_depth >= 0 { lanes & !paths.depth.ge(simd.splat_u(opt.max_depth as u32)) } else { lanes };
    if !alive.any() {
        return 0;
    }
    let glossy = alive & simd.mask_from_bools(std::array::from_fn(|l| mat(l).glossy.is_some()));
    let diffuse = alive & !glossy;
    let lambert = LambertW { kd: simd.v3_from_fn(|l| mat(l).kd) };
    let blinn_phong = glossy
        .any()
        .then(|| BlinnPhongW::from_fn(simd, |l| mat(l).glossy.unwrap_or(BlinnPhong::new(Vec3::ZERO, Vec3::ZERO, 0.0))));
    // Reflection-only surfaces are two-sided: shade the side the ray arrives from.
    let back = ng.dot(wo).lt(0.0);
    let (ng, ns) = (back.select3(-ng, ng), back.select3(-ns, ns));
    let frame = FrameW::from_normal(ns);
    let wo_local = frame.to_local(wo);

    // Next-event estimation (`PathState::scatter`'s): one 2D sample picks the light and
    // the point on it.
    if use_nee {
        let u = samplers.next_2d(alive);
        let (light, pmf, ux, chosen) = scene.lights.select_at_wide(p, u.x);
        let ls = scene.lights.sample_li_wide(light, p, V2w { x: ux, y: u.y }, alive & chosen);
        let (wi, li, light_pdf, some, delta) = (ls.wi, ls.li, ls.pdf, ls.some, ls.delta);
        let reflects_above = ng.dot(wi).gt(0.0);
        let cond = some & light_pdf.gt(0.0) & li.max_element().gt(0.0) & reflects_above;
        let wi_local = frame.to_local(wi);
        let (mut f, mut bsdf_pdf) = (lambert.eval(wo_local, wi_local), lambert.pdf(wo_local, wi_local));
        if let Some(bp) = &blinn_phong {
            let on = cond & glossy;
            if on.any() {
                let (fg, pg) = bp.eval_pdf(wo_local, wi_local, on);
                (f, bsdf_pdf) = (glossy.select3(fg, f), glossy.select(pg, bsdf_pdf));
            }
        }
        let keep = cond & f.max_element().gt(0.0);
        if keep.any() {
            // A light at a point (delta) cannot be hit by BSDF sampling: no MIS.
            let area_pdf = pmf * light_pdf;
            let pdf = delta.select(pmf, area_pdf);
            let w = if use_bsdf_hits { wide::power_heuristic(1.0, area_pdf, 1.0, bsdf_pdf) } else { simd.one() };
            let w = delta.select(simd.one(), w);
            let origin = offset_origin_wide(p, ng, wi);
            let d = ls.target - origin;
            let dist = d.length();
            let far = ls.at_infinity;
            shadows.origin = keep.select3(origin, shadows.origin);
            shadows.dir = keep.select3(far.select3(wi, d / dist), shadows.dir);
            shadows.tmax = keep.select(far.select(simd.splat(f32::INFINITY), dist * (1.0 - 1e-5)), shadows.tmax);
            shadows.unshadowed = keep.select3(paths.beta * f * li, shadows.unshadowed);
            shadows.weight = keep.select(w, shadows.weight);
            shadows.pdf = keep.select(pdf, shadows.pdf);
            shadows.pending |= keep.bits();
            shadows.traced |= (keep & (far | !dist.le(0.0))).bits();
        }
    }

    // BSDF sampling: the next segment. Lambert draws a direction; the glossy BSDF a lobe
    // choice, then a direction.
    let u_lobe = if glossy.any() { samplers.next_1d(glossy) } else { simd.zero() };
    let u = samplers.next_2d(alive);
    let (mut wi, mut pdf, mut ok) = lambert.sample(wo_local, u, diffuse);
    let mut weight = lambert.kd;
    if let Some(bp) = &blinn_phong {
        let (wg, weight_g, pg, ok_g) = bp.sample(wo_local, u_lobe, u, glossy);
        (wi, weight, pdf, ok) =
            (glossy.select3(wg, wi), glossy.select3(weight_g, weight), glossy.select(pg, pdf), ok | ok_g);
    }
    let wi = frame.to_world(wi);
    // A reflection that dips below the geometric surface would leak light through it.
    let beta = paths.beta * weight;
    let go = ok & !ng.dot(wi).le(0.0) & beta.max_element().gt(0.0) & beta.is_finite();
    paths.beta = go.select3(beta, paths.beta);
    paths.prev_pdf = go.select(pdf, paths.prev_pdf);
    paths.prev_delta = go.select_m(simd.none(), paths.prev_delta);
    paths.prev_p = go.select3(p, paths.prev_p);
    paths.origin = go.select3(offset_origin_wide(p, ng, wi), paths.origin);
    paths.dir = go.select3(wi, paths.dir);

    // Russian roulette.
    let rr = go & paths.depth.ge(simd.splat_u(opt.rr_depth));
    if !rr.any() {
        return go.bits();
    }
    let q = paths.beta.max_element().min(0.95);
    let dies = rr & samplers.next_1d(rr).ge(q);
    paths.beta = (rr & !dies).select3(paths.beta / q, paths.beta);
    (go & !dies).bits()
}
