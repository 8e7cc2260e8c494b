//! The per-frame geometry the whole core works on: the rejectors, PnP's prior depths and the
//! verifier's prior all come from it.

use nalgebra::{Point2, Point3, Vector3};

use super::align::{estimate_scale_shift, ScaleShift, ScaleShiftParams};
use super::normals::image_normals_into;
use super::{DepthImage, DepthKind, Intrinsics, PointIndex, PriorSpace};

/// What one frame gives its geometry: the correspondences split into pixels, map points and the
/// matcher's scores, and the dense depth prior if any.
pub struct FrameParts<'a> {
    pub intrinsics: Intrinsics,
    pub pixels: Vec<Point2<f64>>,
    pub map_points: Vec<Point3<f64>>,
    pub matcher_scores: Vec<f32>,
    pub depth_prior: Option<&'a DepthImage>,
}

/// The per-frame geometry every rejector works on: the correspondences split into pixels and
/// map points, each pixel's ray and prior depth, and the image cloud o_i (eq. 2) after the
/// prior's scale and shift were aligned to the map (when that succeeded).
#[derive(Clone, Debug, Default)]
pub struct FrameGeometry {
    pub intrinsics: Option<Intrinsics>,
    pub pixels: Vec<Point2<f64>>,
    pub map_points: Vec<Point3<f64>>,
    pub matcher_scores: Vec<f32>,
    /// Each pixel's ray scaled to z = 1.
    pub rays: Vec<Vector3<f64>>,
    /// Prior coordinate per pixel ([`DepthKind::coordinate`]: affine in depth or in inverse
    /// depth, see `prior_space`); NaN where unknown.
    pub prior_coordinate: Vec<f64>,
    /// The space in which `prior_coordinate` is affine.
    pub prior_space: PriorSpace,
    /// The prior's map to metric depth, when estimated.
    pub scale_shift: Option<ScaleShift>,
    /// o_i: pixels back-projected with the aligned prior (prior units if not aligned).
    pub image_points: Vec<Point3<f64>>,
    /// n^I: normals of the image cloud from the dense prior, towards the camera (zero where
    /// unknown); empty without a prior.
    pub image_normals: Vec<Vector3<f64>>,
}

/// What building a frame's geometry works in besides the geometry itself (the alignment's
/// voting inputs), kept between frames by whoever rebuilds geometry frame after frame.
#[derive(Clone, Debug, Default)]
pub struct GeometryScratch {
    known: Vec<usize>,
    rays: Vec<Vector3<f64>>,
    prior: Vec<f64>,
    map: Vec<Point3<f64>>,
    flat: Vec<Point3<f32>>,
    pairs: Vec<(u32, u32)>,
}

impl FrameGeometry {
    /// Builds the geometry of one frame's correspondences. Without a depth prior,
    /// `prior_coordinate` is all NaN and the image cloud empty; rejectors that need it report that.
    pub fn new(parts: FrameParts, kind: DepthKind, align: Option<&ScaleShiftParams>) -> Self {
        let FrameParts { intrinsics, pixels, map_points, matcher_scores, depth_prior } = parts;
        let mut geometry = Self { pixels, map_points, matcher_scores, ..Self::default() };
        geometry.derive(intrinsics, depth_prior, kind, align, &mut GeometryScratch::default());
        geometry
    }

    /// Everything else from `pixels`, `map_points` and `matcher_scores` (already filled): rays,
    /// prior coordinates, the alignment, the image cloud and its normals, each refilled in its
    /// own buffer (a geometry kept across frames allocates them once).
    pub fn derive(
        &mut self,
        k: Intrinsics,
        depth_prior: Option<&DepthImage>,
        kind: DepthKind,
        align: Option<&ScaleShiftParams>,
        scratch: &mut GeometryScratch,
    ) {
        self.intrinsics = Some(k);
        self.rays.clear();
        self.rays.extend(self.pixels.iter().map(|p| Vector3::new((p.x - k.cx) / k.fx, (p.y - k.cy) / k.fy, 1.0)));
        self.prior_coordinate.clear();
        match depth_prior {
            Some(prior) => self.prior_coordinate.extend(
                self.pixels.iter().map(|p| prior.sample(p, k.width, k.height).map_or(f64::NAN, |v| kind.coordinate(v))),
            ),
            None => self.prior_coordinate.resize(self.pixels.len(), f64::NAN),
        }
        self.prior_space = kind.space();
        self.scale_shift = None;
        self.image_points.clear();
        self.image_normals.clear();
        if depth_prior.is_some() {
            if let Some(params) = align {
                self.scale_shift = self.estimate_scale_shift(params, scratch);
            }
            self.lift();
            let mut normals = std::mem::take(&mut self.image_normals);
            image_normals_into(&mut normals, &k, depth_prior, self, kind);
            self.image_normals = normals;
        }
    }

    pub fn len(&self) -> usize {
        self.pixels.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pixels.is_empty()
    }

    pub fn has_prior(&self) -> bool {
        !self.image_points.is_empty()
    }

    /// Scale and shift of the prior from the correspondences themselves; local pairs are each
    /// pixel's nearest neighbours in the image.
    fn estimate_scale_shift(&self, params: &ScaleShiftParams, s: &mut GeometryScratch) -> Option<ScaleShift> {
        s.known.clear();
        s.known.extend(
            (0..self.len()).filter(|&i| self.prior_coordinate[i].is_finite() && self.prior_coordinate[i] > 0.0),
        );
        s.rays.clear();
        s.rays.extend(s.known.iter().map(|&i| self.rays[i]));
        s.prior.clear();
        s.prior.extend(s.known.iter().map(|&i| self.prior_coordinate[i]));
        s.map.clear();
        s.map.extend(s.known.iter().map(|&i| self.map_points[i]));
        s.flat.clear();
        s.flat.extend(s.known.iter().map(|&i| Point3::new(self.pixels[i].x as f32, self.pixels[i].y as f32, 0.0)));
        let index = PointIndex::new(&s.flat);
        let neighbours = params.local_neighbours.min(params.max_local_pairs / s.known.len().max(1)).max(1);
        s.pairs.clear();
        for (a, p) in s.flat.iter().enumerate() {
            for b in index.nearest(p, neighbours + 1) {
                if b != a {
                    s.pairs.push((a as u32, b as u32));
                }
            }
        }
        estimate_scale_shift(&s.rays, &s.prior, &s.map, &s.pairs, self.prior_space, params)
    }

    /// The prior's map to depth: the estimated one, else the identity of its space.
    pub fn alignment(&self) -> ScaleShift {
        self.scale_shift.unwrap_or(ScaleShift::identity(self.prior_space))
    }

    /// o_i = depth(x_i)·ray_i; unknown prior depths give a NaN point.
    fn lift(&mut self) {
        let align = self.alignment();
        self.image_points.clear();
        self.image_points.extend(self.rays.iter().zip(&self.prior_coordinate).map(|(r, &d)| {
            let z = align.depth(d);
            if z.is_finite() && z > 0.0 {
                Point3::from(r * z)
            } else {
                Point3::new(f64::NAN, f64::NAN, f64::NAN)
            }
        }));
    }
}
