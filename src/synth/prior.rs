//! The simulated monocular depth prior, as `depth_prior` in `make_rgbd_bags.py` makes it:
//! area-downsampled ground truth with holes filled, times a low-frequency warp field
//! (1 + amp · bicubic-upsampled 3×4 grid of normals, normalised), Gaussian-blurred, then
//! `round((blurred − t) / s, 3)` with a per-frame scale `s` (log-uniform) and shift `t`.

use rand::rngs::StdRng;
use rand::RngExt;
use rand_distr::StandardNormal;

use crate::geometry::DepthImage;

/// Prior parameters for one frame.
#[derive(Clone, Copy, Debug)]
pub struct PriorParams {
    pub width: u32,
    pub height: u32,
    pub warp_amplitude: f64,
    pub blur_sigma: f64,
    pub scale_range: [f64; 2],
    /// t ~ U(−f, f) · median depth.
    pub shift_fraction: f64,
    pub kind: super::SynthPriorKind,
}

/// The prior and the affine map back to metric depth: `depth ≈ scale · prior + shift`.
#[derive(Clone, Debug)]
pub struct Prior {
    pub image: DepthImage,
    pub scale: f64,
    pub shift: f64,
}

/// A dense row-major f64 image.
#[derive(Clone, Debug)]
pub(crate) struct Grid {
    pub w: usize,
    pub h: usize,
    pub data: Vec<f64>,
}

impl Grid {
    fn get_clamped(&self, x: i64, y: i64) -> f64 {
        let x = x.clamp(0, self.w as i64 - 1) as usize;
        let y = y.clamp(0, self.h as i64 - 1) as usize;
        self.data[y * self.w + x]
    }
}

/// Area-average resampling of `src` (w×h, values ≤ 0 or non-finite unknown) to `dw×dh`,
/// averaging over known pixels only; an output pixel with no known source is 0 (unknown).
pub(crate) fn area_downsample(src: &[f32], w: usize, h: usize, dw: usize, dh: usize) -> Grid {
    let mut data = vec![0.0; dw * dh];
    if w == 0 || h == 0 || dw == 0 || dh == 0 || src.len() != w * h {
        return Grid { w: dw, h: dh, data };
    }
    let (rx, ry) = (w as f64 / dw as f64, h as f64 / dh as f64);
    for oy in 0..dh {
        let (y0, y1) = (oy as f64 * ry, (oy + 1) as f64 * ry);
        for ox in 0..dw {
            let (x0, x1) = (ox as f64 * rx, (ox + 1) as f64 * rx);
            let (mut sum, mut weight) = (0.0, 0.0);
            for sy in (y0.floor() as usize)..(y1.ceil() as usize).min(h) {
                let wy = (y1.min(sy as f64 + 1.0) - y0.max(sy as f64)).max(0.0);
                for sx in (x0.floor() as usize)..(x1.ceil() as usize).min(w) {
                    let wx = (x1.min(sx as f64 + 1.0) - x0.max(sx as f64)).max(0.0);
                    let d = src[sy * w + sx];
                    if d.is_finite() && d > 0.0 {
                        sum += wx * wy * d as f64;
                        weight += wx * wy;
                    }
                }
            }
            if weight > 1e-12 {
                data[oy * dw + ox] = sum / weight;
            }
        }
    }
    Grid { w: dw, h: dh, data }
}

/// Fills unknown (≤ 0) pixels by repeatedly averaging known 4-neighbours; all-unknown → 1.
pub(crate) fn fill_holes(g: &mut Grid) {
    if !g.data.iter().any(|&d| d > 0.0) {
        g.data.iter_mut().for_each(|d| *d = 1.0);
        return;
    }
    loop {
        let holes: Vec<usize> = (0..g.data.len()).filter(|&i| g.data[i] <= 0.0).collect();
        if holes.is_empty() {
            return;
        }
        let mut updates = Vec::new();
        for &i in &holes {
            let (x, y) = ((i % g.w) as i64, (i / g.w) as i64);
            let (mut sum, mut n) = (0.0, 0);
            for (dx, dy) in [(-1, 0), (1, 0), (0, -1), (0, 1)] {
                let (nx, ny) = (x + dx, y + dy);
                if nx >= 0 && ny >= 0 && nx < g.w as i64 && ny < g.h as i64 {
                    let d = g.data[ny as usize * g.w + nx as usize];
                    if d > 0.0 {
                        sum += d;
                        n += 1;
                    }
                }
            }
            if n > 0 {
                updates.push((i, sum / n as f64));
            }
        }
        if updates.is_empty() {
            return;
        }
        for (i, d) in updates {
            g.data[i] = d;
        }
    }
}

/// Bicubic kernel with a = −0.75 (OpenCV's INTER_CUBIC).
fn cubic(x: f64) -> f64 {
    let a = -0.75;
    let x = x.abs();
    if x <= 1.0 {
        ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0
    } else if x < 2.0 {
        ((a * x - 5.0 * a) * x + 8.0 * a) * x - 4.0 * a
    } else {
        0.0
    }
}

/// Bicubic resize with pixel-centre alignment and replicated borders.
pub(crate) fn bicubic_resize(src: &Grid, dw: usize, dh: usize) -> Grid {
    let mut data = vec![0.0; dw * dh];
    if src.w == 0 || src.h == 0 {
        return Grid { w: dw, h: dh, data };
    }
    let (rx, ry) = (src.w as f64 / dw as f64, src.h as f64 / dh as f64);
    for oy in 0..dh {
        let y = (oy as f64 + 0.5) * ry - 0.5;
        let (yi, fy) = (y.floor() as i64, y - y.floor());
        for ox in 0..dw {
            let x = (ox as f64 + 0.5) * rx - 0.5;
            let (xi, fx) = (x.floor() as i64, x - x.floor());
            let mut v = 0.0;
            for j in -1..=2 {
                let wy = cubic(fy - j as f64);
                for i in -1..=2 {
                    v += wy * cubic(fx - i as f64) * src.get_clamped(xi + i, yi + j);
                }
            }
            data[oy * dw + ox] = v;
        }
    }
    Grid { w: dw, h: dh, data }
}

/// Reflect-101 index (OpenCV's default border).
fn reflect101(i: i64, n: usize) -> usize {
    if n <= 1 {
        return 0;
    }
    let n = n as i64;
    let period = 2 * (n - 1);
    let mut i = i.rem_euclid(period);
    if i >= n {
        i = period - i;
    }
    i as usize
}

/// Separable Gaussian blur (radius ⌈4σ⌉, reflect-101 borders); σ ≤ 0 is a no-op.
pub(crate) fn gaussian_blur(g: &Grid, sigma: f64) -> Grid {
    if sigma.is_nan() || sigma <= 0.0 || g.data.is_empty() {
        return g.clone();
    }
    let r = (4.0 * sigma).ceil() as i64;
    let kernel: Vec<f64> = (-r..=r).map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp()).collect();
    let total: f64 = kernel.iter().sum();
    let kernel: Vec<f64> = kernel.iter().map(|k| k / total).collect();
    let mut tmp = vec![0.0; g.data.len()];
    for y in 0..g.h {
        for x in 0..g.w {
            let mut v = 0.0;
            for (k, w) in kernel.iter().enumerate() {
                v += w * g.data[y * g.w + reflect101(x as i64 + k as i64 - r, g.w)];
            }
            tmp[y * g.w + x] = v;
        }
    }
    let mut out = vec![0.0; g.data.len()];
    for y in 0..g.h {
        for x in 0..g.w {
            let mut v = 0.0;
            for (k, w) in kernel.iter().enumerate() {
                v += w * tmp[reflect101(y as i64 + k as i64 - r, g.h) * g.w + x];
            }
            out[y * g.w + x] = v;
        }
    }
    Grid { w: g.w, h: g.h, data: out }
}

fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(|a, b| a.total_cmp(b));
    Some(values[values.len() / 2])
}

/// Makes the prior of a metric depth image (`width`×`height`, 0 = unknown).
pub fn depth_prior(depth: &DepthImage, params: &PriorParams, rng: &mut StdRng) -> Prior {
    let (dw, dh) = (params.width.max(1) as usize, params.height.max(1) as usize);
    let mut small = area_downsample(&depth.data, depth.width as usize, depth.height as usize, dw, dh);
    fill_holes(&mut small);
    let grid = Grid { w: 4, h: 3, data: (0..12).map(|_| rng.sample::<f64, _>(StandardNormal)).collect() };
    let field = bicubic_resize(&grid, dw, dh);
    let max_abs = field.data.iter().fold(1e-6_f64, |m, v| m.max(v.abs()));
    let amp = params.warp_amplitude.max(0.0);
    let warped = Grid {
        w: dw,
        h: dh,
        data: small.data.iter().zip(&field.data).map(|(d, f)| d * (1.0 + amp * f / max_abs)).collect(),
    };
    let warped = match params.kind {
        super::SynthPriorKind::Harsh => harsh_errors(warped, rng),
        _ => warped,
    };
    let blurred = gaussian_blur(&warped, params.blur_sigma);
    if params.kind == super::SynthPriorKind::Disparity {
        return disparity(&blurred, params, rng);
    }
    let [lo, hi] = params.scale_range;
    let (lo, hi) = (lo.max(1e-6), hi.max(lo.max(1e-6)));
    let scale = (lo.ln() + rng.random::<f64>() * (hi.ln() - lo.ln())).exp();
    let mut positive: Vec<f64> = small.data.iter().copied().filter(|d| *d > 0.0).collect();
    let med = median(&mut positive).unwrap_or(1.0);
    let mut shift = (2.0 * rng.random::<f64>() - 1.0) * params.shift_fraction.max(0.0) * med;
    // Keep every prior value positive (a non-positive value would read as "unknown").
    let min_blurred = blurred.data.iter().copied().fold(f64::INFINITY, f64::min);
    if min_blurred.is_finite() {
        shift = shift.min(min_blurred - 0.05 * med);
    }
    let data = blurred.data.iter().map(|b| (((b - shift) / scale) * 1000.0).round() as f32 / 1000.0).collect();
    Prior { image: DepthImage::new(dw as u32, dh as u32, data), scale, shift }
}

/// The errors of real metric-like networks on top of the warp: 4–8 object-sized regions
/// (ellipses of 8–25 % of the width) off by up to ±15 %, and a monotonic compression of far
/// depths, `m·(d/m)^γ` with γ ∈ [0.75, 0.9] about the median m. Edges are smeared by the blur
/// that follows.
fn harsh_errors(mut g: Grid, rng: &mut StdRng) -> Grid {
    let (w, h) = (g.w as f64, g.h as f64);
    for _ in 0..4 + rng.random_range(0..5) {
        let (cx, cy) = (rng.random::<f64>() * w, rng.random::<f64>() * h);
        let (rx, ry) = (w * (0.08 + 0.17 * rng.random::<f64>()), w * (0.08 + 0.17 * rng.random::<f64>()));
        let factor = 1.0 + 0.15 * (2.0 * rng.random::<f64>() - 1.0);
        for (i, d) in g.data.iter_mut().enumerate() {
            let (x, y) = ((i % g.w) as f64, (i / g.w) as f64);
            if ((x - cx) / rx).powi(2) + ((y - cy) / ry).powi(2) < 1.0 {
                *d *= factor;
            }
        }
    }
    let mut positive: Vec<f64> = g.data.iter().copied().filter(|d| *d > 0.0).collect();
    let m = median(&mut positive).unwrap_or(1.0);
    let gamma = 0.75 + 0.15 * rng.random::<f64>();
    g.data.iter_mut().filter(|d| **d > 0.0).for_each(|d| *d = m * (*d / m).powf(gamma));
    g
}

/// Affine-invariant disparity of a (warped, blurred) depth: `scale/depth + shift`, the scale
/// log-uniform in the range, the shift 20–60 % of the median `scale/depth`.
fn disparity(depth: &Grid, params: &PriorParams, rng: &mut StdRng) -> Prior {
    let [lo, hi] = params.scale_range;
    let (lo, hi) = (lo.max(1e-6), hi.max(lo.max(1e-6)));
    let scale = (lo.ln() + rng.random::<f64>() * (hi.ln() - lo.ln())).exp();
    let mut inverse: Vec<f64> = depth.data.iter().filter(|d| **d > 0.0).map(|d| scale / d).collect();
    let med = median(&mut inverse).unwrap_or(1.0);
    let shift = (0.2 + 0.4 * rng.random::<f64>()) * med;
    let data = depth
        .data
        .iter()
        .map(|&d| if d > 0.0 { (((scale / d + shift) * 1e4).round() / 1e4) as f32 } else { 0.0 })
        .collect();
    Prior { image: DepthImage::new(depth.w as u32, depth.h as u32, data), scale, shift }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn area_downsample_averages_known_only() {
        let src = [1.0, 3.0, 0.0, 2.0, 5.0, 5.0, 5.0, 5.0];
        let g = area_downsample(&src, 4, 2, 2, 1);
        assert!((g.data[0] - 3.5).abs() < 1e-12);
        assert!((g.data[1] - 4.0).abs() < 1e-12);
    }

    #[test]
    fn fill_holes_fills_everything() {
        let mut g = Grid { w: 3, h: 3, data: vec![0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0] };
        fill_holes(&mut g);
        assert!(g.data.iter().all(|&d| (d - 2.0).abs() < 1e-12));
    }

    #[test]
    fn blur_and_resize_preserve_constants() {
        let g = Grid { w: 4, h: 3, data: vec![1.5; 12] };
        let r = bicubic_resize(&g, 40, 30);
        assert!(r.data.iter().all(|&d| (d - 1.5).abs() < 1e-9));
        let b = gaussian_blur(&r, 2.0);
        assert!(b.data.iter().all(|&d| (d - 1.5).abs() < 1e-9));
    }

    #[test]
    fn reflect101_indices() {
        assert_eq!(reflect101(-1, 5), 1);
        assert_eq!(reflect101(-2, 5), 2);
        assert_eq!(reflect101(5, 5), 3);
        assert_eq!(reflect101(6, 5), 2);
        assert_eq!(reflect101(3, 1), 0);
    }
}
