//! The model constants: the `network.*` parameters a model was trained with. The training inputs
//! were built with them (`angle-i2p export`: K, M, the graphs' θ and σ_d, the prior alignment,
//! the keypoint pass and its ranking) or the model was calibrated with them (the confidence it
//! reads for a matcher without one), so a model works with its own values only, and changing one
//! in a params file used to break the network silently. The model carries them in its ONNX
//! metadata (`angle_i2p.<key>`, stamped by `training/train.py` or `training/stamp_metadata.py`);
//! at load its values are the ones used, and a params file that sets one to another value is
//! refused. A model without them (older ones) runs with the params' values, as before.

use std::collections::BTreeMap;
use std::path::Path;

use super::network_params::{ModelConstant, NetworkParams};

/// Prefix of the model's metadata keys.
pub const METADATA_PREFIX: &str = "angle_i2p.";
/// The metadata key of the format version.
pub const FORMAT_KEY: &str = "angle_i2p.format";
/// The format version this build writes and reads: the keys of [`ModelConstant::ALL`], each
/// value as a params file writes it.
pub const FORMAT_VERSION: u32 = 1;
/// What `angle-i2p export` writes beside the samples: the metadata a model trained on them
/// carries (`training/train.py` stamps it).
pub const EXPORT_FILE: &str = "model_constants.json";

/// Why a model's metadata cannot be used with the parameters (the caller adds the model's path).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ConstantsError {
    /// The params set a constant the model was trained with another value of.
    #[error(
        "network.{key} is {params} in the parameters, but the model was trained with {model} (its metadata \
         `angle_i2p.{key}`): leave network.{key} unset to use the model's value, or use a model trained with {params}"
    )]
    Mismatch { key: &'static str, params: String, model: String },
    /// A metadata value that is no value of its parameter, or outside its range.
    #[error("metadata `angle_i2p.{key}` = {value:?} is no valid network.{key}: {message}")]
    Unreadable { key: String, value: String, message: String },
    /// An `angle_i2p.*` key this build does not know (a newer exporter, or a typo).
    #[error("unknown metadata `{key}`: this build knows angle_i2p.format and {}", known_keys())]
    Unknown { key: String },
    /// Constants without a format version (`missing`), or of another one.
    #[error("metadata `{FORMAT_KEY}` is {found}: this build reads format {FORMAT_VERSION}")]
    Format { found: String },
    /// A fixed input dimension of the graph that disagrees with a constant.
    #[error("input `{input}` has dimension {dim} at axis {axis}, but network.{key} is {value}")]
    Graph { input: String, axis: usize, dim: i64, key: &'static str, value: usize },
}

fn known_keys() -> String {
    ModelConstant::ALL.iter().map(|c| format!("{METADATA_PREFIX}{}", c.name())).collect::<Vec<_>>().join(", ")
}

/// The metadata a model trained with `params` carries: the format and every constant.
pub fn metadata_of(params: &NetworkParams) -> BTreeMap<String, String> {
    let constants = ModelConstant::ALL.iter().map(|c| (format!("{METADATA_PREFIX}{}", c.name()), c.text(params)));
    std::iter::once((FORMAT_KEY.to_string(), FORMAT_VERSION.to_string())).chain(constants).collect()
}

/// Writes [`metadata_of`] `params` as `dir`/[`EXPORT_FILE`] (what `export` leaves for training).
pub fn write_export_file(dir: &Path, params: &NetworkParams) -> std::io::Result<()> {
    let json = serde_json::to_string_pretty(&metadata_of(params)).map_err(std::io::Error::other)?;
    std::fs::write(dir.join(EXPORT_FILE), json + "\n")
}

/// The model's constants, read from its `angle_i2p.*` metadata (`metadata` may hold other keys
/// too; they are ignored). Empty when the model carries none.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModelConstants {
    values: BTreeMap<ModelConstant, String>,
}

impl ModelConstants {
    /// Reads the constants from a model's metadata; an unknown `angle_i2p.*` key, a missing or
    /// other format, or a value that is no value of its parameter is an error.
    pub fn read(metadata: &BTreeMap<String, String>) -> Result<Self, ConstantsError> {
        let mut values = BTreeMap::new();
        let mut format = None;
        for (key, value) in metadata {
            let Some(name) = key.strip_prefix(METADATA_PREFIX) else { continue };
            if key == FORMAT_KEY {
                format = Some(value.clone());
                continue;
            }
            let constant =
                ModelConstant::from_name(name).ok_or_else(|| ConstantsError::Unknown { key: key.clone() })?;
            values.insert(constant, value.clone());
        }
        let stamped = Self { values };
        if format.is_none() && stamped.is_empty() {
            return Ok(stamped);
        }
        if format.as_deref().map(str::trim) != Some(FORMAT_VERSION.to_string().as_str()) {
            return Err(ConstantsError::Format { found: format.unwrap_or_else(|| "missing".into()) });
        }
        stamped.check_values()?;
        Ok(stamped)
    }

    /// Each value reads as its parameter's type and lies in its range.
    fn check_values(&self) -> Result<(), ConstantsError> {
        for (&constant, text) in &self.values {
            let mut params = NetworkParams::default();
            let checked = constant.set(&mut params, text).map_err(|e| e.to_string());
            checked.and_then(|()| params.validate().map_err(|e| e.to_string())).map_err(|message| {
                ConstantsError::Unreadable { key: constant.name().to_string(), value: text.clone(), message }
            })?;
        }
        Ok(())
    }

    /// The constants as the model's metadata holds them (with the format; empty for none).
    pub fn metadata(&self) -> BTreeMap<String, String> {
        if self.is_empty() {
            return BTreeMap::new();
        }
        let values = self.values.iter().map(|(c, v)| (format!("{METADATA_PREFIX}{}", c.name()), v.clone()));
        std::iter::once((FORMAT_KEY.to_string(), FORMAT_VERSION.to_string())).chain(values).collect()
    }

    /// Whether the model carries no constant (a model from before the metadata).
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// The constants the model does not carry (their params values are used).
    pub fn missing(&self) -> Vec<ModelConstant> {
        ModelConstant::ALL.into_iter().filter(|c| !self.values.contains_key(c)).collect()
    }

    /// `params` with the model's constants in place of its own; an error where the params gave a
    /// constant ([`NetworkParams::given`]) with another value than the model's.
    pub fn resolve(&self, params: &NetworkParams) -> Result<NetworkParams, ConstantsError> {
        let model = self.applied_to(params)?;
        for &constant in self.values.keys().filter(|c| params.given.contains(c)) {
            let (ours, theirs) = (constant.text(params), constant.text(&model));
            if ours != theirs {
                return Err(ConstantsError::Mismatch { key: constant.name(), params: ours, model: theirs });
            }
        }
        Ok(model)
    }

    /// `params` with every constant of the model written over it.
    fn applied_to(&self, params: &NetworkParams) -> Result<NetworkParams, ConstantsError> {
        let mut out = params.clone();
        for (&constant, text) in &self.values {
            constant.set(&mut out, text).map_err(|e| ConstantsError::Unreadable {
                key: constant.name().to_string(),
                value: text.clone(),
                message: e.to_string(),
            })?;
        }
        Ok(out)
    }
}

/// Checks the model's fixed input dimensions against K and M (`inputs`: each input's name and
/// shape, -1 for a dynamic axis; the shipped models' are all dynamic, so this guards a model
/// exported with fixed graph sizes).
pub fn check_graph(inputs: &[(String, Vec<i64>)], params: &NetworkParams) -> Result<(), ConstantsError> {
    let (k, m) = (params.graph.neighbours, params.graph.keypoints);
    let expected: &[(&str, usize, &'static str, usize)] = &[
        ("local_index", 1, "neighbours", k),
        ("local_theta", 1, "neighbours", k),
        ("local_theta", 2, "neighbours", k),
        ("global_index", 0, "keypoints", m),
        ("global_theta", 0, "keypoints", m),
        ("global_theta", 1, "keypoints", m),
        ("cross_theta", 1, "keypoints", m),
    ];
    for (name, shape) in inputs {
        for &(input, axis, key, value) in expected.iter().filter(|e| e.0 == name) {
            let Some(&dim) = shape.get(axis) else { continue };
            if dim >= 0 && dim as usize != value {
                return Err(ConstantsError::Graph { input: input.to_string(), axis, dim, key, value });
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::consistency::PairMetric;
    use crate::reject::network_params::KeypointRanking;

    fn stamped(pairs: &[(&str, &str)]) -> BTreeMap<String, String> {
        pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect()
    }

    fn given(constants: &[ModelConstant]) -> NetworkParams {
        NetworkParams { given: constants.iter().copied().collect(), ..NetworkParams::default() }
    }

    /// The metadata of the defaults reads back as the defaults, key by key as a params file
    /// writes them.
    #[test]
    fn the_defaults_metadata_reads_back_as_the_defaults() {
        let metadata = metadata_of(&NetworkParams::default());
        assert_eq!(metadata["angle_i2p.format"], "1");
        assert_eq!(metadata["angle_i2p.neighbours"], "32");
        assert_eq!(metadata["angle_i2p.theta"], "angle");
        assert_eq!(metadata["angle_i2p.sigma_d"], "0.2");
        assert_eq!(metadata["angle_i2p.align_prior"], "true");
        assert_eq!(metadata["angle_i2p.keypoint_ranking"], "spectral_matcher");
        assert_eq!(metadata["angle_i2p.missing_confidence"], "0.25");
        let constants = ModelConstants::read(&metadata).unwrap();
        assert!(constants.missing().is_empty());
        assert_eq!(constants.resolve(&given(&ModelConstant::ALL)).unwrap().graph, NetworkParams::default().graph);
    }

    /// Not given: the model's value is used; given equal: fine; given otherwise: refused,
    /// naming the key, the params value and the model's.
    #[test]
    fn the_models_values_win_and_a_contradiction_is_refused() {
        let model = ModelConstants::read(&stamped(&[
            ("angle_i2p.format", "1"),
            ("angle_i2p.theta", "distance"),
            ("angle_i2p.neighbours", "16"),
            ("angle_i2p.keypoint_ranking", "spectral_matcher_rank"),
            ("producer", "anything else is ignored"),
        ]))
        .unwrap();
        let used = model.resolve(&NetworkParams::default()).unwrap();
        assert_eq!((used.graph.theta, used.graph.neighbours), (PairMetric::Distance, 16));
        assert_eq!(used.keypoint_ranking, KeypointRanking::SpectralMatcherRank);
        assert_eq!(used.graph.keypoints, 100, "a constant the model lacks keeps the params value");
        let mut same = given(&[ModelConstant::Neighbours]);
        same.graph.neighbours = 16;
        assert_eq!(model.resolve(&same).unwrap().graph.neighbours, 16);
        let err = model.resolve(&given(&[ModelConstant::Neighbours])).unwrap_err();
        assert_eq!(err, ConstantsError::Mismatch { key: "neighbours", params: "32".into(), model: "16".into() });
        let text = err.to_string();
        assert!(text.contains("network.neighbours is 32") && text.contains("trained with 16"), "{text}");
    }

    #[test]
    fn a_model_without_constants_keeps_the_params() {
        let none = ModelConstants::read(&stamped(&[("producer", "pytorch")])).unwrap();
        assert!(none.is_empty());
        let mut params = given(&[ModelConstant::Keypoints]);
        params.graph.keypoints = 7;
        assert_eq!(none.resolve(&params).unwrap(), params);
    }

    #[test]
    fn bad_metadata_is_an_error_naming_the_key() {
        let read = |pairs: &[(&str, &str)]| ModelConstants::read(&stamped(pairs)).unwrap_err().to_string();
        let e = read(&[("angle_i2p.format", "1"), ("angle_i2p.theta", "cosine")]);
        assert!(e.contains("angle_i2p.theta") && e.contains("cosine"), "{e}");
        let e = read(&[("angle_i2p.format", "1"), ("angle_i2p.neighbours", "0")]);
        assert!(e.contains("angle_i2p.neighbours") && e.contains("at least 1"), "{e}");
        let e = read(&[("angle_i2p.format", "1"), ("angle_i2p.neighbors", "8")]);
        assert!(e.contains("unknown metadata `angle_i2p.neighbors`"), "{e}");
        let e = read(&[("angle_i2p.neighbours", "8")]);
        assert!(e.contains("`angle_i2p.format` is missing"), "{e}");
        let e = read(&[("angle_i2p.format", "2"), ("angle_i2p.neighbours", "8")]);
        assert!(e.contains("`angle_i2p.format` is 2: this build reads format 1"), "{e}");
    }

    #[test]
    fn given_constants_are_the_network_keys_a_layer_names() {
        let tree: serde_yaml::Value = serde_yaml::from_str("{tau: 0.3, theta: angle, keypoints: 5}").unwrap();
        let found = ModelConstant::given_in(Some(&tree));
        assert_eq!(found, [ModelConstant::Keypoints, ModelConstant::Theta].into_iter().collect());
        assert!(ModelConstant::given_in(None).is_empty());
    }

    #[test]
    fn fixed_input_dimensions_must_match_k_and_m() {
        let params = NetworkParams::default();
        let dynamic = vec![("local_index".to_string(), vec![-1, -1]), ("global_theta".to_string(), vec![-1, -1])];
        assert_eq!(check_graph(&dynamic, &params), Ok(()));
        let fixed = vec![("local_index".to_string(), vec![-1, 32]), ("cross_theta".to_string(), vec![-1, 64])];
        let e = check_graph(&fixed, &params).unwrap_err();
        assert_eq!(
            e,
            ConstantsError::Graph { input: "cross_theta".into(), axis: 1, dim: 64, key: "keypoints", value: 100 }
        );
    }
}
