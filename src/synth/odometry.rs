//! A robot's odometry along the camera's path, as wheel or visual odometry has it: the camera's
//! pose in an `odom` frame that starts somewhere other than the map's origin and drifts — every
//! step's motion is measured with an error that grows with the distance travelled and the angle
//! turned, and the errors add up (a random walk). A kidnap is a jump odometry does not see: its
//! step is the small one the camera would have made had it not been carried away.

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;

use crate::rng::mix64;

/// Where the odometry frame starts in the map: turned 0.6 rad about the vertical and moved, so
/// that a pose in one is never taken for a pose in the other unnoticed.
fn odom_from_map() -> Isometry3<f64> {
    Isometry3::new(Vector3::new(2.0, -1.0, 0.0), Vector3::new(0.0, 0.0, 0.6))
}

/// The odometry of a path.
pub struct Odometry {
    /// The error of a step, as a share of its distance (translation, per axis) and of its turn
    /// plus its distance in metres (rotation about the vertical, radians).
    drift: f64,
    seed: u64,
}

impl Odometry {
    pub fn new(drift: f64, seed: u64) -> Self {
        Self { drift, seed: mix64(seed ^ 0x0D0_3E7E) }
    }

    /// The camera's pose in the odometry frame at frame `k`: the first pose, then every step
    /// from frame 0 to `k` as measured. `true_pose(j)` is the camera-to-map pose of frame `j`;
    /// `felt_step(j)` the motion odometry feels into frame `j` where it is not the true one (a
    /// kidnap).
    pub fn at(
        &self,
        k: usize,
        true_pose: impl Fn(usize) -> Isometry3<f64>,
        felt_step: impl Fn(usize) -> Option<Isometry3<f64>>,
    ) -> Isometry3<f64> {
        let mut odometry = odom_from_map() * true_pose(0);
        let mut before = true_pose(0);
        for j in 1..=k {
            let now = true_pose(j);
            let step = felt_step(j).unwrap_or_else(|| before.inverse() * now);
            odometry *= step * self.error(j, &step);
            before = now;
        }
        odometry
    }

    /// The measurement error of step `j` (in the camera's frame after the step).
    fn error(&self, j: usize, step: &Isometry3<f64>) -> Isometry3<f64> {
        let mut rng = StdRng::seed_from_u64(mix64(self.seed ^ j as u64));
        let mut normal = || rng.sample::<f64, _>(StandardNormal);
        let distance = step.translation.vector.norm();
        let turn = step.rotation.angle();
        let sigma_t = self.drift * distance;
        let translation = Vector3::new(normal(), normal(), normal()) * sigma_t;
        // The optical frame's vertical is -y: yaw errors turn about it.
        let yaw = normal() * self.drift * (turn + distance);
        Isometry3::from_parts(translation.into(), UnitQuaternion::from_scaled_axis(Vector3::y() * yaw))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn walk(j: usize) -> Isometry3<f64> {
        Isometry3::new(Vector3::new(0.1 * j as f64, 0.0, 0.0), Vector3::new(0.0, 0.05 * j as f64, 0.0))
    }

    #[test]
    fn without_drift_odometry_is_the_path_in_another_frame() {
        let odometry = Odometry::new(0.0, 1);
        for k in [0, 1, 7] {
            let expected = odom_from_map() * walk(k);
            let got = odometry.at(k, walk, |_| None);
            assert!((got.to_homogeneous() - expected.to_homogeneous()).abs().max() < 1e-12, "frame {k}");
        }
    }

    #[test]
    fn drift_grows_with_the_path_and_steps_stay_close() {
        let odometry = Odometry::new(0.02, 3);
        let relative = |k: usize| (odom_from_map() * walk(k)).inverse() * odometry.at(k, walk, |_| None);
        let (early, late) = (relative(2).translation.vector.norm(), relative(200).translation.vector.norm());
        assert!(late > early, "{early} then {late}");
        // One step's error: 2 % of its 10 cm on each axis.
        let step_error =
            (odometry.at(10, walk, |_| None).inverse() * odometry.at(11, walk, |_| None)).translation.vector
                - (walk(10).inverse() * walk(11)).translation.vector;
        assert!(step_error.norm() < 0.02, "{step_error}");
    }

    #[test]
    fn a_kidnap_odometry_does_not_see_is_a_small_step() {
        let odometry = Odometry::new(0.0, 1);
        let jumped = |j: usize| if j >= 5 { walk(j + 40) } else { walk(j) };
        let felt = |j: usize| (j == 5).then(|| walk(4).inverse() * walk(5));
        let step = odometry.at(4, jumped, felt).inverse() * odometry.at(5, jumped, felt);
        let unjumped = walk(4).inverse() * walk(5);
        assert!((step.to_homogeneous() - unjumped.to_homogeneous()).abs().max() < 1e-9, "{step:?}");
    }
}
