//! Surface normals: of a neighbourhood (PCA), of every point of a cloud, and of the image
//! cloud straight from a dense depth prior, and the per-correspondence image normals n^I.

use nalgebra::{Matrix3, Point2, Point3, SymmetricEigen, Vector3};

use super::{centroid, DepthImage, DepthKind, FrameGeometry, Intrinsics, PointIndex};

/// Unit normal of a neighbourhood by PCA (eigenvector of the smallest covariance eigenvalue),
/// oriented so that it points towards `towards`. `None` for fewer than 3 points.
pub fn pca_normal(neighbours: &[Point3<f64>], towards: &Point3<f64>) -> Option<Vector3<f64>> {
    if neighbours.len() < 3 {
        return None;
    }
    let c = centroid(neighbours);
    let mut cov = Matrix3::zeros();
    for p in neighbours {
        let d = p - c;
        cov += d * d.transpose();
    }
    let eig = SymmetricEigen::new(cov);
    let (i, _) = eig.eigenvalues.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1))?;
    let mut n: Vector3<f64> = eig.eigenvectors.column(i).into_owned();
    if !n.iter().all(|v| v.is_finite()) {
        return None;
    }
    if n.dot(&(towards - c)) < 0.0 {
        n = -n;
    }
    Some(n.normalize())
}

/// The unit normal of every point of `cloud` (indexed by `index`) from its `k` nearest
/// neighbours, with an arbitrary sign; degenerate neighbourhoods get a zero vector.
pub fn point_cloud_normals(index: &PointIndex, cloud: &[Point3<f32>], k: usize) -> Vec<Vector3<f32>> {
    let mut neighbours = Vec::with_capacity(k);
    cloud
        .iter()
        .map(|p| {
            neighbours.clear();
            neighbours.extend(index.nearest(p, k).into_iter().map(|i| cloud[i].cast::<f64>()));
            let c = centroid(&neighbours);
            pca_normal(&neighbours, &c).map_or_else(Vector3::zeros, |n| n.cast())
        })
        .collect()
}

/// Normals of the image cloud straight from the dense depth prior: the cross product of the
/// back-projected horizontal and vertical neighbours of each pixel, oriented towards the camera.
/// `depth_of` maps a prior coordinate ([`DepthKind::coordinate`]) to depth (after any alignment).
pub fn prior_normals(
    intrinsics: &Intrinsics,
    prior: &DepthImage,
    kind: DepthKind,
    pixels: &[Point2<f64>],
    depth_of: impl Fn(f64) -> f64,
) -> Vec<Vector3<f64>> {
    let mut out = Vec::with_capacity(pixels.len());
    prior_normals_into(&mut out, intrinsics, prior, kind, pixels, depth_of);
    out
}

/// [`prior_normals`] appended to `out`.
fn prior_normals_into(
    out: &mut Vec<Vector3<f64>>,
    intrinsics: &Intrinsics,
    prior: &DepthImage,
    kind: DepthKind,
    pixels: &[Point2<f64>],
    depth_of: impl Fn(f64) -> f64,
) {
    // One pixel of the prior, in camera pixels.
    let step_u = intrinsics.width as f64 / prior.width as f64;
    let step_v = intrinsics.height as f64 / prior.height as f64;
    let lift = |p: Point2<f64>| -> Option<Point3<f64>> {
        let value = prior.sample(&p, intrinsics.width, intrinsics.height)?;
        let z = depth_of(kind.coordinate(value));
        (z.is_finite() && z > 0.0).then(|| intrinsics.back_project(&p, z))
    };
    out.extend(pixels.iter().map(|p| {
        let pts = (
            lift(Point2::new(p.x - step_u, p.y)),
            lift(Point2::new(p.x + step_u, p.y)),
            lift(Point2::new(p.x, p.y - step_v)),
            lift(Point2::new(p.x, p.y + step_v)),
        );
        let (Some(l), Some(r), Some(u), Some(d)) = pts else { return Vector3::zeros() };
        let n = (r - l).cross(&(d - u));
        let norm = n.norm();
        if !(norm > 1e-12) {
            return Vector3::zeros();
        }
        let mut n = n / norm;
        // Towards the camera at the origin.
        if n.dot(&(-l.coords)) < 0.0 {
            n = -n;
        }
        n
    }));
}

/// n^I: normals of the image cloud from the dense prior (aligned when an alignment is known),
/// oriented towards the camera; zero without a prior. Into `out` (cleared first).
pub fn image_normals_into(
    out: &mut Vec<Vector3<f64>>,
    intrinsics: &Intrinsics,
    prior: Option<&DepthImage>,
    geometry: &FrameGeometry,
    kind: DepthKind,
) {
    out.clear();
    let Some(prior) = prior else { return out.resize(geometry.len(), Vector3::zeros()) };
    let align = geometry.alignment();
    prior_normals_into(out, intrinsics, prior, kind, &geometry.pixels, |d| align.depth(d));
}
