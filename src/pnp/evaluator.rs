//! The scoring context of one solve (positions, scorer, scratch), with what turns a hypothesis
//! into a better one: LO-RANSAC's local optimisation, and the final refinement into a
//! [`PnpSolution`].

use super::covariance::covariance;
use super::hypothesis::{Bound, Hypothesis};
use super::lm::{lm_refine, Loss};
use super::ops::Positions;
use super::scorer::Scorer;
use super::{MapToCamera, PnpError, PnpParams, PnpSolution, RobustLoss};

/// Rounds of local optimisation per new best model, and LM iterations per round.
const LO_ROUNDS: usize = 4;
const LO_LM_ITERATIONS: usize = 6;
/// Rounds of the final refinement and their LM iterations.
const FINAL_ROUNDS: usize = 3;
const FINAL_LM_ITERATIONS: usize = 30;

pub(crate) struct Evaluator {
    pub data: Positions,
    pub scorer: Scorer,
    /// Scratch for inlier positions.
    idx_buf: Vec<usize>,
}

impl Evaluator {
    pub(crate) fn new(data: Positions, scorer: Scorer) -> Self {
        let idx_buf = Vec::with_capacity(data.len());
        Self { data, scorer, idx_buf }
    }

    /// LO-RANSAC's inner step: rounds of least squares on the inliers while the ranking cost
    /// improves and the inliers grow.
    pub(crate) fn local_optimization(&mut self, mut h: Hypothesis) -> Hypothesis {
        let loss = Loss::new(RobustLoss::Trivial, 1.0);
        let data = &self.data;
        for _ in 0..LO_ROUNDS {
            data.collect_inliers(&h.pose, &mut self.idx_buf);
            if self.idx_buf.len() < 4 {
                break;
            }
            let (cand, _, _) = lm_refine(&data.cam, &data.px, &data.pw, &self.idx_buf, h.pose, &loss, LO_LM_ITERATIONS);
            let Some(next) = self.scorer.rescore(data, &cand, Bound::of(&h)) else { break };
            if !(next.cost < h.cost) {
                break;
            }
            let grew = next.inliers > h.inliers;
            h = next;
            if !grew {
                break;
            }
        }
        h
    }

    /// Refines `pose` on its inliers (when `params.refine`) and measures it; an error when it
    /// has fewer than `required` inliers. `input_len`: correspondences in the input.
    pub(crate) fn solution(
        &mut self,
        mut pose: MapToCamera,
        params: &PnpParams,
        required: usize,
        input_len: usize,
        iterations: usize,
    ) -> Result<PnpSolution, PnpError> {
        if params.refine {
            pose = self.final_refinement(pose, params, required);
        }
        let data = &self.data;
        data.collect_inliers(&pose, &mut self.idx_buf);
        let num_inliers = self.idx_buf.len();
        if num_inliers < required {
            return Err(PnpError::NoConsensus { inliers: num_inliers, required });
        }
        let sq: f64 = self.idx_buf.iter().map(|&i| data.err2(&pose, i)).sum();
        let rmse_px = (sq / num_inliers as f64).sqrt();
        let cov = covariance(&data.cam, &data.px, &data.pw, &self.idx_buf, &pose)
            .ok_or(PnpError::Degenerate("pose covariance is not finite"))?;
        let mut inliers = vec![false; input_len];
        for &i in &self.idx_buf {
            inliers[data.original[i]] = true;
        }
        Ok(PnpSolution {
            pose: pose.to_camera_to_map(),
            inliers,
            num_inliers,
            iterations,
            rmse_px,
            covariance: cov,
            alternatives: Vec::new(),
        })
    }

    /// Rounds of robust LM on the inliers while they change; a round that loses the consensus
    /// (fewer than `required` inliers) keeps the pose before it.
    fn final_refinement(&mut self, mut pose: MapToCamera, params: &PnpParams, required: usize) -> MapToCamera {
        let loss = Loss::new(params.loss, params.loss_scale_px);
        let data = &self.data;
        let mut prev: Vec<usize> = Vec::new();
        data.collect_inliers(&pose, &mut self.idx_buf);
        for _ in 0..FINAL_ROUNDS {
            if self.idx_buf.len() < 4 || self.idx_buf == prev {
                break;
            }
            let (cand, _, _) =
                lm_refine(&data.cam, &data.px, &data.pw, &self.idx_buf, pose, &loss, FINAL_LM_ITERATIONS);
            std::mem::swap(&mut prev, &mut self.idx_buf);
            data.collect_inliers(&cand, &mut self.idx_buf);
            if self.idx_buf.len() < required.min(prev.len()) {
                // Refinement lost the consensus: keep the unrefined pose.
                std::mem::swap(&mut prev, &mut self.idx_buf);
                break;
            }
            pose = cand;
        }
        pose
    }
}
