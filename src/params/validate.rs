//! Parameter validation at load: every numeric parameter with a range it must lie in. A value
//! outside it stops the command with an error naming the key, the value and the valid range,
//! instead of failing every frame later (or panicking: `network.neighbours: 0` divides by it).

use super::{AppParams, LocalizerParams, MapSource};
use crate::reject::network::NetworkParams;

/// A parameter outside its valid range.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("parameter {key} = {value} is invalid: must be {range}")]
pub struct InvalidParam {
    /// Dotted name, e.g. `pnp.threshold_px`.
    pub key: &'static str,
    /// The value given, as written.
    pub value: String,
    /// The valid range, in words.
    pub range: &'static str,
}

/// The ranges one check can ask for.
#[derive(Clone, Copy)]
enum Range {
    /// Finite and > 0.
    Positive,
    /// Finite and ≥ 0.
    NonNegative,
    /// In [0, 1].
    Unit,
    /// In (0, 1).
    OpenUnit,
    /// In (0, 1].
    Share,
    /// Finite and ≥ 1.
    AtLeastOne,
}

impl Range {
    fn holds(self, v: f64) -> bool {
        match self {
            Range::Positive => v.is_finite() && v > 0.0,
            Range::NonNegative => v.is_finite() && v >= 0.0,
            Range::Unit => (0.0..=1.0).contains(&v),
            Range::OpenUnit => v > 0.0 && v < 1.0,
            Range::Share => v > 0.0 && v <= 1.0,
            Range::AtLeastOne => v.is_finite() && v >= 1.0,
        }
    }

    fn words(self) -> &'static str {
        match self {
            Range::Positive => "a finite number > 0",
            Range::NonNegative => "a finite number ≥ 0",
            Range::Unit => "in [0, 1]",
            Range::OpenUnit => "in (0, 1), exclusive",
            Range::Share => "in (0, 1]",
            Range::AtLeastOne => "finite, at least 1",
        }
    }
}

fn real(key: &'static str, value: f64, range: Range) -> Result<(), InvalidParam> {
    if range.holds(value) {
        return Ok(());
    }
    Err(InvalidParam { key, value: value.to_string(), range: range.words() })
}

fn at_least(key: &'static str, value: u64, min: u64, range: &'static str) -> Result<(), InvalidParam> {
    if value >= min {
        return Ok(());
    }
    Err(InvalidParam { key, value: value.to_string(), range })
}

/// `node.cameras`: relative ROS names, none repeated.
fn camera_namespaces(cameras: &[String]) -> Result<(), InvalidParam> {
    const RANGE: &str = "distinct relative ROS names (letters, digits, _ and /; not starting with / or a digit, \
                         no // nor a trailing /)";
    for (i, name) in cameras.iter().enumerate() {
        let tokens_ok = name.split('/').all(|t| {
            t.chars().next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
                && t.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        });
        if !tokens_ok || cameras[..i].contains(name) {
            return Err(InvalidParam { key: "node.cameras", value: format!("{name:?}"), range: RANGE });
        }
    }
    Ok(())
}

/// `node.map_source` against `node.map_path`: `file` needs the file, `topic` refuses one.
fn map_source(source: MapSource, map_path: &str) -> Result<(), InvalidParam> {
    let range = match source {
        MapSource::File if map_path.is_empty() => {
            "file_and_topic or topic while node.map_path is empty (file reads it)"
        }
        MapSource::Topic if !map_path.is_empty() => {
            "file_and_topic or file while node.map_path is set (topic ignores it)"
        }
        _ => return Ok(()),
    };
    Err(InvalidParam { key: "node.map_source", value: source.name().to_string(), range })
}

impl AppParams {
    /// Checks every parameter with a range, the localizer's first; the first one outside its
    /// range is the error.
    pub fn validate(&self) -> Result<(), InvalidParam> {
        self.localizer.validate()?;
        self.validate_limits()?;
        self.validate_node()
    }

    fn validate_limits(&self) -> Result<(), InvalidParam> {
        let l = &self.limits;
        at_least("limits.max_correspondences", l.max_correspondences as u64, 1, "at least 1")?;
        at_least("limits.max_image_side", l.max_image_side as u64, 1, "at least 1")?;
        at_least("limits.max_image_pixels", l.max_image_pixels, 1, "at least 1")?;
        at_least("limits.max_map_points", l.max_map_points as u64, 1, "at least 1")?;
        at_least("limits.max_record_bytes", l.max_record_bytes, 1024, "at least 1024 bytes")?;
        at_least("limits.max_pending_frames", l.max_pending_frames as u64, 1, "at least 1")?;
        real("limits.merge_duplicates_above", l.merge_duplicates_above, Range::Unit)
    }

    fn validate_node(&self) -> Result<(), InvalidParam> {
        let n = &self.node;
        real("node.diagnostics_window_s", n.diagnostics_window_s, Range::Positive)?;
        real("node.min_rate_hz", n.min_rate_hz, Range::NonNegative)?;
        real("node.transform_tolerance_s", n.transform_tolerance_s, Range::NonNegative)?;
        real("node.tf_publish_rate_hz", n.tf_publish_rate_hz, Range::NonNegative)?;
        at_least("node.queue_depth", n.queue_depth as u64, 1, "at least 1")?;
        map_source(n.map_source, &n.map_path)?;
        camera_namespaces(&n.cameras)
    }
}

impl LocalizerParams {
    /// Checks every parameter of the core with a range; the first one outside it is the error.
    pub fn validate(&self) -> Result<(), InvalidParam> {
        self.validate_pnp()?;
        self.validate_rejection()?;
        real("tracking.gate", self.tracking.gate, Range::Positive)?;
        real("tracking.settle_gate", self.tracking.settle_gate, Range::NonNegative)
    }

    fn validate_pnp(&self) -> Result<(), InvalidParam> {
        let (p, v, f) = (&self.pnp, &self.verify, &self.final_refine);
        real("pnp.threshold_px", p.threshold_px, Range::Positive)?;
        real("pnp.confidence", p.confidence, Range::OpenUnit)?;
        at_least("pnp.max_iterations", p.max_iterations as u64, 1, "at least 1")?;
        if p.min_iterations > p.max_iterations {
            return Err(InvalidParam {
                key: "pnp.min_iterations",
                value: p.min_iterations.to_string(),
                range: "at most pnp.max_iterations",
            });
        }
        at_least("pnp.min_inliers", p.min_inliers as u64, 3, "at least 3 (P3P)")?;
        real("pnp.loss_scale_px", p.loss_scale_px, Range::Positive)?;
        real("pnp.coverage_cell_px", p.coverage_cell_px, Range::NonNegative)?;
        real("pnp.prior_tolerance", p.prior_tolerance, Range::NonNegative)?;
        real("pnp.reference_focal_px", p.reference_focal_px, Range::NonNegative)?;
        at_least("verify.candidates", v.candidates as u64, 1, "at least 1")?;
        real("verify.accept", v.accept, Range::Unit)?;
        real("verify.min_view", v.min_view, Range::Share)?;
        real("verify.min_trust", v.min_trust, Range::Unit)?;
        real("verify.settle_support", v.settle_support, Range::Unit)?;
        at_least("verify.check_every", v.check_every as u64, 1, "at least 1")?;
        at_least("verify.max_iterations", v.max_iterations as u64, 1, "at least 1")?;
        at_least("verify.max_map_points", v.max_map_points as u64, 1, "at least 1")?;
        real("verify.cell_px", v.cell_px, Range::Positive)?;
        at_least("verify.cull_above_budgets", v.cull_above_budgets as u64, 1, "at least 1")?;
        real("verify.cull_range_m", v.cull_range_m, Range::Positive)?;
        real("verify.render_voxel_m", v.render_voxel_m, Range::Positive)?;
        real("verify.tolerance", v.tolerance, Range::Positive)?;
        real("verify.coverage_weight", v.coverage_weight, Range::NonNegative)?;
        real("verify.min_support_share", v.min_support_share, Range::Unit)?;
        real("final_refine.loss_sigmas", f.loss_sigmas, Range::Positive)?;
        real("final_refine.min_loss_scale_px", f.min_loss_scale_px, Range::Positive)?;
        at_least("final_refine.rounds", f.rounds as u64, 1, "at least 1")?;
        real("final_refine.switch_margin", f.switch_margin, Range::AtLeastOne)?;
        real("covariance.map_error_deg", self.covariance.map_error_deg, Range::NonNegative)?;
        let regions = self.covariance.map_error_regions;
        if !(1..=crate::pnp::MapError::MAX_REGIONS).contains(&regions) {
            let range = "1 to 64 (regions per image axis)";
            return Err(InvalidParam { key: "covariance.map_error_regions", value: regions.to_string(), range });
        }
        let c = &self.cascade;
        at_least("cascade.max_iterations", c.max_iterations as u64, 1, "at least 1")?;
        at_least("cascade.probe_iterations", c.probe_iterations as u64, 1, "at least 1")?;
        if c.min_iterations > c.max_iterations {
            return Err(InvalidParam {
                key: "cascade.min_iterations",
                value: c.min_iterations.to_string(),
                range: "at most cascade.max_iterations",
            });
        }
        real("cascade.min_inlier_ratio", c.min_inlier_ratio, Range::Unit)?;
        real("cascade.min_cell_share", c.min_cell_share, Range::Unit)?;
        real("cascade.confirm_nfa", c.confirm_nfa, Range::NonNegative)?;
        real("cascade.publish_nfa", c.publish_nfa, Range::NonNegative)?;
        real("cascade.prior_nfa", c.prior_nfa, Range::NonNegative)?;
        at_least("cascade.grid_columns", c.grid_columns as u64, 1, "at least 1")
    }

    fn validate_rejection(&self) -> Result<(), InvalidParam> {
        let (s, n, a) = (&self.spectral, &self.network, &self.align);
        real("spectral.sigma_d", s.sigma_d, Range::Positive)?;
        real("spectral.sigma_spread", s.sigma_spread, Range::NonNegative)?;
        real("spectral.sigma_rel", s.sigma_rel, Range::NonNegative)?;
        real("spectral.keep_ratio", s.keep_ratio, Range::Share)?;
        if s.min_keep > s.max_keep {
            return Err(InvalidParam {
                key: "spectral.min_keep",
                value: s.min_keep.to_string(),
                range: "at most spectral.max_keep",
            });
        }
        at_least("spectral.max_keep", s.max_keep as u64, 1, "at least 1")?;
        at_least("spectral.iterations", s.iterations as u64, 1, "at least 1")?;
        real("spectral.tolerance", s.tolerance as f64, Range::Positive)?;
        if s.max_nodes == 1 {
            // One anchor has no pair to be consistent with.
            return Err(InvalidParam {
                key: "spectral.max_nodes",
                value: s.max_nodes.to_string(),
                range: "0 (every correspondence) or at least 2",
            });
        }
        n.validate()?;
        real("align.shift_range", a.shift_range, Range::NonNegative)?;
        at_least("align.shift_steps", a.shift_steps as u64, 1, "at least 1")?;
        real("align.log_scale_window", a.log_scale_window, Range::Positive)?;
        real("align.min_pair_fraction", a.min_pair_fraction, Range::Unit)
    }
}

impl NetworkParams {
    /// The `network.*` ranges: also what a model's metadata is checked with
    /// ([`crate::reject::model_constants`]).
    pub fn validate(&self) -> Result<(), InvalidParam> {
        real("network.tau", self.tau, Range::Unit)?;
        real("network.missing_confidence", self.missing_confidence as f64, Range::Unit)?;
        at_least("network.intra_threads", self.intra_threads as u64, 1, "at least 1")?;
        at_least("network.neighbours", self.graph.neighbours as u64, 1, "at least 1")?;
        at_least("network.keypoints", self.graph.keypoints as u64, 1, "at least 1")?;
        real("network.sigma_d", self.graph.sigma_d, Range::Positive)?;
        at_least("network.keypoint_iterations", self.keypoint_iterations as u64, 1, "at least 1")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid() {
        assert_eq!(AppParams::default().validate(), Ok(()));
        let mut p = AppParams::default();
        p.node.cameras = vec!["cam0".into(), "robot/cam_1".into()];
        assert_eq!(p.validate(), Ok(()));
        p.node.map_path = "map.ply".into();
        for source in [MapSource::FileAndTopic, MapSource::File] {
            p.node.map_source = source;
            assert_eq!(p.validate(), Ok(()));
        }
    }

    #[test]
    fn bad_values_name_key_value_and_range() {
        let cases: Vec<(&str, Box<dyn Fn(&mut AppParams)>)> = vec![
            ("pnp.threshold_px", Box::new(|p| p.localizer.pnp.threshold_px = -1.0)),
            ("pnp.threshold_px", Box::new(|p| p.localizer.pnp.threshold_px = f64::NAN)),
            ("pnp.confidence", Box::new(|p| p.localizer.pnp.confidence = 2.0)),
            ("pnp.max_iterations", Box::new(|p| p.localizer.pnp.max_iterations = 0)),
            ("cascade.min_iterations", Box::new(|p| p.localizer.cascade.min_iterations = 401)),
            ("cascade.confirm_nfa", Box::new(|p| p.localizer.cascade.confirm_nfa = -1.0)),
            ("cascade.publish_nfa", Box::new(|p| p.localizer.cascade.publish_nfa = f64::NAN)),
            ("cascade.prior_nfa", Box::new(|p| p.localizer.cascade.prior_nfa = -1.0)),
            ("network.tau", Box::new(|p| p.localizer.network.tau = 1.5)),
            ("network.missing_confidence", Box::new(|p| p.localizer.network.missing_confidence = -0.5)),
            ("verify.min_support_share", Box::new(|p| p.localizer.verify.min_support_share = 1.5)),
            ("final_refine.switch_margin", Box::new(|p| p.localizer.final_refine.switch_margin = 0.5)),
            ("final_refine.switch_margin", Box::new(|p| p.localizer.final_refine.switch_margin = f64::INFINITY)),
            ("covariance.map_error_deg", Box::new(|p| p.localizer.covariance.map_error_deg = -1.0)),
            ("covariance.map_error_regions", Box::new(|p| p.localizer.covariance.map_error_regions = 0)),
            ("covariance.map_error_regions", Box::new(|p| p.localizer.covariance.map_error_regions = 65)),
            ("tracking.gate", Box::new(|p| p.localizer.tracking.gate = 0.0)),
            ("tracking.settle_gate", Box::new(|p| p.localizer.tracking.settle_gate = -1.0)),
            ("spectral.keep_ratio", Box::new(|p| p.localizer.spectral.keep_ratio = 5.0)),
            ("spectral.max_nodes", Box::new(|p| p.localizer.spectral.max_nodes = 1)),
            ("verify.accept", Box::new(|p| p.localizer.verify.accept = 2.0)),
            ("network.neighbours", Box::new(|p| p.localizer.network.graph.neighbours = 0)),
            ("limits.max_correspondences", Box::new(|p| p.limits.max_correspondences = 0)),
            ("limits.max_image_pixels", Box::new(|p| p.limits.max_image_pixels = 0)),
            ("node.queue_depth", Box::new(|p| p.node.queue_depth = 0)),
            ("node.diagnostics_window_s", Box::new(|p| p.node.diagnostics_window_s = 0.0)),
            ("node.min_rate_hz", Box::new(|p| p.node.min_rate_hz = f64::INFINITY)),
            ("node.tf_publish_rate_hz", Box::new(|p| p.node.tf_publish_rate_hz = -1.0)),
            ("node.cameras", Box::new(|p| p.node.cameras = vec!["/cam0".into()])),
            ("node.cameras", Box::new(|p| p.node.cameras = vec!["cam0".into(), "cam0".into()])),
            ("node.cameras", Box::new(|p| p.node.cameras = vec!["".into()])),
            ("node.cameras", Box::new(|p| p.node.cameras = vec!["robot//cam".into()])),
            ("node.cameras", Box::new(|p| p.node.cameras = vec!["0cam".into()])),
            ("node.map_source", Box::new(|p| p.node.map_source = MapSource::File)),
            (
                "node.map_source",
                Box::new(|p| {
                    p.node.map_source = MapSource::Topic;
                    p.node.map_path = "map.ply".into();
                }),
            ),
        ];
        for (key, set) in cases {
            let mut p = AppParams::default();
            set(&mut p);
            let err = p.validate().unwrap_err();
            assert_eq!(err.key, key);
            let text = err.to_string();
            assert!(text.contains(key) && text.contains("must be"), "{text}");
        }
    }
}
