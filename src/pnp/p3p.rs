//! Minimal solver: Lambda Twist P3P (Persson & Nordberg, ECCV 2018), written from the paper.
//!
//! The depths `λᵢ` along the unit bearings satisfy three quadrics
//! `λᵢ² + λⱼ² + bᵢⱼλᵢλⱼ = aᵢⱼ` (`bᵢⱼ = −2yᵢ·yⱼ`, `aᵢⱼ = |xᵢ − xⱼ|²`). Two homogeneous
//! combinations `D1`, `D2` are formed; a root `γ` of the cubic `det(D1 + γD2) = 0` makes
//! `D0 = D1 + γD2` a degenerate conic, a pair of planes through the origin. On each plane the
//! homogeneous quadratic of `D1` gives up to two depth directions; scale, Gauss–Newton polish,
//! then the pose from two orthonormal frames. Near-degenerate input yields no solution.

use super::MapToCamera;
use nalgebra::{Matrix3, Point3, Vector3};

/// Up to four map-to-camera poses from one P3P problem; derefs to a slice.
#[derive(Clone, Copy, Debug)]
pub struct P3pSolutions {
    poses: [MapToCamera; 4],
    len: usize,
}

impl P3pSolutions {
    fn new() -> Self {
        Self { poses: [MapToCamera::identity(); 4], len: 0 }
    }

    fn push(&mut self, p: MapToCamera) {
        if self.len < 4 {
            self.poses[self.len] = p;
            self.len += 1;
        }
    }
}

impl std::ops::Deref for P3pSolutions {
    type Target = [MapToCamera];
    fn deref(&self) -> &[MapToCamera] {
        &self.poses[..self.len]
    }
}

/// P3P from three bearings (camera frame, any norm) and their three map points. Returns the
/// map-to-camera poses with all three points in front of the camera (0–4 of them); none for
/// non-finite, coincident or collinear input or an ill-conditioned system.
pub fn p3p(bearings: &[Vector3<f64>; 3], points: &[Point3<f64>; 3]) -> P3pSolutions {
    let mut y = [Vector3::zeros(); 3];
    for (yi, b) in y.iter_mut().zip(bearings) {
        let n = b.norm();
        if !(n.is_finite() && n > 0.0) {
            return P3pSolutions::new();
        }
        *yi = b / n;
    }
    p3p_unit(&y, &[points[0].coords, points[1].coords, points[2].coords])
}

/// Homogeneous roots `(α, β)` of `a·α² + 2b·αβ + c·β² = 0`; `disc_tol` (relative) lets a
/// slightly negative discriminant count as a double root.
#[inline(always)]
fn homogeneous_quadratic(a: f64, b: f64, c: f64) -> ([(f64, f64); 2], usize) {
    let scale = a.abs().max(b.abs()).max(c.abs());
    if !(scale > 0.0) {
        return ([(0.0, 0.0); 2], 0);
    }
    let mut disc = b * b - a * c;
    if disc < 0.0 {
        if disc > -1e-10 * scale * scale {
            disc = 0.0;
        } else {
            return ([(0.0, 0.0); 2], 0);
        }
    }
    let sq = disc.sqrt();
    // Stable form: q = −(b + sign(b)·√disc); roots of a t² + 2b t + c are q/a and c/q.
    let q = -(b + if b >= 0.0 { sq } else { -sq });
    let mut out = [(0.0, 0.0); 2];
    let mut n = 0;
    // Root t = α/β = q/a  ⇔  (α, β) = (q, a); root t = c/q  ⇔  (α, β) = (c, q).
    if q.abs() > 1e-300 || a.abs() > 1e-300 {
        out[n] = (q, a);
        n += 1;
    }
    if sq > 0.0 && (c.abs() > 1e-300 || q.abs() > 1e-300) {
        out[n] = (c, q);
        n += 1;
    }
    (out, n)
}

/// One real root of `c3 g³ + c2 g² + c1 g + c0`, Newton-polished.
fn cubic_real_root(c3: f64, c2: f64, c1: f64, c0: f64) -> Option<f64> {
    let scale = c3.abs().max(c2.abs()).max(c1.abs()).max(c0.abs());
    if !(scale.is_finite() && scale > 0.0) {
        return None;
    }
    let mut g = if c3.abs() > 1e-10 * scale {
        let (a, b, c) = (c2 / c3, c1 / c3, c0 / c3);
        let p = b - a * a / 3.0;
        let q = 2.0 * a * a * a / 27.0 - a * b / 3.0 + c;
        let disc = q * q / 4.0 + p * p * p / 27.0;
        if disc >= 0.0 {
            let s = disc.sqrt();
            let big = -(q.signum()) * (q.abs() / 2.0 + s).cbrt();
            let small = if big != 0.0 { -p / (3.0 * big) } else { 0.0 };
            big + small - a / 3.0
        } else {
            // Three real roots: take the largest (p < 0 here).
            let r = 2.0 * (-p / 3.0).sqrt();
            let arg = (3.0 * q / (p * r)).clamp(-1.0, 1.0);
            r * (arg.acos() / 3.0).cos() - a / 3.0
        }
    } else if c2.abs() > 1e-10 * scale {
        let (roots, n) = homogeneous_quadratic(c2, c1 / 2.0, c0);
        let (al, be) = roots[..n].iter().copied().find(|(_, be)| be.abs() > 1e-300)?;
        al / be
    } else if c1.abs() > 1e-10 * scale {
        -c0 / c1
    } else {
        return None;
    };
    for _ in 0..3 {
        let f = ((c3 * g + c2) * g + c1) * g + c0;
        let df = (3.0 * c3 * g + 2.0 * c2) * g + c1;
        if df.abs() > 1e-300 {
            let step = f / df;
            if step.is_finite() {
                g -= step;
            }
        }
    }
    g.is_finite().then_some(g)
}

#[inline(always)]
fn quad(m: &Matrix3<f64>, u: &Vector3<f64>, v: &Vector3<f64>) -> f64 {
    u.dot(&(m * v))
}

/// Any unit vector orthogonal to unit `n`.
#[inline(always)]
fn orthogonal(n: &Vector3<f64>) -> Vector3<f64> {
    let a = if n.x.abs() < 0.6 {
        Vector3::x()
    } else if n.y.abs() < 0.6 {
        Vector3::y()
    } else {
        Vector3::z()
    };
    (a - n * n.dot(&a)).normalize()
}

/// Rotation whose columns are an orthonormal frame built from two difference vectors.
#[inline(always)]
fn frame(d1: &Vector3<f64>, d2: &Vector3<f64>) -> Option<Matrix3<f64>> {
    let e1 = d1.try_normalize(1e-300)?;
    let e3 = d1.cross(d2).try_normalize(1e-300)?;
    let e2 = e3.cross(&e1);
    Some(Matrix3::from_columns(&[e1, e2, e3]))
}

/// P3P with unit bearings `y` and map points `x`.
pub(crate) fn p3p_unit(y: &[Vector3<f64>; 3], x: &[Vector3<f64>; 3]) -> P3pSolutions {
    let mut out = P3pSolutions::new();
    let d12 = x[0] - x[1];
    let d13 = x[0] - x[2];
    let d23 = x[1] - x[2];
    let (a12, a13, a23) = (d12.norm_squared(), d13.norm_squared(), d23.norm_squared());
    let amax = a12.max(a13).max(a23);
    // Coincident or collinear map points (sin of the angle below ~1e-5), or non-finite input.
    if !(amax.is_finite() && a12.min(a13).min(a23) > 1e-12 * amax)
        || d12.cross(&d13).norm_squared() <= 1e-10 * a12 * a13
    {
        return out;
    }
    let (c12, c13, c23) = (y[0].dot(&y[1]), y[0].dot(&y[2]), y[1].dot(&y[2]));
    // Coincident bearings.
    if !(c12 < 1.0 - 1e-12 && c13 < 1.0 - 1e-12 && c23 < 1.0 - 1e-12) {
        return out;
    }
    let (b12, b13, b23) = (-2.0 * c12, -2.0 * c13, -2.0 * c23);
    // Scale-free: divide the homogeneous combinations by a23.
    let (k12, k13) = (a12 / a23, a13 / a23);
    let m12 = Matrix3::new(1.0, b12 / 2.0, 0.0, b12 / 2.0, 1.0, 0.0, 0.0, 0.0, 0.0);
    let m13 = Matrix3::new(1.0, 0.0, b13 / 2.0, 0.0, 0.0, 0.0, b13 / 2.0, 0.0, 1.0);
    let m23 = Matrix3::new(0.0, 0.0, 0.0, 0.0, 1.0, b23 / 2.0, 0.0, b23 / 2.0, 1.0);
    let d1 = m12 - m23 * k12;
    let d2 = m13 - m23 * k13;

    let Some(g) = degenerate_combination(&d1, &d2) else { return out };
    let d0 = d1 + d2 * g;
    let Some(n0) = null_vector(&d0) else { return out };
    let u = orthogonal(&n0);
    let v = n0.cross(&u);
    let (planes, np) = homogeneous_quadratic(quad(&d0, &u, &u), quad(&d0, &u, &v), quad(&d0, &v, &v));

    let msum = m12 + m13 + m23;
    let asum = a12 + a13 + a23;
    let Some(fw) = frame(&d12, &d13) else { return out };
    let fwt = fw.transpose();
    let cw = (x[0] + x[1] + x[2]) / 3.0;
    for &(al, be) in &planes[..np] {
        let Some(dk) = (u * al + v * be).try_normalize(1e-300) else { continue };
        // On this plane D1 and D2 are proportional; use the better conditioned one.
        let q_d1 = (quad(&d1, &n0, &n0), quad(&d1, &n0, &dk), quad(&d1, &dk, &dk));
        let q_d2 = (quad(&d2, &n0, &n0), quad(&d2, &n0, &dk), quad(&d2, &dk, &dk));
        let mag = |q: &(f64, f64, f64)| q.0.abs() + q.1.abs() + q.2.abs();
        let qq = if mag(&q_d1) >= mag(&q_d2) { q_d1 } else { q_d2 };
        let (dirs, nd) = homogeneous_quadratic(qq.0, qq.1, qq.2);
        for &(s, w) in &dirs[..nd] {
            let dir = n0 * s + dk * w;
            let qn = quad(&msum, &dir, &dir);
            if !(qn > 0.0) {
                continue;
            }
            let mut lam = dir * (asum / qn).sqrt();
            if lam.sum() < 0.0 {
                lam = -lam;
            }
            if !(lam.x > 0.0 && lam.y > 0.0 && lam.z > 0.0) {
                continue;
            }
            let Some(lam) = polish(lam, [b12, b13, b23], [a12, a13, a23]) else { continue };
            let pc = [y[0] * lam.x, y[1] * lam.y, y[2] * lam.z];
            let Some(fc) = frame(&(pc[0] - pc[1]), &(pc[0] - pc[2])) else { continue };
            let rot = fc * fwt;
            let cc = (pc[0] + pc[1] + pc[2]) / 3.0;
            let pose = MapToCamera { rotation: rot, translation: cc - rot * cw };
            if pose.is_finite() {
                out.push(pose);
            }
        }
    }
    out
}

/// A real γ with det(D1 + γD2) = 0, the determinant as a cubic in γ from the column triple
/// product.
#[inline(always)]
fn degenerate_combination(d1: &Matrix3<f64>, d2: &Matrix3<f64>) -> Option<f64> {
    let (p1, p2, p3) = (d1.column(0).into_owned(), d1.column(1).into_owned(), d1.column(2).into_owned());
    let (q1, q2, q3) = (d2.column(0).into_owned(), d2.column(1).into_owned(), d2.column(2).into_owned());
    let c0 = p1.dot(&p2.cross(&p3));
    let c1 = q1.dot(&p2.cross(&p3)) + p1.dot(&q2.cross(&p3)) + p1.dot(&p2.cross(&q3));
    let c2 = p1.dot(&q2.cross(&q3)) + q1.dot(&p2.cross(&q3)) + q1.dot(&q2.cross(&p3));
    let c3 = q1.dot(&q2.cross(&q3));
    cubic_real_root(c3, c2, c1, c0)
}

/// The unit null vector of the rank-2 `d0`: the largest cross product of two rows (`None` when
/// `d0` is of lower rank).
#[inline(always)]
fn null_vector(d0: &Matrix3<f64>) -> Option<Vector3<f64>> {
    let (r0, r1, r2) = (d0.row(0).transpose(), d0.row(1).transpose(), d0.row(2).transpose());
    let cands = [r0.cross(&r1), r0.cross(&r2), r1.cross(&r2)];
    let mut n0 = cands[0];
    for c in &cands[1..] {
        if c.norm_squared() > n0.norm_squared() {
            n0 = *c;
        }
    }
    let d0_scale = d0.norm_squared();
    if !(n0.norm_squared() > 1e-20 * d0_scale * d0_scale) {
        return None;
    }
    Some(n0.normalize())
}

/// Gauss–Newton on the three distance equations; `None` if it does not converge to a
/// consistent positive solution (an ill-conditioned sample).
#[inline(always)]
fn polish(mut l: Vector3<f64>, b: [f64; 3], a: [f64; 3]) -> Option<Vector3<f64>> {
    let res = |l: &Vector3<f64>| {
        Vector3::new(
            l.x * l.x + l.y * l.y + b[0] * l.x * l.y - a[0],
            l.x * l.x + l.z * l.z + b[1] * l.x * l.z - a[1],
            l.y * l.y + l.z * l.z + b[2] * l.y * l.z - a[2],
        )
    };
    let mut r = res(&l);
    let mut err = r.amax();
    for _ in 0..5 {
        if err < 1e-13 * a[0].max(a[1]).max(a[2]) {
            break;
        }
        let j = Matrix3::new(
            2.0 * l.x + b[0] * l.y,
            2.0 * l.y + b[0] * l.x,
            0.0,
            2.0 * l.x + b[1] * l.z,
            0.0,
            2.0 * l.z + b[1] * l.x,
            0.0,
            2.0 * l.y + b[2] * l.z,
            2.0 * l.z + b[2] * l.y,
        );
        let Some(ji) = j.try_inverse() else { break };
        let cand = l - ji * r;
        let rc = res(&cand);
        let ec = rc.amax();
        if ec < err {
            l = cand;
            r = rc;
            err = ec;
        } else {
            break;
        }
    }
    let amax = a[0].max(a[1]).max(a[2]);
    (err <= 1e-8 * amax && l.x > 0.0 && l.y > 0.0 && l.z > 0.0 && l.iter().all(|v| v.is_finite())).then_some(l)
}
