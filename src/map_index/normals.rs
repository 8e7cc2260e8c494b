//! Normals of map points, computed when a frame first needs them and kept: a frame uses a few
//! hundred map points, so the map's millions are never all solved (at 5 M points that took
//! ~38 s at load). The same PCA over the same k nearest neighbours as an eager pass, so a lazy
//! normal equals the eager one bit for bit.

use std::collections::HashMap;
use std::sync::Mutex;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::voxels::VoxelGrid;
use crate::geometry::{centroid, pca_normal, PointIndex};

/// Finds the map points nearest to a point: one k-d tree over the whole map, or the voxel
/// grid's per-voxel trees ([`VoxelGrid::nearest_k`]).
pub trait NearestPoints: Sync {
    /// Indices of the `k` nearest map points to `p`, nearest first.
    fn nearest_points(&self, p: &Point3<f32>, k: usize) -> Vec<usize>;
}

impl NearestPoints for PointIndex {
    fn nearest_points(&self, p: &Point3<f32>, k: usize) -> Vec<usize> {
        self.nearest(p, k)
    }
}

impl NearestPoints for VoxelGrid {
    fn nearest_points(&self, p: &Point3<f32>, k: usize) -> Vec<usize> {
        self.nearest_k(p, k)
    }
}

/// Normals at most kept; beyond it the cache starts afresh (a bound on what an hour-long run
/// over a huge map can make it hold: 4 M entries ≈ 100 MB).
const MAX_CACHED: usize = 4_000_000;

/// Lazily computed, cached normals of the points of one map.
#[derive(Debug, Default)]
pub struct LazyNormals {
    cache: Mutex<HashMap<u32, Vector3<f32>>>,
}

impl LazyNormals {
    /// The normal of each of `which` (indices into `points`), from its `k` nearest neighbours
    /// in `index`; an index out of range gets a zero vector. The ones not cached yet are solved
    /// in parallel, outside the lock (another camera's frame may meanwhile read the cache; two
    /// solving the same point get the same normal).
    pub fn get(
        &self,
        index: &dyn NearestPoints,
        points: &[Point3<f32>],
        k: usize,
        which: &[usize],
    ) -> Vec<Vector3<f32>> {
        let key = |i: usize| u32::try_from(i).ok().filter(|_| i < points.len());
        let mut missing: Vec<u32> = {
            let cache = self.lock();
            which.iter().filter_map(|&i| key(i)).filter(|key| !cache.contains_key(key)).collect()
        };
        missing.sort_unstable();
        missing.dedup();
        let solve = |neighbours: &mut Vec<Point3<f64>>, key: u32| match points.get(key as usize) {
            Some(p) => point_normal(index, points, p, k, neighbours),
            None => Vector3::zeros(),
        };
        let fresh: HashMap<u32, Vector3<f32>> = missing
            .par_iter()
            .map_init(|| Vec::with_capacity(k), |neighbours, &key| (key, solve(neighbours, key)))
            .collect();
        let mut cache = self.lock();
        let mut neighbours = Vec::with_capacity(k);
        let normals = which
            .iter()
            .map(|&i| match key(i) {
                None => Vector3::zeros(),
                // Cached before (unless the cache started afresh meanwhile) or solved just now.
                Some(key) => match fresh.get(&key).or_else(|| cache.get(&key)) {
                    Some(normal) => *normal,
                    None => solve(&mut neighbours, key),
                },
            })
            .collect();
        if cache.len() + fresh.len() > MAX_CACHED {
            cache.clear();
        }
        cache.extend(fresh);
        normals
    }

    /// The cache (a poisoned lock only means another thread panicked mid-insert: the cache
    /// stays valid).
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<u32, Vector3<f32>>> {
        self.cache.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Normals cached so far.
    pub fn cached(&self) -> usize {
        self.lock().len()
    }
}

/// The unit normal at `p` from its `k` nearest points (arbitrary sign; zero when degenerate),
/// exactly as [`crate::geometry::point_cloud_normals`] computes it.
pub fn point_normal(
    index: &dyn NearestPoints,
    points: &[Point3<f32>],
    p: &Point3<f32>,
    k: usize,
    neighbours: &mut Vec<Point3<f64>>,
) -> Vector3<f32> {
    neighbours.clear();
    neighbours.extend(index.nearest_points(p, k).into_iter().filter_map(|i| points.get(i)).map(|q| q.cast::<f64>()));
    let c = centroid(neighbours);
    pca_normal(neighbours, &c).map_or_else(Vector3::zeros, |n| n.cast())
}
