//! The look-at camera of the report: position, look-at point, an "up" hint corrected to
//! be orthogonal to the forward direction, right = forward × up, a vertical field of view
//! and a pixel grid with row 0 at the top. Optional thin lens for depth of field.

use glam::{Vec2, Vec3};

use crate::geometry::Ray;
use crate::math;
use crate::simd::{V2w, V3w};

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Camera {
    pub position: Vec3,
    pub forward: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    pub width: u32,
    pub height: u32,
    /// tan(fov/2): the half-height of the image plane at distance 1.
    tan_half_fov: f32,
    /// Lens radius (0 = pinhole) and distance of the plane in focus.
    aperture: f32,
    focus_distance: f32,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraError {
    #[error("coincides with camera.position")]
    NoDirection,
    #[error("is parallel to the viewing direction")]
    UpParallel,
    #[error("must be in (0, 180) degrees, got {0}")]
    Fov(f32),
    #[error("must be at least 1 (the image is {0}×{1})")]
    Size(u32, u32),
    #[error("aperture must be ≥ 0 and focus_distance > 0")]
    Lens,
}

impl CameraError {
    /// The scene-file field the error is about.
    pub fn field(&self) -> &'static str {
        match self {
            CameraError::NoDirection => "camera.look_at",
            CameraError::UpParallel => "camera.up",
            CameraError::Fov(_) => "camera.fov",
            CameraError::Size(0, _) => "camera.width",
            CameraError::Size(..) => "camera.height",
            CameraError::Lens => "camera.aperture",
        }
    }
}

impl Camera {
    pub fn look_at(
        position: Vec3,
        look_at: Vec3,
        up_hint: Vec3,
        fov_degrees: f32,
        width: u32,
        height: u32,
    ) -> Result<Self, CameraError> {
        let forward = (look_at - position).normalize_or_zero();
        if forward == Vec3::ZERO || !forward.is_finite() {
            return Err(CameraError::NoDirection);
        }
        let right = forward.cross(up_hint).normalize_or_zero();
        if right == Vec3::ZERO || !right.is_finite() {
            return Err(CameraError::UpParallel);
        }
        if !(fov_degrees > 0.0 && fov_degrees < 180.0) {
            return Err(CameraError::Fov(fov_degrees));
        }
        if width == 0 || height == 0 {
            return Err(CameraError::Size(width, height));
        }
        // The corrected up: orthogonal to forward and right, on the side of the hint.
        let up = right.cross(forward);
        Ok(Self {
            position,
            forward,
            right,
            up,
            width,
            height,
            tan_half_fov: math::tan(fov_degrees.to_radians() * 0.5),
            aperture: 0.0,
            focus_distance: (look_at - position).length(),
        })
    }

    /// Adds a thin lens of radius `aperture` focused at `focus_distance` along forward.
    pub fn with_lens(mut self, aperture: f32, focus_distance: f32) -> Result<Self, CameraError> {
        if !(aperture >= 0.0 && focus_distance > 0.0 && aperture.is_finite() && focus_distance.is_finite()) {
            return Err(CameraError::Lens);
        }
        self.aperture = aperture;
        self.focus_distance = focus_distance;
        Ok(self)
    }

    pub fn has_lens(&self) -> bool {
        self.aperture > 0.0
    }

    /// The ray through film position `film` (in pixels: x right, y down, (0,0) the top
    /// left corner of the image). `lens` is a uniform sample in [0,1)², used only with a
    /// thin lens.
    #[inline]
    pub fn generate_ray(&self, film: Vec2, lens: Vec2) -> Ray {
        let aspect = self.width as f32 / self.height as f32;
        let sx = (2.0 * film.x / self.width as f32 - 1.0) * self.tan_half_fov * aspect;
        let sy = (1.0 - 2.0 * film.y / self.height as f32) * self.tan_half_fov;
        let dir = (self.forward + sx * self.right + sy * self.up).normalize();
        if self.aperture <= 0.0 {
            return Ray::new(self.position, dir);
        }
        // Points at distance focus_distance along forward stay sharp.
        let focus = self.position + dir * (self.focus_distance / dir.dot(self.forward));
        let d = crate::sampling::concentric_disk(lens) * self.aperture;
        let origin = self.position + d.x * self.right + d.y * self.up;
        Ray::new(origin, (focus - origin).normalize())
    }

    /// Eight pinhole rays' directions at once (their origin is `position`): lane by lane
    /// [`Camera::generate_ray`]'s direction without a lens, bit for bit, since each lane
    /// goes through the same operations in the same order. Refilling the renderer's
    /// lanes one scalar ray at a time waited on each ray's divisions and square root.
    #[inline(always)]
    pub fn pinhole_dirs(&self, film: V2w) -> V3w {
        let simd = film.x.simd();
        let aspect = self.width as f32 / self.height as f32;
        let sx = (2.0 * film.x / self.width as f32 - 1.0) * self.tan_half_fov * aspect;
        let sy = (1.0 - 2.0 * film.y / self.height as f32) * self.tan_half_fov;
        (simd.v3(self.forward) + sx * simd.v3(self.right) + sy * simd.v3(self.up)).normalize()
    }

    /// World to camera space as OpenEXR's `worldToCamera` defines it: origin at the
    /// camera, +x right, +y up, +z the viewing direction (left-handed). Column vectors
    /// (`m * p`); OpenEXR's row-vector matrix is the same numbers in column order.
    pub fn world_to_camera(&self) -> glam::Mat4 {
        let row = |axis: Vec3| axis.extend(-axis.dot(self.position));
        glam::Mat4::from_cols(row(self.right), row(self.up), row(self.forward), glam::Vec4::W).transpose()
    }

    /// World to OpenEXR's normalised device coordinates: (0, 0) the top left corner of
    /// the image, (1, 1) the bottom right, after division by w (the distance along the
    /// viewing direction). Column vectors, as [`Camera::world_to_camera`].
    pub fn world_to_ndc(&self) -> glam::Mat4 {
        let aspect = self.width as f32 / self.height as f32;
        let (sx, sy) = (0.5 / (self.tan_half_fov * aspect), 0.5 / self.tan_half_fov);
        let projection = glam::Mat4::from_cols(
            glam::Vec4::new(sx, 0.0, 0.0, 0.0),
            glam::Vec4::new(0.0, -sy, 0.0, 0.0),
            glam::Vec4::new(0.5, 0.5, 0.0, 1.0),
            glam::Vec4::new(0.0, 0.0, 1.0, 0.0),
        );
        projection * self.world_to_camera()
    }

    /// Projects a world point to film coordinates (pixels), if it is in front.
    pub fn project(&self, p: Vec3) -> Option<Vec2> {
        let v = p - self.position;
        let z = v.dot(self.forward);
        if z <= 0.0 {
            return None;
        }
        let aspect = self.width as f32 / self.height as f32;
        let sx = v.dot(self.right) / z / (self.tan_half_fov * aspect);
        let sy = v.dot(self.up) / z / self.tan_half_fov;
        Some(Vec2::new((sx + 1.0) * 0.5 * self.width as f32, (1.0 - sy) * 0.5 * self.height as f32))
    }
}

#[cfg(test)]
#[allow(clippy::disallowed_methods)] // values checked, not platform-free bits
mod tests {
    #[test]
    fn exr_matrices_agree_with_the_projection() {
        let cam = Camera::look_at(Vec3::new(1.0, 2.0, 3.0), Vec3::new(0.5, 1.0, -2.0), Vec3::Y, 50.0, 64, 48).unwrap();
        let p = Vec3::new(0.3, 1.4, -1.0);
        let c = cam.world_to_camera().transform_point3(p);
        let v = p - cam.position;
        assert!((c - Vec3::new(v.dot(cam.right), v.dot(cam.up), v.dot(cam.forward))).length() < 1e-5);
        let h = cam.world_to_ndc() * p.extend(1.0);
        let ndc = glam::Vec2::new(h.x / h.w, h.y / h.w);
        let film = cam.project(p).unwrap() / glam::Vec2::new(64.0, 48.0);
        assert!((ndc - film).length() < 1e-5, "{ndc} {film}");
    }

    use super::*;

    fn cam() -> Camera {
        Camera::look_at(Vec3::new(0.0, 0.0, -5.0), Vec3::ZERO, Vec3::Y, 60.0, 200, 100).unwrap()
    }

    #[test]
    fn right_is_forward_cross_up_and_lands_right() {
        let c = cam();
        assert!((c.right - Vec3::Z.cross(Vec3::Y)).length() < 1e-6);
        // A point to the camera's right and above the centre: right half, top half.
        let p = c.project(c.position + 5.0 * c.forward + 1.0 * c.right + 0.5 * c.up).unwrap();
        assert!(p.x > 100.0 && p.y < 50.0, "{p}");
    }

    #[test]
    fn centre_pixel_looks_forward_and_corners_span_fov() {
        let c = cam();
        let r = c.generate_ray(Vec2::new(100.0, 50.0), Vec2::ZERO);
        assert!((r.dir - c.forward).length() < 1e-6);
        let top = c.generate_ray(Vec2::new(100.0, 0.0), Vec2::ZERO);
        assert!((top.dir.angle_between(c.forward).to_degrees() - 30.0).abs() < 1e-3);
        assert!(top.dir.dot(c.up) > 0.0);
        // project() inverts generate_ray().
        let f = Vec2::new(37.25, 81.5);
        let q = c.project(c.generate_ray(f, Vec2::ZERO).at(3.0)).unwrap();
        assert!((q - f).length() < 1e-3);
    }

    /// The eight-lane pinhole directions are the one-ray directions bit for bit, over
    /// film positions across the frame (and outside it) and several cameras.
    #[test]
    fn pinhole_dirs_are_generate_ray_bits() {
        let simd = crate::simd::tests::require_avx2();
        let mut h = 11u64;
        let mut next = || {
            h = h.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (h >> 40) as f32 / (1u64 << 24) as f32
        };
        let cams = [
            cam(),
            Camera::look_at(Vec3::new(278.0, 273.0, -800.0), Vec3::new(278.0, 273.0, 0.0), Vec3::Y, 39.3, 256, 256)
                .unwrap(),
            Camera::look_at(Vec3::new(1.0, -2.0, 3.5), Vec3::new(-0.3, 0.7, 0.1), Vec3::Z, 95.0, 1919, 1079).unwrap(),
        ];
        let mut differ = 0;
        for c in &cams {
            for _ in 0..4000 {
                let film: [Vec2; 8] = std::array::from_fn(|_| {
                    Vec2::new(next() * 1.2 - 0.1, next() * 1.2 - 0.1) * Vec2::new(c.width as f32, c.height as f32)
                });
                let wide = c.pinhole_dirs(V2w { x: simd.f8(film.map(|f| f.x)), y: simd.f8(film.map(|f| f.y)) });
                for (l, f) in film.iter().enumerate() {
                    let one = c.generate_ray(*f, Vec2::ZERO).dir;
                    assert_eq!(wide.get(l).to_array().map(f32::to_bits), one.to_array().map(f32::to_bits), "{f}");
                    differ += usize::from(one != c.forward);
                }
            }
        }
        assert!(differ > 90_000, "the film positions must spread over the frame");
    }

    #[test]
    fn up_hint_is_corrected_and_bad_input_rejected() {
        let c = Camera::look_at(Vec3::ZERO, Vec3::new(0.0, -1.0, 1.0), Vec3::Y, 40.0, 10, 10).unwrap();
        assert!(c.up.dot(c.forward).abs() < 1e-6 && c.up.y > 0.0);
        assert_eq!(Camera::look_at(Vec3::ZERO, Vec3::ZERO, Vec3::Y, 40.0, 1, 1), Err(CameraError::NoDirection));
        assert_eq!(Camera::look_at(Vec3::ZERO, Vec3::Y, Vec3::Y, 40.0, 1, 1), Err(CameraError::UpParallel));
        assert_eq!(Camera::look_at(Vec3::ZERO, Vec3::Z, Vec3::Y, 180.0, 1, 1), Err(CameraError::Fov(180.0)));
    }

    #[test]
    fn thin_lens_keeps_focus_plane_sharp() {
        let c = cam().with_lens(0.5, 5.0).unwrap();
        let f = Vec2::new(60.0, 20.0);
        // The lens sample (0.5, 0.5) is the centre of the lens: the pinhole ray.
        let pinhole = c.generate_ray(f, Vec2::splat(0.5));
        assert_eq!(pinhole.origin, c.position);
        let target = c.position + pinhole.dir * (5.0 / pinhole.dir.dot(c.forward));
        for lens in [Vec2::new(0.1, 0.9), Vec2::new(0.7, 0.3)] {
            let r = c.generate_ray(f, lens);
            let t = (target - r.origin).dot(r.dir);
            assert!((r.at(t) - target).length() < 1e-4);
        }
    }
}
