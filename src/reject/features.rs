//! Eq. (9): the learned rejector's input, a 24-d feature per correspondence,
//! f_i = [c̃_i; sin(c̃_i / 2); cos(c̃_i / 2); n^I_i; n^P_i], where c̃_i = [õ_i; p̂_i] joins the
//! centred image point (in map units) and the centred map point, and n^I, n^P are the normals of
//! the image cloud (from the dense prior) and of the map cloud.

use nalgebra::{Point3, Vector3};

use crate::consistency::estimate_scale;
use crate::geometry::{centroid, FrameGeometry};

/// Length of one feature vector.
pub const FEATURE_DIM: usize = 24;

/// Neighbours of a map point that define its normal.
pub const MAP_NORMAL_NEIGHBOURS: usize = 16;

/// The centred clouds of eq. (5), the image one in map units: õ_i = (o_i − o_c)/s with s from
/// eq. (8) when the prior was not aligned and `rescale` (with an aligned prior the cloud is
/// metric, s = 1; without alignment and without `rescale`, s = 1 too: the no-scale-alignment
/// ablation). Correspondences without a prior depth get a zero image vector.
pub fn centred_clouds(geometry: &FrameGeometry, rescale: bool) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let finite: Vec<usize> = (0..geometry.len())
        .filter(|&i| geometry.image_points.get(i).is_some_and(|p| p.coords.iter().all(|v| v.is_finite())))
        .collect();
    let image: Vec<Point3<f64>> = finite.iter().map(|&i| geometry.image_points[i]).collect();
    let map: Vec<Point3<f64>> = finite.iter().map(|&i| geometry.map_points[i]).collect();
    let scale = match geometry.scale_shift {
        None if rescale => estimate_scale(&image, &map).unwrap_or(1.0),
        _ => 1.0,
    };
    let (oc, pc) = (centroid(&image), centroid(&geometry.map_points));
    let mut centred_image = vec![Vector3::zeros(); geometry.len()];
    for &i in &finite {
        centred_image[i] = (geometry.image_points[i] - oc) / scale;
    }
    let centred_map = geometry.map_points.iter().map(|p| p - pc).collect();
    (centred_image, centred_map)
}

/// The map, indexed once, with the normal of each map point a frame uses (PCA over its
/// [`MAP_NORMAL_NEIGHBOURS`] nearest, sign left to each frame) computed on first use and cached.
pub type IndexedMap = crate::map_index::MapIndex;
const _: () = assert!(MAP_NORMAL_NEIGHBOURS == crate::map_index::NORMAL_NEIGHBOURS);

/// n^P: the normal of the map point nearest to each correspondence's map point, oriented
/// towards the centroid of the frame's map points (a choice that moves with the map, like the
/// image normals' camera).
pub fn map_normals(map: &IndexedMap, geometry: &FrameGeometry) -> Vec<Vector3<f64>> {
    let towards = centroid(&geometry.map_points);
    geometry
        .map_points
        .iter()
        .zip(map.nearest_normals(&geometry.map_points))
        .map(|(q, normal)| {
            let Some(normal) = normal else { return Vector3::zeros() };
            let n: Vector3<f64> = normal.cast();
            if n.dot(&(towards - q)) < 0.0 {
                -n
            } else {
                n
            }
        })
        .collect()
}

/// Eq. (9) for every correspondence.
pub fn features(
    geometry: &FrameGeometry,
    image_normals: &[Vector3<f64>],
    map_normals: &[Vector3<f64>],
    rescale: bool,
) -> Vec<[f32; FEATURE_DIM]> {
    let mut out = Vec::new();
    features_into(&mut out, geometry, image_normals, map_normals, rescale);
    out
}

/// [`features`] into `out`, reusing its allocation.
pub fn features_into(
    out: &mut Vec<[f32; FEATURE_DIM]>,
    geometry: &FrameGeometry,
    image_normals: &[Vector3<f64>],
    map_normals: &[Vector3<f64>],
    rescale: bool,
) {
    let (image, map) = centred_clouds(geometry, rescale);
    out.clear();
    out.extend((0..geometry.len()).map(|i| {
        let c = [image[i].x, image[i].y, image[i].z, map[i].x, map[i].y, map[i].z];
        let mut f = [0.0f32; FEATURE_DIM];
        for k in 0..6 {
            f[k] = c[k] as f32;
            f[6 + k] = (c[k] / 2.0).sin() as f32;
            f[12 + k] = (c[k] / 2.0).cos() as f32;
        }
        let (ni, np) =
            (image_normals.get(i).copied().unwrap_or_default(), map_normals.get(i).copied().unwrap_or_default());
        for k in 0..3 {
            f[18 + k] = ni[k] as f32;
            f[21 + k] = np[k] as f32;
        }
        f
    }));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::consistency::ScaleShift;
    use nalgebra::Point2;

    fn geometry(image: Vec<Point3<f64>>, map: Vec<Point3<f64>>, aligned: bool) -> FrameGeometry {
        FrameGeometry {
            pixels: vec![Point2::origin(); image.len()],
            map_points: map,
            image_points: image,
            scale_shift: aligned.then_some(ScaleShift::IDENTITY),
            ..FrameGeometry::default()
        }
    }

    #[test]
    fn unaligned_image_cloud_is_rescaled_by_eq8() {
        let map = vec![Point3::new(0.0, 0.0, 0.0), Point3::new(2.0, 0.0, 0.0), Point3::new(0.0, 2.0, 0.0)];
        let image: Vec<_> = map.iter().map(|p| Point3::from(p.coords * 3.0 + Vector3::new(1.0, 1.0, 5.0))).collect();
        let (oi, pm) = centred_clouds(&geometry(image, map, false), true);
        for (a, b) in oi.iter().zip(&pm) {
            assert!((a - b).norm() < 1e-12, "{a} vs {b}");
        }
    }

    #[test]
    fn feature_layout_follows_eq9() {
        let g = geometry(
            vec![Point3::new(1.0, 0.0, 0.0), Point3::new(-1.0, 0.0, 0.0)],
            vec![Point3::new(0.0, 0.0, 2.0), Point3::new(0.0, 0.0, -2.0)],
            true,
        );
        let n = [Vector3::new(0.0, 0.0, -1.0); 2];
        let f = features(&g, &n, &[Vector3::new(1.0, 0.0, 0.0); 2], true);
        assert_eq!(f.len(), 2);
        assert_eq!(&f[0][..6], &[1.0, 0.0, 0.0, 0.0, 0.0, 2.0]);
        assert!((f[0][6] - 0.5f32.sin()).abs() < 1e-7 && (f[0][12] - 0.5f32.cos()).abs() < 1e-7);
        assert!((f[0][11] - 1.0f32.sin()).abs() < 1e-7 && (f[0][17] - 1.0f32.cos()).abs() < 1e-7);
        assert_eq!(&f[0][18..], &[0.0, 0.0, -1.0, 1.0, 0.0, 0.0]);
    }
}
