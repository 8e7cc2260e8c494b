//! Non-minimal solver: EPnP (Lepetit, Moreno-Noguer & Fua, IJCV 2009), written from the paper.
//!
//! Map points are expressed in barycentric coordinates of four control points (centroid +
//! principal axes); the camera-frame control points lie in the span of the four smallest
//! eigenvectors of `MᵀM`; the combination weights β come from the control-point distances
//! (three linearisations, each Gauss–Newton polished), the pose from absolute orientation.
//! Non-planar point sets only (a planar map region is reported as degenerate).

use super::ops::{check_basic, finite_pairs, Cam};
use super::{MapToCamera, PnpError};
use crate::geometry::Intrinsics;
use nalgebra::{
    Isometry3, Matrix3, Matrix4, Point2, Point3, SMatrix, SVector, SymmetricEigen, Vector2, Vector3, Vector4,
};

type M12 = SMatrix<f64, 12, 12>;
type V12 = SVector<f64, 12>;

/// Absolute orientation (Kabsch): the rigid transform taking `from[i]` to `to[i]`.
pub(crate) fn absolute_orientation(from: &[Vector3<f64>], to: &[Vector3<f64>]) -> Option<MapToCamera> {
    let n = from.len() as f64;
    let cf = from.iter().sum::<Vector3<f64>>() / n;
    let ct = to.iter().sum::<Vector3<f64>>() / n;
    let mut h = Matrix3::zeros();
    for (f, t) in from.iter().zip(to) {
        h += (t - ct) * (f - cf).transpose();
    }
    if !h.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = h.try_svd(true, true, f64::EPSILON, 200)?;
    let (u, vt) = (svd.u?, svd.v_t?);
    let d = (u * vt).determinant().signum();
    let rot = u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * vt;
    let pose = MapToCamera { rotation: rot, translation: ct - rot * cf };
    pose.is_finite().then_some(pose)
}

/// EPnP's four control points in the map: the centroid and the principal axes scaled by the RMS
/// extent, with each map point's barycentric coordinates in them.
struct ControlPoints {
    world: [Vector3<f64>; 4],
    alphas: Vec<Vector4<f64>>,
}

/// EPnP on normalised image coordinates `uv` (`K⁻¹·pixel`, z = 1) and map points `pw`.
pub(crate) fn epnp_normalized(uv: &[Vector2<f64>], pw: &[Vector3<f64>]) -> Result<MapToCamera, PnpError> {
    let n = uv.len();
    if n < 4 || pw.len() != n {
        return Err(PnpError::TooFewPoints { usable: n.min(pw.len()), required: 4 });
    }
    let control = control_points(pw)?;
    let v = null_space(&control.alphas, uv)?;
    let (q, rho) = pair_distances(&v, &control.world);
    let mut best: Option<(f64, MapToCamera)> = None;
    let mut pc = vec![Vector3::zeros(); n];
    for init in beta_inits(&q, &rho) {
        let beta = gauss_newton_betas(init, &q, &rho);
        let mut cc = [Vector3::zeros(); 4];
        for (j, c) in cc.iter_mut().enumerate() {
            for k in 0..4 {
                *c += Vector3::new(v[k][3 * j], v[k][3 * j + 1], v[k][3 * j + 2]) * beta[k];
            }
        }
        for (p, a) in pc.iter_mut().zip(&control.alphas) {
            *p = cc[0] * a[0] + cc[1] * a[1] + cc[2] * a[2] + cc[3] * a[3];
        }
        if pc.iter().map(|p| p.z).sum::<f64>() < 0.0 {
            pc.iter_mut().for_each(|p| *p = -*p);
        }
        let Some(pose) = absolute_orientation(pw, &pc) else { continue };
        let err = normalized_error(&pose, pw, uv);
        if err.is_finite() && best.as_ref().is_none_or(|(e, _)| err < *e) {
            best = Some((err, pose));
        }
    }
    best.map(|(_, p)| p).ok_or(PnpError::Degenerate("EPnP found no valid pose"))
}

/// Σ squared error in normalised image coordinates (1e6 per point behind the camera).
fn normalized_error(pose: &MapToCamera, pw: &[Vector3<f64>], uv: &[Vector2<f64>]) -> f64 {
    pw.iter()
        .zip(uv)
        .map(|(p, m)| {
            let x = pose.transform(p);
            if x.z > 0.0 {
                (x.x / x.z - m.x).powi(2) + (x.y / x.z - m.y).powi(2)
            } else {
                1e6
            }
        })
        .sum()
}

/// Control points: centroid + principal axes scaled by the RMS extent.
fn control_points(pw: &[Vector3<f64>]) -> Result<ControlPoints, PnpError> {
    let n = pw.len();
    let c0 = pw.iter().sum::<Vector3<f64>>() / n as f64;
    let mut cov = Matrix3::zeros();
    for p in pw {
        let d = p - c0;
        cov += d * d.transpose();
    }
    cov /= n as f64;
    if !cov.iter().all(|v| v.is_finite()) {
        return Err(PnpError::Degenerate("map point spread overflows"));
    }
    let eig =
        SymmetricEigen::try_new(cov, f64::EPSILON, 1000).ok_or(PnpError::Degenerate("eigen decomposition failed"))?;
    let lmax = eig.eigenvalues.amax();
    if !(lmax.is_finite() && lmax > 0.0) || eig.eigenvalues.min() <= 1e-10 * lmax {
        return Err(PnpError::Degenerate("map points are planar or collinear"));
    }
    let mut axes = [Vector3::zeros(); 3];
    let mut cw = [c0; 4];
    for k in 0..3 {
        let s = eig.eigenvalues[k].sqrt();
        axes[k] = eig.eigenvectors.column(k) / s;
        cw[k + 1] = c0 + eig.eigenvectors.column(k) * s;
    }
    let alphas: Vec<Vector4<f64>> = pw
        .iter()
        .map(|p| {
            let d = p - c0;
            let (a1, a2, a3) = (axes[0].dot(&d), axes[1].dot(&d), axes[2].dot(&d));
            Vector4::new(1.0 - a1 - a2 - a3, a1, a2, a3)
        })
        .collect();
    Ok(ControlPoints { world: cw, alphas })
}

/// The four eigenvectors of MᵀM with the smallest eigenvalues (the camera control points lie
/// in their span).
fn null_space(alphas: &[Vector4<f64>], uv: &[Vector2<f64>]) -> Result<[V12; 4], PnpError> {
    let mut mtm = M12::zeros();
    for (a, m) in alphas.iter().zip(uv) {
        let mut r1 = V12::zeros();
        let mut r2 = V12::zeros();
        for j in 0..4 {
            r1[3 * j] = a[j];
            r1[3 * j + 2] = -a[j] * m.x;
            r2[3 * j + 1] = a[j];
            r2[3 * j + 2] = -a[j] * m.y;
        }
        mtm += r1 * r1.transpose() + r2 * r2.transpose();
    }
    if !mtm.iter().all(|v| v.is_finite()) {
        return Err(PnpError::Degenerate("EPnP system is not finite"));
    }
    let eig12 =
        SymmetricEigen::try_new(mtm, f64::EPSILON, 1000).ok_or(PnpError::Degenerate("eigen decomposition failed"))?;
    let mut order: [usize; 12] = std::array::from_fn(|i| i);
    order.sort_by(|&a, &b| eig12.eigenvalues[a].total_cmp(&eig12.eigenvalues[b]));
    Ok(std::array::from_fn(|k| eig12.eigenvectors.column(order[k]).into_owned()))
}

/// The control-point pairs of EPnP's distance constraints.
const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];

/// For each control-point pair: Q[k][l] = dv_k · dv_l, with ‖Σ β_k dv_k‖² = ρ.
fn pair_distances(v: &[V12; 4], cw: &[Vector3<f64>; 4]) -> ([Matrix4<f64>; 6], [f64; 6]) {
    let mut q = [Matrix4::zeros(); 6];
    let mut rho = [0.0; 6];
    for (p, &(a, b)) in PAIRS.iter().enumerate() {
        let dv: [Vector3<f64>; 4] = std::array::from_fn(|k| {
            Vector3::new(
                v[k][3 * a] - v[k][3 * b],
                v[k][3 * a + 1] - v[k][3 * b + 1],
                v[k][3 * a + 2] - v[k][3 * b + 2],
            )
        });
        for k in 0..4 {
            for l in 0..4 {
                q[p][(k, l)] = dv[k].dot(&dv[l]);
            }
        }
        rho[p] = (cw[a] - cw[b]).norm_squared();
    }
    (q, rho)
}

/// Initial β from the linearised products (approximations N = 1, 2, 3 of the paper).
fn beta_inits(q: &[Matrix4<f64>; 6], rho: &[f64; 6]) -> Vec<Vector4<f64>> {
    // Solve L·x = ρ over the chosen products (k, l) by least squares.
    let solve_products = |prods: &[(usize, usize)]| -> Option<Vec<f64>> {
        let m = prods.len();
        let mut l = nalgebra::DMatrix::zeros(6, m);
        for p in 0..6 {
            for (c, &(k, ll)) in prods.iter().enumerate() {
                l[(p, c)] = if k == ll { q[p][(k, k)] } else { 2.0 * q[p][(k, ll)] };
            }
        }
        let r = nalgebra::DVector::from_row_slice(rho);
        let x = l.try_svd(true, true, f64::EPSILON, 200)?.solve(&r, 1e-12).ok()?;
        Some(x.iter().copied().collect())
    };
    let mut inits: Vec<Vector4<f64>> = Vec::with_capacity(3);
    // N = 1 (approx. 1 of the paper: b11, b12, b13, b14).
    if let Some(x) = solve_products(&[(0, 0), (0, 1), (0, 2), (0, 3)]) {
        let b1 = x[0].abs().sqrt();
        if b1 > 0.0 {
            let s = if x[0] < 0.0 { -1.0 } else { 1.0 };
            inits.push(Vector4::new(b1, s * x[1] / b1, s * x[2] / b1, s * x[3] / b1));
        }
    }
    // N = 2 (b11, b12, b22).
    if let Some(x) = solve_products(&[(0, 0), (0, 1), (1, 1)]) {
        let (mut b1, b2) = (x[0].abs().sqrt(), x[2].abs().sqrt());
        if x[1] < 0.0 {
            b1 = -b1;
        }
        inits.push(Vector4::new(b1, b2, 0.0, 0.0));
    }
    // N = 3 (b11, b12, b22, b13, b23).
    if let Some(x) = solve_products(&[(0, 0), (0, 1), (1, 1), (0, 2), (1, 2)]) {
        let (mut b1, b2) = (x[0].abs().sqrt(), x[2].abs().sqrt());
        if x[1] < 0.0 {
            b1 = -b1;
        }
        let b3 = if b1 != 0.0 { x[3] / b1 } else { 0.0 };
        inits.push(Vector4::new(b1, b2, b3, 0.0));
    }
    inits
}

fn gauss_newton_betas(mut b: Vector4<f64>, q: &[Matrix4<f64>; 6], rho: &[f64; 6]) -> Vector4<f64> {
    let cost = |b: &Vector4<f64>| (0..6).map(|p| (b.dot(&(q[p] * b)) - rho[p]).powi(2)).sum::<f64>();
    let mut c = cost(&b);
    for _ in 0..10 {
        let mut h = Matrix4::zeros();
        let mut g = Vector4::zeros();
        for p in 0..6 {
            let qb = q[p] * b;
            let r = b.dot(&qb) - rho[p];
            let j = qb * 2.0;
            h += j * j.transpose();
            g += j * r;
        }
        for k in 0..4 {
            h[(k, k)] += 1e-12 + 1e-9 * h[(k, k)];
        }
        let Some(ch) = h.cholesky() else { break };
        let nb = b - ch.solve(&g);
        let nc = cost(&nb);
        if nc < c && nb.iter().all(|v| v.is_finite()) {
            b = nb;
            c = nc;
        } else {
            break;
        }
    }
    b
}

/// EPnP on all finite correspondences (≥ 4, non-planar map points), no refinement. Returns the
/// camera-to-map pose. See [`super::solve_pnp_nonminimal`] for EPnP + LM.
pub fn epnp(
    intrinsics: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
) -> Result<Isometry3<f64>, PnpError> {
    check_basic(intrinsics, pixels.len(), points.len())?;
    let pairs = finite_pairs(pixels, points);
    let (px, pw) = (pairs.pixels, pairs.points);
    let cam = Cam::new(intrinsics);
    let uv: Vec<Vector2<f64>> =
        px.iter().map(|p| Vector2::new((p.x - cam.cx) / cam.fx, (p.y - cam.cy) / cam.fy)).collect();
    Ok(epnp_normalized(&uv, &pw)?.to_camera_to_map())
}
