//! A gate on the poses PnP may return: a prior pose (e.g. `/initialpose`, or the last pose of a
//! tracked camera) and how far from it a pose may lie. Inside [`super::solve_pnp_ransac`] a
//! hypothesis outside the gate is never scored, so a wrong pose with more support elsewhere in
//! the map cannot win over the right one near the prior.

use nalgebra::{Isometry3, UnitQuaternion};

use super::MapToCamera;

/// A camera-to-map pose and the largest distance and rotation from it a pose may have.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseGate {
    /// Camera-to-map pose at the gate's centre.
    pub centre: Isometry3<f64>,
    pub radius_m: f64,
    pub max_angle_rad: f64,
}

/// A pose outside the gate, and by how much.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("pose {distance_m:.2} m / {angle_deg:.1}° from the prior, gate {radius_m:.2} m / {max_angle_deg:.1}°")]
pub struct GateMiss {
    pub distance_m: f64,
    pub radius_m: f64,
    pub angle_deg: f64,
    pub max_angle_deg: f64,
}

impl PoseGate {
    /// Whether the camera-to-map `pose` is inside the gate.
    pub fn check(&self, pose: &Isometry3<f64>) -> Result<(), GateMiss> {
        let distance_m = (pose.translation.vector - self.centre.translation.vector).norm();
        let angle = UnitQuaternion::angle_to(&pose.rotation, &self.centre.rotation);
        if distance_m <= self.radius_m && angle <= self.max_angle_rad {
            return Ok(());
        }
        Err(GateMiss {
            distance_m,
            radius_m: self.radius_m,
            angle_deg: angle.to_degrees(),
            max_angle_deg: self.max_angle_rad.to_degrees(),
        })
    }

    /// Moves the gate to an accepted pose (a tracked camera's gate follows it).
    pub fn follow(&mut self, pose: &Isometry3<f64>) {
        self.centre = *pose;
    }

    /// Whether a solver's map-to-camera hypothesis is inside the gate (cheap: no quaternion).
    pub(crate) fn admits(&self, pose: &MapToCamera) -> bool {
        // Camera centre in the map: −Rᵀ·t.
        let centre = -(pose.rotation.transpose() * pose.translation);
        if !((centre - self.centre.translation.vector).norm() <= self.radius_m) {
            return false;
        }
        // The rotation between the two camera-to-map rotations, Rᵀ and R_g: tr(R_gᵀ·Rᵀ) = Σ R_g ∘ R.
        let gate = self.centre.rotation.to_rotation_matrix().into_inner();
        let trace: f64 =
            (0..3).flat_map(|i| (0..3).map(move |j| (i, j))).map(|(i, j)| gate[(i, j)] * pose.rotation[(j, i)]).sum();
        let cos = ((trace - 1.0) / 2.0).clamp(-1.0, 1.0);
        cos >= self.max_angle_rad.min(std::f64::consts::PI).cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, Vector3};

    #[test]
    fn a_gate_admits_what_it_checks_as_inside() {
        let gate = PoseGate {
            centre: Isometry3::from_parts(
                Translation3::new(1.0, 2.0, 0.5),
                UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
            ),
            radius_m: 0.5,
            max_angle_rad: 0.3,
        };
        for (dx, angle) in [(0.1, 0.1), (0.45, 0.25), (0.6, 0.1), (0.1, 0.35), (2.0, 2.0)] {
            let pose = Isometry3::from_parts(
                Translation3::from(gate.centre.translation.vector + Vector3::new(dx, 0.0, 0.0)),
                UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.6, 0.8) * angle) * gate.centre.rotation,
            );
            let inside = gate.check(&pose).is_ok();
            assert_eq!(inside, dx <= 0.5 && angle <= 0.3, "{dx} {angle}");
            assert_eq!(gate.admits(&MapToCamera::from_camera_to_map(&pose)), inside, "{dx} {angle}");
        }
    }
}
