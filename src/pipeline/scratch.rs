//! The per-frame buffers a [`super::Localizer`] owns and refills frame after frame, so that a
//! frame allocates none of them again once a frame as large was seen: the frame's geometry (and
//! what its alignment works in) and PnP's inputs.

use nalgebra::{Point2, Point3};

use crate::frame::Frame;
use crate::geometry::{FrameGeometry, GeometryScratch};
use crate::reject::Rejection;

/// One frame's working buffers (contents meaningful only during [`super::Localizer::process`]).
#[derive(Debug, Default)]
pub(super) struct FrameScratch {
    /// Rays, prior depths and the aligned image cloud of the frame's correspondences.
    pub geometry: FrameGeometry,
    pub geometry_work: GeometryScratch,
    /// PnP's input: the correspondences it sees (the rejector's kept ones, best first, or all),
    /// as indices into the frame, their pixels, map points, scores and prior coordinates.
    pub subset: Vec<usize>,
    pub pixels: Vec<Point2<f64>>,
    pub points: Vec<Point3<f64>>,
    pub scores: Vec<f32>,
    pub priors: Vec<f64>,
}

impl FrameScratch {
    /// Fills PnP's inputs from `frame` and what the rejector decided (`None`: no rejector, every
    /// correspondence, no scores). Prior coordinates only when the geometry has a prior.
    pub fn fill_pnp_inputs(&mut self, frame: &Frame, rejection: Option<&Rejection>) {
        self.subset.clear();
        match rejection {
            Some(r) => self.subset.extend_from_slice(&r.kept),
            None => self.subset.extend(0..frame.correspondences.len()),
        }
        let chosen = || self.subset.iter().map(|&i| &frame.correspondences[i]);
        self.pixels.clear();
        self.pixels.extend(chosen().map(|c| c.pixel));
        self.points.clear();
        self.points.extend(chosen().map(|c| c.point));
        self.scores.clear();
        if let Some(r) = rejection {
            self.scores.extend(self.subset.iter().map(|&i| r.scores[i]));
        }
        self.priors.clear();
        if self.geometry.has_prior() {
            self.priors.extend(self.subset.iter().map(|&i| self.geometry.prior_coordinate[i]));
        }
    }

    /// The scores PnP samples by (PROSAC), when a rejector gave them.
    pub fn scores(&self, rejection: Option<&Rejection>) -> Option<&[f32]> {
        rejection.map(|_| self.scores.as_slice())
    }

    /// The prior coordinates of PnP's correspondences, when the frame has a prior.
    pub fn priors(&self) -> Option<&[f64]> {
        self.geometry.has_prior().then_some(self.priors.as_slice())
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Localization, Localizer, LocalizerParams, Method};
    use crate::synth::{generate, SynthConfig};

    /// What a frame's result is made of, timings left out.
    fn outcome(l: &Localization) -> String {
        format!(
            "{:?} {:?} {:?} {} {} {:?} {:?} {} {:?}",
            l.pose,
            l.covariance,
            l.kept,
            l.num_inliers,
            l.pnp_iterations,
            l.scale_shift,
            l.prior_quality,
            l.fast_path,
            l.failure
        )
    }

    /// A localizer that reuses its buffers gives every frame what a fresh one gives, whatever
    /// came before: frames of other sizes in any order leave nothing behind.
    fn reuse_changes_nothing(method: Method) {
        let mut frames = Vec::new();
        let mut map = None;
        for n in [600, 150, 900] {
            let config = SynthConfig { frames: 2, correspondences: n, seed: 3, ..SynthConfig::preset("hard").unwrap() };
            let scene = generate(&config);
            map.get_or_insert(scene.map);
            frames.extend(scene.frames);
        }
        let map = map.unwrap();
        let params = LocalizerParams { method, ..LocalizerParams::default() };
        let Ok(mut reused) = Localizer::new(params.clone()) else {
            eprintln!("skipped: {} cannot run here (ONNX Runtime?)", method.name());
            return;
        };
        reused.set_map(&map);
        for frame in frames.iter().chain(frames.iter().rev()) {
            let mut fresh = Localizer::new(params.clone()).unwrap();
            fresh.set_map(&map);
            assert_eq!(outcome(&reused.process(frame)), outcome(&fresh.process(frame)), "{:?}", frame.stamp);
        }
    }

    #[test]
    fn reused_buffers_change_nothing_spectral() {
        reuse_changes_nothing(Method::Consistency);
    }

    #[test]
    fn reused_buffers_change_nothing_network() {
        reuse_changes_nothing(Method::AngleI2p);
    }
}
