//! The learned rejector (paper section 3.3) run with ONNX Runtime through `ort`: inputs are
//! built in Rust ([`super::inputs`]), the network scores each correspondence, and those with
//! score ≥ τ are kept.
//!
//! ONNX Runtime is loaded at start-up from `NetworkParams::onnxruntime_path`, else
//! `ORT_DYLIB_PATH`, else `.ort/libonnxruntime.so.1.31.1` (`make ort` puts it there).

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use super::inputs::{build_inputs, build_inputs_into, IndexedMap, InputScratch, NetworkInputs, TensorValues};
use super::model_constants::{check_graph, ConstantsError, ModelConstants, METADATA_PREFIX};
pub use super::network_params::{KeypointRanking, NetworkParams};
use super::{top_k, FrameGeometry, RejectError, Rejection, Rejector, SpectralParams, SpectralRejector};
use ort::session::builder::GraphOptimizationLevel;
use ort::session::{Session, SessionInputValue};
use ort::value::{Tensor, TensorRef};

/// The library file this build expects (the `api-31` feature).
pub const ONNXRUNTIME_LIBRARY: &str = "libonnxruntime.so.1.31.1";

#[derive(Debug, Clone, thiserror::Error)]
pub enum NetworkError {
    #[error(
        "ONNX Runtime not found at {0}: run `make ort` (it extracts {ONNXRUNTIME_LIBRARY} from the PyPI wheel \
         onnxruntime==1.31.1 into .ort/), or set ORT_DYLIB_PATH or network.onnxruntime_path; the other methods work without it"
    )]
    MissingRuntime(String),
    #[error("ONNX Runtime at {path}: {message}")]
    Runtime { path: String, message: String },
    #[error("model {path}: {message}")]
    Model { path: String, message: String },
    /// The model's constants (its ONNX metadata) against the parameters and its graph.
    #[error("model {path}: {source}")]
    Constants {
        path: String,
        #[source]
        source: ConstantsError,
    },
}

/// The process-wide ONNX Runtime environment (ort allows one per process).
fn environment(params: &NetworkParams) -> Result<ort::environment::Environment, NetworkError> {
    static ENV: OnceLock<Result<ort::environment::Environment, NetworkError>> = OnceLock::new();
    ENV.get_or_init(|| {
        let path = runtime_path(params);
        if !path.exists() {
            return Err(NetworkError::MissingRuntime(path.display().to_string()));
        }
        let err = |e: String| NetworkError::Runtime { path: path.display().to_string(), message: e };
        ort::init_from(&path).map_err(|e| err(e.to_string()))?.build().map_err(|e| err(e.to_string()))
    })
    .clone()
}

pub fn runtime_path(params: &NetworkParams) -> PathBuf {
    if !params.onnxruntime_path.is_empty() {
        return locate(Path::new(&params.onnxruntime_path));
    }
    if let Some(p) = std::env::var_os("ORT_DYLIB_PATH") {
        return PathBuf::from(p);
    }
    locate(&Path::new(".ort").join(ONNXRUNTIME_LIBRARY))
}

/// A relative path as given when it exists from the working directory, else under the source
/// tree this binary was built from: a node started from any directory (`ros2 launch`) finds the
/// shipped model and `make ort`'s runtime.
pub fn locate(path: &Path) -> PathBuf {
    if path.is_absolute() || path.exists() {
        return path.to_path_buf();
    }
    let in_tree = Path::new(env!("CARGO_MANIFEST_DIR")).join(path);
    if in_tree.exists() {
        in_tree
    } else {
        path.to_path_buf()
    }
}

/// Scores correspondences with the trained network.
pub struct NetworkRejector {
    params: NetworkParams,
    session: Session,
    spectral: SpectralRejector,
    map: Option<Arc<IndexedMap>>,
    /// The last frame's inputs and what building them works in: refilled every frame, so
    /// their buffers are allocated once.
    inputs: NetworkInputs,
    scratch: InputScratch,
    /// The model takes the matcher's confidence as within-frame ranks (`matcher_rank`).
    ranks_confidence: bool,
    /// What the model's metadata says it was trained with.
    constants: ModelConstants,
}

impl NetworkRejector {
    pub fn new(params: NetworkParams, spectral: SpectralParams) -> Result<Self, NetworkError> {
        let env = environment(&params)?;
        let model_path = locate(Path::new(&params.model_path));
        let model_err = |e: String| NetworkError::Model { path: model_path.display().to_string(), message: e };
        if !model_path.exists() {
            return Err(model_err("no such file".into()));
        }
        let session = Session::builder(&env)
            .and_then(|b| b.with_intra_threads(params.intra_threads.max(1)).map_err(Into::into))
            .and_then(|b| b.with_intra_op_spinning(false).map_err(Into::into))
            // Basic graph rewrites only (constant folding, redundant nodes): the extended
            // fusions (SkipLayerNormalization, fused MatMul/Gemm) made this small model ~10 %
            // slower per run (1.86 → 1.64 ms median on redkitchen-extreme-val-harsh, measured
            // interleaved), as its tensors are too small for the fused kernels to pay.
            .and_then(|b| b.with_optimization_level(GraphOptimizationLevel::Level1).map_err(Into::into))
            .and_then(|mut b| b.commit_from_file(&model_path))
            .map_err(|e| model_err(e.to_string()))?;
        let (params, constants) = model_params(&session, params, &model_path)?;
        let spectral = SpectralRejector::new(params.keypoint_spectral(spectral));
        let ranks_confidence = session.inputs().iter().any(|i| i.name() == "matcher_rank");
        Ok(Self {
            params,
            session,
            spectral,
            map: None,
            inputs: NetworkInputs::default(),
            scratch: InputScratch::default(),
            ranks_confidence,
            constants,
        })
    }

    /// The parameters it runs with: the model's constants over the ones it was given.
    pub fn params(&self) -> &NetworkParams {
        &self.params
    }

    /// The model constants its metadata carries (none for an older model).
    pub fn model_constants(&self) -> &ModelConstants {
        &self.constants
    }

    /// The network's inputs for one frame (eq. 9 features, graphs, θ).
    pub fn inputs(&mut self, geometry: &FrameGeometry) -> NetworkInputs {
        let mut inputs = build_inputs(geometry, self.map.as_deref(), &mut self.spectral, &self.params);
        if self.ranks_confidence {
            inputs.rank_matcher_scores();
        }
        inputs
    }

    /// The network's scores for prepared inputs.
    pub fn run(&mut self, inputs: &NetworkInputs) -> Result<Vec<f32>, RejectError> {
        score(&mut self.session, inputs)
    }
}

/// The parameters the model at `path` runs with: its constants (ONNX metadata, see
/// [`super::model_constants`]) in place of `params`'s, refused where the params gave another
/// value or the graph's fixed input dimensions disagree. A model without them keeps `params`'s
/// values, said in one line.
fn model_params(
    session: &Session,
    params: NetworkParams,
    path: &Path,
) -> Result<(NetworkParams, ModelConstants), NetworkError> {
    let shown = path.display().to_string();
    let err = |source: ConstantsError| NetworkError::Constants { path: shown.clone(), source };
    let metadata = stamped_metadata(session)
        .map_err(|e| NetworkError::Model { path: shown.clone(), message: format!("reading its metadata: {e}") })?;
    let constants = ModelConstants::read(&metadata).map_err(err)?;
    let missing = constants.missing();
    if !missing.is_empty() {
        let values: Vec<String> =
            missing.iter().map(|c| format!("network.{} ({})", c.name(), c.text(&params))).collect();
        let what = if constants.is_empty() { "its model constants (an older model)" } else { "every model constant" };
        eprintln!("note: model {shown} does not carry {what}: using the parameters' {}", values.join(", "));
    }
    let resolved = constants.resolve(&params).map_err(err)?;
    check_graph(&input_shapes(session), &resolved).map_err(err)?;
    Ok((resolved, constants))
}

/// The model's `angle_i2p.*` metadata entries.
fn stamped_metadata(session: &Session) -> Result<BTreeMap<String, String>, ort::Error> {
    let metadata = session.metadata()?;
    let keys = metadata.custom_keys()?.into_iter().filter(|k| k.starts_with(METADATA_PREFIX));
    Ok(keys.filter_map(|k| metadata.custom(&k).map(|v| (k, v))).collect())
}

/// Each tensor input's name and shape (-1: a dynamic axis).
fn input_shapes(session: &Session) -> Vec<(String, Vec<i64>)> {
    let shape = |i: &ort::value::Outlet| Some((i.name().to_string(), i.dtype().tensor_shape()?.to_vec()));
    session.inputs().iter().filter_map(shape).collect()
}

/// Runs `session` on `inputs`: each tensor a view of the inputs' own buffers (no copy).
fn score(session: &mut Session, inputs: &NetworkInputs) -> Result<Vec<f32>, RejectError> {
    let n = inputs.features.len();
    let fail = |e: ort::Error| RejectError::Failed(format!("network: {e}"));
    let mut values: Vec<(Cow<'static, str>, SessionInputValue<'_>)> = Vec::new();
    for t in inputs.tensors() {
        // Each model takes the inputs it declares: one without global attention (the ablation)
        // has no global ones, one trained without the matcher's confidence has no `matcher_score`
        // (and one trained on its ranks has `matcher_rank` instead).
        if !session.inputs().iter().any(|i| i.name() == t.name) {
            continue;
        }
        let value: SessionInputValue<'_> = match t.values {
            TensorValues::F32(Cow::Borrowed(v)) => TensorRef::from_array_view((t.shape, v)).map_err(fail)?.into(),
            TensorValues::F32(Cow::Owned(v)) => Tensor::from_array((t.shape, v)).map_err(fail)?.into(),
            TensorValues::I64(v) => Tensor::from_array((t.shape, v)).map_err(fail)?.into(),
        };
        values.push((Cow::Borrowed(t.name), value));
    }
    let outputs = session.run(values).map_err(fail)?;
    let (_, scores) = outputs["score"].try_extract_tensor::<f32>().map_err(fail)?;
    if scores.len() != n {
        return Err(RejectError::Failed(format!("network returned {} scores for {n} correspondences", scores.len())));
    }
    Ok(scores.to_vec())
}

impl Rejector for NetworkRejector {
    fn name(&self) -> &'static str {
        "angle_i2p"
    }

    fn set_map_index(&mut self, index: &Arc<IndexedMap>) {
        self.map = Some(Arc::clone(index));
    }

    fn reject(&mut self, geometry: &FrameGeometry) -> Result<Rejection, RejectError> {
        if !geometry.has_prior() {
            return Err(RejectError::MissingDepthPrior("angle_i2p"));
        }
        let map = self.map.as_deref();
        build_inputs_into(&mut self.inputs, geometry, map, &mut self.spectral, &self.params, &mut self.scratch);
        if self.ranks_confidence {
            self.inputs.rank_matcher_scores();
        }
        let scores = score(&mut self.session, &self.inputs)?;
        let mut kept: Vec<usize> = top_k(&scores, scores.len());
        let above = kept.iter().take_while(|&&i| f64::from(scores[i]) >= self.params.tau).count();
        kept.truncate(above.max(self.params.min_keep).min(scores.len()));
        Ok(Rejection { scores, kept })
    }
}
