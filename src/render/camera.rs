//! Pinhole cameras: intrinsics, the optical frame, projection and back-projection.
//!
//! The camera's optical frame is the OpenCV one: x right, y down, z forward along the optical
//! axis. Pixel `(u, v)` covers `[u, u + 1) x [v, v + 1)` in image coordinates, so its centre
//! back-projects as `X = (u + 0.5 - cx) z / fx`, `Y = (v + 0.5 - cy) z / fy`, `Z = z`, with `z`
//! the depth along the optical axis (what the depth image stores).

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub width_px: u32,
    pub height_px: u32,
    pub fx_px: f64,
    pub fy_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
    /// Geometry closer than this along the optical axis is clipped, metres.
    pub near_m: f64,
    /// Geometry farther than this is not drawn (background), metres.
    pub far_m: f64,
    /// Pose of the optical frame in the world.
    pub world_from_camera: Isometry3<f64>,
}

/// The optical frame at `eye` looking along `forward` with the image's up along `up`.
pub fn look_along(eye: Point3<f64>, forward: Vector3<f64>, up: Vector3<f64>) -> Isometry3<f64> {
    let z = forward.normalize();
    let y = (-up + z * up.dot(&z)).normalize();
    let x = y.cross(&z);
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    Isometry3::from_parts(
        Translation3::from(eye.coords),
        UnitQuaternion::from_rotation_matrix(&rotation),
    )
}

impl Camera {
    /// A camera with a vertical field of view, principal point at the image centre.
    pub fn from_fov(
        width_px: u32,
        height_px: u32,
        fovy_rad: f64,
        near_m: f64,
        far_m: f64,
        world_from_camera: Isometry3<f64>,
    ) -> Self {
        let f = f64::from(height_px) / 2.0 / (fovy_rad / 2.0).tan();
        Camera {
            width_px,
            height_px,
            fx_px: f,
            fy_px: f,
            cx_px: f64::from(width_px) / 2.0,
            cy_px: f64::from(height_px) / 2.0,
            near_m,
            far_m,
            world_from_camera,
        }
    }

    /// The reference endoscope (ECM): eye (0.655, 0, 0.777) m looking along
    /// (-0.783, 0, -0.622), 60 deg vertical field of view, 224 x 224, near 4 mm.
    ///
    /// **Ours:** far 0.3 m rather than the reference's nominal 0.2 m: the reference frame shows
    /// the tray's far rim, about 0.24 m from the lens, so its effective far plane lay beyond.
    pub fn endoscope() -> Self {
        let pose = look_along(
            Point3::new(0.655, 0.0, 0.777),
            Vector3::new(-0.783, 0.0, -0.622),
            Vector3::new(-0.622, 0.0, 0.783),
        );
        Camera::from_fov(224, 224, 60f64.to_radians(), 0.004, 0.3, pose)
    }

    /// A wider overview of the whole workspace from above and behind the endoscope.
    pub fn overview() -> Self {
        let eye = Point3::new(0.72, 0.0, 0.86);
        let target = Point3::new(0.54, 0.0, 0.678);
        let forward = target - eye;
        let pose = look_along(eye, forward, Vector3::z());
        Camera::from_fov(224, 224, 70f64.to_radians(), 0.01, 0.6, pose)
    }

    /// The same camera rendering `factor` times more pixels in each direction.
    pub fn scaled(&self, factor: u32) -> Self {
        let k = f64::from(factor.max(1));
        Camera {
            width_px: self.width_px * factor.max(1),
            height_px: self.height_px * factor.max(1),
            fx_px: self.fx_px * k,
            fy_px: self.fy_px * k,
            cx_px: self.cx_px * k,
            cy_px: self.cy_px * k,
            ..*self
        }
    }

    /// Image coordinates (continuous, pixel centres at +0.5) and depth of a camera-frame point.
    pub fn project(&self, camera_point: &Point3<f64>) -> Option<(f64, f64, f64)> {
        let z = camera_point.z;
        (z > 0.0).then(|| {
            (
                self.fx_px * camera_point.x / z + self.cx_px,
                self.fy_px * camera_point.y / z + self.cy_px,
                z,
            )
        })
    }

    /// The camera-frame point seen at the centre of pixel `(u, v)` at depth `z_m`.
    pub fn back_project(&self, u: u32, v: u32, z_m: f64) -> Point3<f64> {
        Point3::new(
            (f64::from(u) + 0.5 - self.cx_px) * z_m / self.fx_px,
            (f64::from(v) + 0.5 - self.cy_px) * z_m / self.fy_px,
            z_m,
        )
    }

    /// The 3x3 intrinsic matrix K.
    pub fn intrinsics(&self) -> Matrix3<f64> {
        Matrix3::new(
            self.fx_px, 0.0, self.cx_px, 0.0, self.fy_px, self.cy_px, 0.0, 0.0, 1.0,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endoscope_matches_the_reference_intrinsics() {
        let camera = Camera::endoscope();
        assert!((camera.fx_px - 193.99).abs() < 0.01, "{}", camera.fx_px);
        let forward = camera.world_from_camera.rotation * Vector3::z();
        assert!((forward - Vector3::new(-0.783, 0.0, -0.622).normalize()).norm() < 1e-9);
        // Image right is world +y, image down points away from world up.
        let right = camera.world_from_camera.rotation * Vector3::x();
        assert!((right - Vector3::y()).norm() < 1e-3);
    }

    #[test]
    fn project_and_back_project_round_trip() {
        let camera = Camera::endoscope();
        let p = camera.back_project(17, 200, 0.13);
        let (u, v, z) = camera.project(&p).expect("in front");
        assert!((u - 17.5).abs() < 1e-9 && (v - 200.5).abs() < 1e-9 && (z - 0.13).abs() < 1e-12);
    }
}
