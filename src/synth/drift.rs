//! A map fused from keyframes whose poses came from structure-from-motion: each part of the
//! map sits where its keyframe's slightly wrong pose put it. The map is split into cubic
//! regions (one keyframe's footprint each); every region is moved by its own small rigid motion
//! — a rotation about its centre and an offset — so true matches agree with one camera pose only
//! up to a few centimetres, and two neighbouring regions disagree along their border, as real
//! fused maps do.

use nalgebra::{Point3, UnitQuaternion, Vector3};

use super::SynthConfig;
use crate::rng::{mix64, SplitMix64};

/// The per-region error of a fused map (the identity when `region_m` is 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapDrift {
    /// Side of a region, metres; 0: no drift.
    region_m: f64,
    /// Range of a region's rotation error, degrees (its size uniform in it, its axis random).
    rotation_deg: [f64; 2],
    /// Range of a region's offset, metres (its size uniform in it, its direction random).
    offset_m: [f64; 2],
    seed: u64,
}

impl MapDrift {
    pub fn of(config: &SynthConfig) -> Self {
        Self {
            region_m: config.map_keyframe_m,
            rotation_deg: config.map_rotation_deg,
            offset_m: config.map_offset_m,
            seed: mix64(config.seed ^ 0x00D1_2F75_EEDF_0000),
        }
    }

    pub fn is_identity(&self) -> bool {
        !(self.region_m > 0.0)
    }

    /// Where the fused map holds the true surface point `p`.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        if self.is_identity() {
            return *p;
        }
        let key = p.coords.map(|v| (v / self.region_m).floor());
        let centre = Point3::from((key + Vector3::repeat(0.5)) * self.region_m);
        let hash = key.iter().fold(self.seed, |h, &k| mix64(h ^ (k as i64 as u64)));
        let mut rng = SplitMix64(hash);
        let mut uniform = |[lo, hi]: [f64; 2]| lo + (hi - lo) * rng.next_f64();
        let angle = uniform(self.rotation_deg).to_radians();
        let offset = uniform(self.offset_m);
        let rotation = UnitQuaternion::from_scaled_axis(random_direction(&mut rng) * angle);
        centre + rotation * (p - centre) + random_direction(&mut rng) * offset
    }
}

/// A uniformly random unit vector.
fn random_direction(rng: &mut SplitMix64) -> Vector3<f64> {
    let z = 2.0 * rng.next_f64() - 1.0;
    let phi = std::f64::consts::TAU * rng.next_f64();
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vector3::new(r * phi.cos(), r * phi.sin(), z)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drift(seed: u64) -> MapDrift {
        MapDrift { region_m: 2.0, rotation_deg: [0.5, 1.5], offset_m: [0.01, 0.04], seed }
    }

    #[test]
    fn a_region_moves_rigidly_within_its_bounds() {
        let d = drift(7);
        let (a, b) = (Point3::new(0.3, 0.4, 0.5), Point3::new(1.7, 1.1, 0.2));
        let (da, db) = (d.apply(&a), d.apply(&b));
        // Rigid: distances inside one region are kept.
        assert!(((da - db).norm() - (a - b).norm()).abs() < 1e-9);
        // Bounded: at most the largest rotation over the region's half diagonal plus the offset.
        let bound = 1.5f64.to_radians() * 3f64.sqrt() + 0.04;
        assert!((da - a).norm() <= bound + 1e-9);
        assert!((da - a).norm() > 0.0);
    }

    #[test]
    fn regions_move_differently_and_the_same_seed_moves_alike() {
        let d = drift(7);
        let (a, b) = (Point3::new(1.9, 1.0, 1.0), Point3::new(2.1, 1.0, 1.0));
        let shift = |p: Point3<f64>| d.apply(&p) - p;
        assert!((shift(a) - shift(b)).norm() > 1e-4, "neighbouring regions share a motion");
        assert_eq!(d.apply(&a), drift(7).apply(&a));
        assert_ne!(d.apply(&a), drift(8).apply(&a));
    }

    #[test]
    fn no_region_side_is_the_identity() {
        let d = MapDrift { region_m: 0.0, ..drift(7) };
        let p = Point3::new(1.0, 2.0, 3.0);
        assert_eq!(d.apply(&p), p);
    }
}
