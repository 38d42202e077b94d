//! The surface's texture-space frame at a hit — ∂p/∂u, ∂p/∂v and the MikkTSpace tangent —
//! for materials with normal or bump maps (the only ones that ask for it).

use glam::{Affine3A, Mat3, Vec2, Vec3};

use super::{PrimRef, Scene, SurfaceHit};
use crate::accel::Hit;
use crate::material::normals::UvFrame;
use crate::shapes::Geometry;

impl Scene {
    /// The frame at `si`, the interaction of `hit`, on the front face's side.
    pub fn uv_frame(&self, hit: &Hit, si: &SurfaceHit) -> UvFrame {
        let b = Vec3::new(1.0 - hit.u - hit.v, hit.u, hit.v);
        if let Some(inst) = &self.instances
            && inst.holds(hit.prim)
        {
            let (inst, mesh, i) = inst.resolve(hit.prim);
            let place = (!inst.identity).then_some((inst.to_world, inst.normal_to_world, inst.mirrored));
            return triangle_frame(&mesh.geometry, i, b, si.ng, place);
        }
        match self.geometry.resolve(hit.prim) {
            PrimRef::Triangle(i) => triangle_frame(&self.geometry, i, b, si.ng, None),
            PrimRef::Sphere(i) => sphere_frame(self.geometry.spheres[i].radius, si.ng),
        }
    }
}

/// ∂p/∂u and ∂p/∂v of a triangle with corners `p` and texture coordinates `uv` (zero when
/// the texture coordinates are degenerate).
pub(crate) fn uv_derivatives(p: [Vec3; 3], uv: [Vec2; 3]) -> (Vec3, Vec3) {
    let (d02, d12) = (uv[0] - uv[2], uv[1] - uv[2]);
    let (p02, p12) = (p[0] - p[2], p[1] - p[2]);
    let det = d02.x * d12.y - d02.y * d12.x;
    if det == 0.0 || !det.is_finite() {
        return (Vec3::ZERO, Vec3::ZERO);
    }
    let inv = 1.0 / det;
    ((d12.y * p02 - d02.y * p12) * inv, (d02.x * p12 - d12.x * p02) * inv)
}

/// Triangle `i` of `g`, placed in the world by `place` (to-world transform, its normal
/// matrix, whether it mirrors) for a copy of an instanced mesh.
fn triangle_frame(g: &Geometry, i: usize, b: Vec3, ng: Vec3, place: Option<(Affine3A, Mat3, bool)>) -> UvFrame {
    let corners = g.triangle(i).map(|p| place.map_or(p, |(m, _, _)| m.transform_point3(p)));
    let (dpdu, dpdv) = g.corner_uvs(i).map_or((Vec3::ZERO, Vec3::ZERO), |uv| uv_derivatives(corners, uv));
    let tangent = g.tangent(i, b).map(|(t, sign)| {
        let n = match g.shading_normals(i) {
            Some([n0, n1, n2]) => b.x * n0 + b.y * n1 + b.z * n2,
            None => {
                let [p0, p1, p2] = *g.triangle(i);
                (p1 - p0).cross(p2 - p0).normalize_or_zero()
            }
        };
        let (t, n, sign) = match place {
            // A mirroring copy turns n × t around: the sign keeps the bitangent's meaning.
            Some((m, nm, mirrored)) => (m.transform_vector3(t), nm * n, if mirrored { -sign } else { sign }),
            None => (t, n, sign),
        };
        // The normal on the front face's side (the bitangent with it).
        if n.dot(ng) < 0.0 { (t, -sign, -n) } else { (t, sign, n) }
    });
    UvFrame { dpdu, dpdv, tangent }
}

/// A sphere of radius `r` at the point with outward normal `n`, for the texture
/// coordinates of `Scene::interaction` (u = atan2(z, x) / 2π, v = acos(y) / π); the
/// tangent follows u, with the bitangent's sign that makes it follow v.
fn sphere_frame(r: f32, n: Vec3) -> UvFrame {
    let (tau, pi) = (std::f32::consts::TAU, std::f32::consts::PI);
    let sin_theta = (n.x * n.x + n.z * n.z).sqrt();
    let dpdu = tau * r * Vec3::new(-n.z, 0.0, n.x);
    let dpdv = if sin_theta > 0.0 {
        pi * r * Vec3::new(n.y * n.x / sin_theta, -sin_theta, n.y * n.z / sin_theta)
    } else {
        Vec3::ZERO
    };
    let tangent = (sin_theta > 0.0).then(|| {
        let sign = if n.cross(dpdu).dot(dpdv) < 0.0 { -1.0 } else { 1.0 };
        (dpdu, sign, n)
    });
    UvFrame { dpdu, dpdv, tangent }
}

#[cfg(test)]
#[allow(clippy::disallowed_methods)]
mod tests {
    use super::*;

    #[test]
    fn derivatives_of_a_triangle_follow_its_texture_coordinates() {
        let p = [Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0), Vec3::new(0.0, 3.0, 0.0)];
        let uv = [Vec2::ZERO, Vec2::X, Vec2::Y];
        let (du, dv) = uv_derivatives(p, uv);
        assert!((du - Vec3::new(2.0, 0.0, 0.0)).length() < 1e-6, "{du}");
        assert!((dv - Vec3::new(0.0, 3.0, 0.0)).length() < 1e-6, "{dv}");
        assert_eq!(uv_derivatives(p, [Vec2::ZERO; 3]), (Vec3::ZERO, Vec3::ZERO));
    }

    #[test]
    fn a_sphere_frame_matches_its_texture_coordinates_by_finite_differences() {
        let uv_of = |n: Vec3| {
            Vec2::new(
                (n.z.atan2(n.x) / std::f32::consts::TAU).rem_euclid(1.0),
                n.y.clamp(-1.0, 1.0).acos() / std::f32::consts::PI,
            )
        };
        let r = 2.0;
        let n = Vec3::new(0.3, 0.4, 0.5).normalize();
        let f = sphere_frame(r, n);
        // Moving along ∂p/∂u by ε changes u by ε and v not at all (to first order).
        let eps = 1e-3;
        for (d, du, dv) in [(f.dpdu, 1.0, 0.0), (f.dpdv, 0.0, 1.0)] {
            let q = (r * n + eps * d).normalize();
            let delta = (uv_of(q) - uv_of(n)) / eps;
            assert!((delta - Vec2::new(du, dv)).length() < 1e-2, "{delta}");
        }
        let (t, sign, nn) = f.tangent.unwrap();
        assert!((sign * nn.cross(t)).dot(f.dpdv) > 0.0);
    }
}
