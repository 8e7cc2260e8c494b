//! The DDS edge shared by the node, the player and the tests: a ROS 2 context on
//! `ROS_DOMAIN_ID`, DDS type names of our messages, topic names, and the QoS profiles.
//!
//! ros2-client maps a ROS topic `/a/b` to the DDS topic `rt/a/b` and a type
//! `pkg/msg/Type` ([`MessageTypeName`]) to `pkg::msg::dds_::Type_`; messages are serialized
//! by serde into little-endian CDR, so the [`crate::msgs`] structs travel as they are.

use std::time::Duration;

use anyhow::{anyhow, Context as _, Result};
use ros2_client::dds::rustdds::{DomainParticipantBuilder, DomainParticipantSecurityConfigFiles};
use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::{Context, MessageTypeName, Name, Node, NodeName, NodeOptions, QosProfile};

use super::security::SecurityPlan;
use crate::msgs::RosMessage;

/// The DDS domain from `ROS_DOMAIN_ID` (0 when unset; an invalid value is an error).
pub fn domain_id_from_env() -> Result<u16> {
    match std::env::var("ROS_DOMAIN_ID") {
        Err(_) => Ok(0),
        Ok(s) if s.trim().is_empty() => Ok(0),
        Ok(s) => {
            let id: u16 = s.trim().parse().map_err(|_| anyhow!("ROS_DOMAIN_ID={s:?} is not a domain id (0–232)"))?;
            anyhow::ensure!(id <= 232, "ROS_DOMAIN_ID={id} is out of range (0–232)");
            Ok(id)
        }
    }
}

/// An unsecured ROS 2 context on `ROS_DOMAIN_ID`.
pub fn context() -> Result<Context> {
    context_for(&SecurityPlan::Off { enclave: None })
}

/// Requested kernel receive buffer (`SO_RCVBUF`) of every DDS socket, bytes: a large sample
/// (a map of millions of points) arrives as one burst of fragments, and what the buffer cannot
/// hold is repaired slowly by RustDDS (a few fragments per round). The kernel clamps the
/// request to `net.core.rmem_max` (docs/ros2.md, *Large maps*).
pub const RECEIVE_BUFFER_BYTES: usize = 64 << 20;

/// What to tell the user at start when the kernel caps the receive buffer below
/// [`RECEIVE_BUFFER_BYTES`] (Linux's `net.core.rmem_max`); `None` when it does not, or cannot
/// be read.
pub fn receive_buffer_note() -> Option<String> {
    let text = std::fs::read_to_string("/proc/sys/net/core/rmem_max").ok()?;
    let max: usize = text.trim().parse().ok()?;
    (max < RECEIVE_BUFFER_BYTES).then(|| {
        format!(
            "net.core.rmem_max is {} KiB: a map of over ~1 M points from a RustDDS publisher (angle-i2p play) may \
             arrive late or not at all; raise it to {} MiB (sysctl -w net.core.rmem_max={RECEIVE_BUFFER_BYTES}), \
             as the ROS 2 DDS tuning guide advises for large messages",
            max >> 10,
            RECEIVE_BUFFER_BYTES >> 20
        )
    })
}

/// A ROS 2 context on `ROS_DOMAIN_ID`, secured as `plan` says (SROS2: the enclave's identity,
/// permissions and governance; unencrypted keys, as SROS2 writes them).
pub fn context_for(plan: &SecurityPlan) -> Result<Context> {
    let domain = domain_id_from_env()?;
    let mut builder = DomainParticipantBuilder::new(domain).socket_receive_buffer_size(RECEIVE_BUFFER_BYTES);
    if let SecurityPlan::Secured { dir, .. } = plan {
        builder =
            builder.builtin_security(DomainParticipantSecurityConfigFiles::with_ros_default_names(dir, String::new()));
    }
    let participant = builder.build().map_err(|e| match plan {
        SecurityPlan::Secured { enclave, dir } => {
            anyhow!("cannot create the secured DDS participant (enclave {enclave:?}, {}): {e:?}", dir.display())
        }
        _ => anyhow!("cannot create the DDS participant on domain {domain}: {e:?}"),
    })?;
    Context::from_domain_participant(participant).map_err(|e| anyhow!("cannot create the ROS 2 context: {e:?}"))
}

/// A node `namespace/name` without parameter services or rosout (nothing to serve).
pub fn node(context: &Context, namespace: &str, name: &str) -> Result<Node> {
    let node_name = NodeName::new(namespace, name).map_err(|e| anyhow!("bad node name {namespace}/{name}: {e:?}"))?;
    context
        .new_node(node_name, NodeOptions::new().enable_rosout(false).start_parameter_services(false))
        .map_err(|e| anyhow!("cannot create node {namespace}/{name}: {e:?}"))
}

/// A node `namespace/name` with `options` (parameter services, rosout).
pub fn node_with_options(context: &Context, namespace: &str, name: &str, options: NodeOptions) -> Result<Node> {
    let node_name = NodeName::new(namespace, name).map_err(|e| anyhow!("bad node name {namespace}/{name}: {e:?}"))?;
    context.new_node(node_name, options).map_err(|e| anyhow!("cannot create node {namespace}/{name}: {e:?}"))
}

/// `pkg/msg/Type` → ros2-client's [`MessageTypeName`] (DDS `pkg::msg::dds_::Type_`).
pub fn type_name<M: RosMessage>() -> MessageTypeName {
    let full = M::TYPE_NAME;
    let mut parts = full.split('/');
    let pkg = parts.next().unwrap_or(full);
    let ty = parts.next_back().unwrap_or(full);
    MessageTypeName::new(pkg, ty)
}

/// An absolute ROS topic name as ros2-client wants it.
pub fn topic_name(topic: &str) -> Result<Name> {
    Name::parse(topic).map_err(|e| anyhow!("bad topic name {topic:?}: {e:?}"))
}

/// Creates a topic, a publisher and returns it.
pub fn publisher<M: RosMessage>(node: &mut Node, topic: &str, qos: &QosProfile) -> Result<ros2_client::Publisher<M>> {
    let t = node
        .create_topic(&topic_name(topic)?, type_name::<M>(), qos)
        .map_err(|e| anyhow!("{e:?}"))
        .with_context(|| format!("creating topic {topic}"))?;
    node.create_publisher::<M>(&t, Some(qos.clone()))
        .map_err(|e| anyhow!("{e:?}"))
        .with_context(|| format!("creating publisher on {topic}"))
}

/// Creates a topic, a subscription and returns it.
pub fn subscription<M: RosMessage + 'static>(
    node: &mut Node,
    topic: &str,
    qos: &QosProfile,
) -> Result<ros2_client::Subscription<M>> {
    let t = node
        .create_topic(&topic_name(topic)?, type_name::<M>(), qos)
        .map_err(|e| anyhow!("{e:?}"))
        .with_context(|| format!("creating topic {topic}"))?;
    node.create_subscription::<M>(&t, Some(qos.clone()))
        .map_err(|e| anyhow!("{e:?}"))
        .with_context(|| format!("creating subscription on {topic}"))
}

/// Sensor data (`rmw_qos_profile_sensor_data`): best effort, volatile, keep last 5. Used by
/// subscriptions to camera info, images and the depth prior (they also accept reliable
/// publishers); `depth` is raised for bursts.
pub fn sensor_data(depth: usize) -> QosProfile {
    QosProfile::subscription_default()
        .reliability(Reliability::BestEffort)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth })
}

/// ROS default: reliable, volatile, keep last `depth`.
pub fn reliable(depth: usize) -> QosProfile {
    QosProfile::subscription_default()
        .reliability(Reliability::Reliable { when_full: WhenFull::Wait(Duration::from_millis(200)) })
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth })
}

/// Latched (map): reliable, transient local, keep last 1: late joiners get the last map.
pub fn latched() -> QosProfile {
    QosProfile::subscription_default()
        .reliability(Reliability::Reliable { when_full: WhenFull::Wait(Duration::from_millis(500)) })
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 })
}

/// Runs the node's spinner (discovery bookkeeping) on its own thread.
pub fn spawn_spinner(node: &mut Node) -> Result<std::thread::JoinHandle<()>> {
    let spinner = node.spinner().map_err(|e| anyhow!("cannot start the spinner: {e:?}"))?;
    std::thread::Builder::new()
        .name("ros2-spinner".into())
        .spawn(move || {
            if let Err(e) = futures::executor::block_on(spinner.spin()) {
                eprintln!("[angle_i2p] spinner stopped: {e:?}");
            }
        })
        .context("spawning the spinner thread")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs;

    #[test]
    fn dds_type_names() {
        assert_eq!(type_name::<msgs::PoseStamped>().dds_msg_type(), "geometry_msgs::msg::dds_::PoseStamped_");
        assert_eq!(type_name::<msgs::Correspondences>().dds_msg_type(), "angle_i2p_msgs::msg::dds_::Correspondences_");
        assert_eq!(type_name::<msgs::TFMessage>().dds_msg_type(), "tf2_msgs::msg::dds_::TFMessage_");
    }
}
