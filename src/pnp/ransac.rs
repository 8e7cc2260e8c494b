//! Robust estimation as PoseLib shapes it: one loop that composes a [`Sampler`] (uniform or
//! PROSAC), the P3P minimal solver, a [`Scorer`] (MSAC or coverage, with SPRT), LO-RANSAC
//! ([`Evaluator::local_optimization`]), the candidate [`Pool`] of a verifier and the
//! [`Termination`] rule, then the final refinement and covariance.
//!
//! Nothing is allocated inside the sampling loop except by the pool (one bit set per offer).

use super::coverage::{Coverage, PriorCheck};
use super::evaluator::Evaluator;
use super::hypothesis::{Bound, Hypothesis, Sprt};
use super::ops::{check_basic, check_guidance_length, check_spread, finite_pairs, validate, Positions};
use super::p3p::p3p_unit;
use super::pool::Pool;
use super::sampler::Sampler;
use super::scorer::{msac_bounded, Scorer};
use super::termination::Termination;
use super::{Guidance, MapToCamera, PnpError, PnpParams, PnpSolution, Problem};
use crate::rng::WyRand;

/// Robust PnP: the camera-to-map pose from putative pixel ↔ map-point correspondences, most
/// possibly wrong, guided by what [`Guidance`] gives:
///
/// * `scores` (higher = more likely correct, one per correspondence) switch on PROSAC sampling
///   from the top-ranked correspondences, growing to uniform; `None` samples uniformly
///   (plain LO-RANSAC, which also serves as the baseline on raw correspondences).
/// * `prior_depths` (right up to an unknown scale and shift; NaN where unknown): with coverage
///   scoring and `params.prior_tolerance > 0`, a hypothesis' inliers count only when their
///   depths under it agree with the prior through one increasing affine map: a pose that
///   explains true matches and a displaced patch at once puts the two at depths the prior
///   contradicts.
/// * `verification`: with coverage scoring, the `candidates` best distinct hypotheses are kept
///   (a hypothesis competes with the pool's worst, not the best, and SPRT assumes that one's
///   support) and the verifier's choice among them is refined and returned.
///
/// Inliers: reprojection error below `params.threshold_px` and in front of the camera.
/// Deterministic for a given `params.seed`. Non-finite correspondences are ignored (never
/// inliers); errors for invalid intrinsics or parameters, mismatched lengths, fewer than
/// `max(4, min_inliers)` usable correspondences, coincident/collinear map points, or no pose
/// with `min_inliers` inliers.
pub fn solve_pnp_ransac(problem: &Problem, guidance: &Guidance, params: &PnpParams) -> Result<PnpSolution, PnpError> {
    let (mut search, required) = Search::new(problem, guidance, guidance.verification, params)?;
    search.run();
    search.solution(params, required, problem.pixels.len())
}

/// One robust search that can be run in stages: [`RansacSearch::run_until`] draws up to a
/// number of hypotheses in all and stops, [`RansacSearch::solution`] says what it has found so
/// far, and a later stage goes on from there (the same sampler, random stream and best
/// hypothesis) instead of drawing the first hypotheses again. It has no verifier (a pool is
/// chosen among once, at the end: [`solve_pnp_ransac`]).
pub struct RansacSearch {
    search: Search<'static>,
    params: PnpParams,
    required: usize,
    input_len: usize,
}

impl RansacSearch {
    /// A search not yet started, set up as [`solve_pnp_ransac`] sets it up (the same errors),
    /// without the guidance's verification.
    pub fn new(problem: &Problem, guidance: &Guidance, params: &PnpParams) -> Result<Self, PnpError> {
        let (search, required) = Search::new(problem, guidance, None, params)?;
        Ok(Self { search, params: params.clone(), required, input_len: problem.pixels.len() })
    }

    /// Draws on until `iterations` hypotheses in all (at least `min_iterations`, then until the
    /// adaptive stopping rule ends it), from where the last stage stopped. The sampler keeps
    /// the schedule it was set up with: PROSAC, grown to every correspondence by
    /// `params.max_iterations`, samples uniformly beyond.
    pub fn run_until(&mut self, iterations: usize, min_iterations: usize) {
        self.search.termination.extend(min_iterations, iterations);
        self.search.run();
    }

    /// Hypotheses drawn so far.
    pub fn iterations(&self) -> usize {
        self.search.iterations
    }

    /// Whether its adaptive stopping rule is met: the draws made would have found a consensus
    /// larger than the best one's with the search's confidence (PROSAC's rule: on the
    /// best-ranked prefix where that is likeliest, among correspondences ranked by score).
    pub fn confident(&self) -> bool {
        self.search.termination.confident(self.search.iterations)
    }

    /// What the search has found so far, refined and measured as [`solve_pnp_ransac`] returns
    /// it; the search may go on after.
    pub fn solution(&mut self) -> Result<PnpSolution, PnpError> {
        self.search.solution(&self.params, self.required, self.input_len)
    }

    /// The best hypothesis so far as it was drawn and locally optimised, measured as
    /// [`RansacSearch::solution`] measures it but without the final refinement: for a caller
    /// that refines the pose on its own.
    pub fn best_as_drawn(&mut self) -> Result<PnpSolution, PnpError> {
        let params = PnpParams { refine: false, ..self.params.clone() };
        self.search.solution(&params, self.required, self.input_len)
    }
}

/// The state of one robust search.
struct Search<'a> {
    evaluator: Evaluator,
    sampler: Sampler,
    pool: Option<Pool<'a>>,
    termination: Termination,
    rng: WyRand,
    local_optimization: bool,
    gate: Option<super::PoseGate>,
    best: Option<Hypothesis>,
    /// Minimal samples drawn.
    iterations: usize,
    /// The SPRT of the pool's worst support (which changes far less often than it is asked).
    pool_sprt: SprtCache,
}

/// The SPRT for the last support asked, kept until another is asked.
#[derive(Default)]
struct SprtCache {
    support: Option<usize>,
    sprt: Option<Sprt>,
}

impl SprtCache {
    /// [`Sprt::new`] for a support ratio of `support` among `n`.
    fn for_support(&mut self, support: usize, n: usize) -> Option<Sprt> {
        if self.support != Some(support) {
            self.support = Some(support);
            self.sprt = Sprt::new(support as f64 / n as f64);
        }
        self.sprt
    }
}

impl<'a> Search<'a> {
    /// A search of `problem` as `guidance` and `params` say, with `verification` (the
    /// guidance's, or none), and the inliers a pose needs.
    fn new(
        problem: &Problem,
        guidance: &Guidance,
        verification: Option<super::Verification<'a>>,
        params: &PnpParams,
    ) -> Result<(Self, usize), PnpError> {
        let Guidance { scores, prior_depths, prior_space, gate, .. } = *guidance;
        check_basic(problem.intrinsics, problem.pixels.len(), problem.points.len())?;
        check_guidance_length(problem, prior_depths.map(<[f64]>::len))?;
        check_guidance_length(problem, scores.map(<[f32]>::len))?;
        validate(params)?;
        let pairs = finite_pairs(problem.pixels, problem.points);
        let required = params.min_inliers.max(4);
        if pairs.pixels.len() < required {
            return Err(PnpError::TooFewPoints { usable: pairs.pixels.len(), required });
        }
        check_spread(&pairs.points)?;

        let mut rng = WyRand::new(params.seed);
        let data = Positions::shuffled(problem.intrinsics, pairs, params.threshold_px, &mut rng);
        let sampler = Sampler::new(&data, scores, params.max_iterations);
        let prior = prior_depths.filter(|_| params.prior_tolerance > 0.0).map(|d| PriorCheck {
            values: data.original.iter().map(|&i| d[i]).collect(),
            space: prior_space,
            tolerance: params.prior_tolerance,
        });
        let scorer = match Coverage::new(&data.px, params.coverage_cell_px, prior) {
            Some(coverage) => Scorer::Coverage(coverage),
            None => Scorer::Msac,
        };
        let pool = verification
            .filter(|v| v.candidates > 0 && matches!(scorer, Scorer::Coverage(_)))
            .map(|v| Pool::new(v, params.local_optimization));
        let termination = Termination::new(params, pool.as_ref(), data.len());
        let search = Search {
            evaluator: Evaluator::new(data, scorer),
            sampler,
            pool,
            termination,
            rng,
            local_optimization: params.local_optimization,
            gate: gate.cloned(),
            best: None,
            iterations: 0,
            pool_sprt: SprtCache::default(),
        };
        Ok((search, required))
    }

    /// The verifier's choice (or the best hypothesis) refined and measured; `input_len`:
    /// correspondences in the input.
    fn solution(&mut self, params: &PnpParams, required: usize, input_len: usize) -> Result<PnpSolution, PnpError> {
        let pose = self.choice().ok_or(PnpError::NoConsensus { inliers: 0, required })?;
        let alternatives = self.pool.as_ref().map_or_else(Vec::new, |p| p.alternatives());
        let mut solution = self.evaluator.solution(pose, params, required, input_len, self.iterations)?;
        solution.alternatives = alternatives.iter().map(MapToCamera::to_camera_to_map).collect();
        Ok(solution)
    }

    /// Draws minimal samples until the termination rule stops.
    fn run(&mut self) {
        let n = self.evaluator.data.len();
        while self.iterations < self.termination.loop_max {
            if self.termination.should_stop(self.iterations, self.pool.as_mut(), &mut self.evaluator) {
                break;
            }
            self.iterations += 1;
            let s = self.sampler.sample(&mut self.rng);
            let data = &self.evaluator.data;
            let sols = p3p_unit(
                &[data.bearings[s[0]], data.bearings[s[1]], data.bearings[s[2]]],
                &[data.pw[s[0]], data.pw[s[1]], data.pw[s[2]]],
            );
            let start = if sols.is_empty() { 0 } else { self.rng.below(n) };
            let mut improved = false;
            for pose in sols.iter() {
                if let Some(h) = self.consider(pose, start) {
                    self.best = Some(h);
                    improved = true;
                }
            }
            if let (true, Some(best)) = (improved, &self.best) {
                self.termination.on_new_best(best, &self.sampler, &self.evaluator);
            }
        }
    }

    /// Scores a pose from the minimal solver (from position `start`); a better one than the
    /// best so far comes back locally optimised. With a pool, every pose that enters it is
    /// offered, and the local optimum too.
    fn consider(&mut self, pose: &MapToCamera, start: usize) -> Option<Hypothesis> {
        if self.gate.as_ref().is_some_and(|g| !g.admits(pose)) {
            return None;
        }
        let best = self.best.as_ref().map_or(Bound::NONE, Bound::of);
        let n = self.evaluator.data.len();
        let ev = &mut self.evaluator;
        let hypothesis = match &mut ev.scorer {
            Scorer::Coverage(cov) => {
                // With a pool, a hypothesis must beat the pool's worst, and SPRT assumes that
                // one's support.
                let (bound, sprt) = match &self.pool {
                    Some(p) => {
                        let bound = p.bound();
                        (bound, self.pool_sprt.for_support(bound.support, n))
                    }
                    None => (best, self.termination.sprt),
                };
                let h = cov.cost(&ev.data, pose, bound, sprt, start)?;
                if let Some(p) = self.pool.as_mut() {
                    p.offer(&h, &cov.inliers, n);
                }
                if !(h.cost < best.cost) {
                    return None;
                }
                h
            }
            Scorer::Msac => msac_bounded(&ev.data, pose, best.cost, self.termination.sprt, start)?,
        };
        let optimized = match self.local_optimization && hypothesis.inliers >= 4 {
            true => ev.local_optimization(hypothesis),
            false => hypothesis,
        };
        // A local optimum that leaves the gate is not taken; the hypothesis inside it is.
        let hypothesis = match self.gate.as_ref().is_some_and(|g| !g.admits(&optimized.pose)) {
            true => hypothesis,
            false => optimized,
        };
        if let (Some(p), Some(cov)) = (self.pool.as_mut(), ev.scorer.coverage()) {
            // The local optimum joins the pool (its cluster keeps the better of the two).
            if let Some(h) = cov.cost(&ev.data, &hypothesis.pose, Bound::NONE, None, 0) {
                p.offer(&h, &cov.inliers, n);
            }
        }
        Some(hypothesis)
    }

    /// The pose to refine: the verifier's choice among the pool (verified whole unless its best
    /// was accepted early), else the best hypothesis.
    fn choice(&mut self) -> Option<MapToCamera> {
        let mut pose = self.best.map(|h| h.pose);
        if let (Some(pool), false) = (self.pool.as_mut(), self.termination.early_accepted()) {
            pool.verify_all(&mut self.evaluator);
            if let Some(chosen) = pool.choose() {
                pose = Some(chosen);
            }
        }
        pose
    }
}
