//! Publishers on the node's input topics whose QoS cannot match the node's readers.
//!
//! DDS silently refuses to connect a reader to a writer that offers less than the reader
//! requests (a reliable reader and a best-effort writer; a transient-local reader and a
//! volatile writer), so a misconfigured publisher would just look like silence. ros2-client
//! does not hand out the readers' `REQUESTED_INCOMPATIBLE_QOS` status (the participant's
//! status channel has a single consumer, its spinner), so the node checks the writers that
//! discovery has seen against what it requests, on every diagnostics tick; each offending
//! writer is reported once.

use std::collections::HashSet;

use ros2_client::dds::rustdds::discovery::DiscoveredWriterData;
use ros2_client::dds::rustdds::policy;

/// What the node's readers of one topic need from a writer (the most lenient of its readers,
/// when it has several).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct InputRequirement {
    /// The ROS topic name, e.g. `/cam0/camera/camera_info`.
    pub topic: String,
    pub needs_reliable: bool,
    pub needs_transient_local: bool,
}

/// What one remote writer offers (`None`: not announced, i.e. the DDS default).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OfferedQos {
    /// The DDS topic name, e.g. `rt/camera/camera_info`.
    pub dds_topic: String,
    pub writer: String,
    pub reliable: Option<bool>,
    pub transient_local: Option<bool>,
}

impl OfferedQos {
    pub fn from_discovery(w: &DiscoveredWriterData) -> Self {
        let t = &w.publication_topic_data;
        Self {
            dds_topic: t.topic_name.clone(),
            writer: format!("{:?}", t.key),
            reliable: t.reliability.map(|r| matches!(r, policy::Reliability::Reliable { .. })),
            transient_local: t.durability.map(|d| !matches!(d, policy::Durability::Volatile)),
        }
    }
}

/// One writer that cannot reach the node.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Incompatibility {
    pub topic: String,
    pub writer: String,
    /// `reliability` or `durability`.
    pub policy: &'static str,
    pub offered: &'static str,
    pub requested: &'static str,
}

impl std::fmt::Display for Incompatibility {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "a publisher on {} offers {} {} but the node requests {}: it will never deliver (writer {})",
            self.topic, self.policy, self.offered, self.requested, self.writer
        )
    }
}

/// The node's input topics and the writers already reported.
#[derive(Debug, Default)]
pub struct QosWatch {
    inputs: Vec<InputRequirement>,
    reported: HashSet<String>,
}

impl QosWatch {
    pub fn new(inputs: Vec<InputRequirement>) -> Self {
        Self { inputs, reported: HashSet::new() }
    }

    /// The writers among `offered` that no reader of the node can match, not reported before.
    pub fn check(&mut self, offered: &[OfferedQos]) -> Vec<Incompatibility> {
        let mut found = Vec::new();
        for w in offered {
            let Some(input) = self.inputs.iter().find(|i| dds_topic(&i.topic) == w.dds_topic) else { continue };
            // DDS defaults when not announced: writers reliable, volatile.
            let problem = if input.needs_reliable && w.reliable == Some(false) {
                Some(("reliability", "best_effort", "reliable"))
            } else if input.needs_transient_local && !w.transient_local.unwrap_or(false) {
                Some(("durability", "volatile", "transient_local"))
            } else {
                None
            };
            let Some((policy, offered, requested)) = problem else { continue };
            if self.reported.insert(format!("{}|{}", w.dds_topic, w.writer)) {
                found.push(Incompatibility {
                    topic: input.topic.clone(),
                    writer: w.writer.clone(),
                    policy,
                    offered,
                    requested,
                });
            }
        }
        found
    }
}

/// The DDS topic of a ROS topic (`/a/b` → `rt/a/b`).
fn dds_topic(ros_topic: &str) -> String {
    format!("rt/{}", ros_topic.trim_start_matches('/'))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn writer(topic: &str, id: &str, reliable: Option<bool>, transient_local: Option<bool>) -> OfferedQos {
        OfferedQos { dds_topic: topic.into(), writer: id.into(), reliable, transient_local }
    }

    #[test]
    fn reports_each_incompatible_writer_once() {
        let mut w = QosWatch::new(vec![
            InputRequirement { topic: "/tf".into(), needs_reliable: true, needs_transient_local: false },
            InputRequirement { topic: "/map/points".into(), needs_reliable: true, needs_transient_local: true },
            InputRequirement {
                topic: "/matcher/correspondences".into(),
                needs_reliable: false,
                needs_transient_local: false,
            },
        ]);
        let offered = vec![
            writer("rt/tf", "a", Some(false), None),
            writer("rt/tf", "b", Some(true), None),
            writer("rt/map/points", "c", None, Some(false)),
            writer("rt/map/points", "d", Some(true), Some(true)),
            writer("rt/matcher/correspondences", "e", Some(false), Some(false)),
            writer("rt/other", "f", Some(false), None),
        ];
        let found = w.check(&offered);
        assert_eq!(found.len(), 2, "{found:?}");
        assert_eq!((found[0].writer.as_str(), found[0].policy), ("a", "reliability"));
        assert_eq!((found[1].writer.as_str(), found[1].policy), ("c", "durability"));
        assert!(found[1].to_string().contains("/map/points"));
        assert!(w.check(&offered).is_empty(), "reported again");
    }
}
