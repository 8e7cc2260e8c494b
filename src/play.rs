//! `angle-i2p play`: publishes a rosbag2 bag over DDS with its recorded timing, like
//! `ros2 bag play`. Each message's CDR bytes are decoded into the [`crate::msgs`] type of its
//! topic and published with that topic's QoS: the map (`PointCloud2`) latched (reliable,
//! transient local), camera images as sensor data (best effort), everything else reliable.

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use ros2_client::{Node, Publisher, QosProfile};

use crate::bag::{BagMessage, BagReader};
use crate::msgs::{self, from_cdr, RosMessage};
use crate::node::dds;
use crate::node::security::SecurityPlan;
use crate::params::{Names, RosArgs};

#[derive(clap::Args, Clone, Debug)]
pub struct PlayArgs {
    /// Bag: a rosbag2 directory or a bare .mcap file.
    pub bag: PathBuf,
    /// Speed factor on the recorded timing (2 = twice as fast).
    #[arg(long, default_value_t = 1.0)]
    pub rate: f64,
    /// Start over at the end, until interrupted.
    #[arg(long = "loop")]
    pub loop_: bool,
    /// Only these topics (repeatable; default: every topic with a known type).
    #[arg(long = "topic")]
    pub topics: Vec<String>,
    /// Remap a topic, `from:=to` (repeatable).
    #[arg(long = "remap", short = 'r')]
    pub remaps: Vec<String>,
    /// Before the first message, wait until this topic's publisher has a matched subscriber
    /// (repeatable; at most --wait-timeout seconds, then go on with a warning).
    #[arg(long = "wait-for")]
    pub wait_for: Vec<String>,
    #[arg(long, default_value_t = 10.0)]
    pub wait_timeout: f64,
    /// Keep the publishers this long after the last message (reliable repairs, latched map).
    #[arg(long, default_value_t = 1.0)]
    pub linger: f64,
    /// SROS2 enclave of the player (as `--ros-args -e`; `ROS_SECURITY_ENCLAVE_OVERRIDE` wins),
    /// used when `ROS_SECURITY_ENABLE=true` (docs/ros2.md).
    #[arg(long)]
    pub enclave: Option<String>,
}

/// What a play did.
#[derive(Clone, Debug, Default)]
pub struct PlayReport {
    pub published: usize,
    pub failed: usize,
    pub skipped_topics: Vec<String>,
    pub loops: usize,
    pub seconds: f64,
}

impl std::fmt::Display for PlayReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "play: {} messages published in {:.2} s", self.published, self.seconds)?;
        if self.loops > 1 {
            write!(f, " ({} loops)", self.loops)?;
        }
        if self.failed > 0 {
            write!(f, ", {} failed", self.failed)?;
        }
        if !self.skipped_topics.is_empty() {
            write!(f, "; skipped (unknown type): {}", self.skipped_topics.join(", "))?;
        }
        Ok(())
    }
}

/// A publisher of one topic that takes CDR bytes.
trait CdrPublisher {
    fn publish_cdr(&self, data: &[u8]) -> Result<(), String>;
    fn subscriptions(&self, node: &Node) -> usize;
}

impl<M: RosMessage + std::fmt::Debug> CdrPublisher for Publisher<M> {
    fn publish_cdr(&self, data: &[u8]) -> Result<(), String> {
        let msg: M = from_cdr(data).map_err(|e| e.to_string())?;
        self.publish(msg).map_err(|e| format!("{e:?}"))
    }

    fn subscriptions(&self, node: &Node) -> usize {
        self.get_subscription_count(node)
    }
}

/// QoS of a topic by its type.
pub fn qos_for(type_name: &str) -> QosProfile {
    match type_name {
        "sensor_msgs/msg/PointCloud2" => dds::latched(),
        "sensor_msgs/msg/Image" | "sensor_msgs/msg/CompressedImage" => dds::sensor_data(10),
        _ => dds::reliable(100),
    }
}

fn make_publisher(node: &mut Node, type_name: &str, topic: &str) -> Result<Option<Box<dyn CdrPublisher>>> {
    fn boxed<M: RosMessage + std::fmt::Debug + 'static>(
        node: &mut Node,
        topic: &str,
        qos: &QosProfile,
    ) -> Result<Option<Box<dyn CdrPublisher>>> {
        Ok(Some(Box::new(dds::publisher::<M>(node, topic, qos)?)))
    }
    let qos = qos_for(type_name);
    macro_rules! by_type {
        ($($ty:ty),* $(,)?) => {
            $(if type_name == <$ty as RosMessage>::TYPE_NAME {
                return boxed::<$ty>(node, topic, &qos);
            })*
        };
    }
    by_type!(
        msgs::CameraInfo,
        msgs::CompressedImage,
        msgs::Image,
        msgs::PointCloud2,
        msgs::Correspondences,
        msgs::PoseStamped,
        msgs::PoseWithCovarianceStamped,
        msgs::TFMessage,
        msgs::DiagnosticArray,
        msgs::Header,
    );
    Ok(None)
}

/// A bag topic's publisher and the (remapped) topic it publishes on.
struct TopicPublisher {
    out_topic: String,
    publisher: Box<dyn CdrPublisher>,
}

/// Publishes the bag; returns when done (or never with `--loop`, until interrupted).
pub fn play(args: &PlayArgs) -> Result<PlayReport> {
    if !(args.rate.is_finite() && args.rate > 0.0) {
        bail!("--rate must be a positive number, got {}", args.rate);
    }
    let reader = BagReader::open(&args.bag)?;
    let names = Names::new("angle_i2p_player", &RosArgs::from_cli(&[] as &[&str], &args.remaps)?);

    let security = SecurityPlan::for_process(args.enclave.as_deref(), "angle_i2p_player")?;
    let context = dds::context_for(&security)?;
    let mut node = dds::node(&context, "/", &format!("angle_i2p_player_{}", std::process::id()))?;
    let _spinner = dds::spawn_spinner(&mut node)?;

    let mut report = PlayReport::default();
    let publishers = publishers(&reader, args, &names, &mut node, &mut report)?;
    if publishers.is_empty() {
        bail!("{}: nothing to publish", args.bag.display());
    }
    wait_for_subscribers(args, &publishers, &node);
    let messages = reader.messages();
    let Some(first) = messages.first().map(|m| m.log_time) else {
        bail!("{}: the bag has no messages", args.bag.display());
    };
    let start = Instant::now();
    loop {
        report.loops += 1;
        publish_pass(messages, first, &publishers, args.rate, &mut report);
        if !args.loop_ {
            break;
        }
    }
    report.seconds = start.elapsed().as_secs_f64();
    std::thread::sleep(Duration::from_secs_f64(args.linger.max(0.0)));
    node.stop_spinner();
    Ok(report)
}

/// One publisher per bag topic (of `--topic` if given) whose type we can publish; the others
/// are listed in the report as skipped.
fn publishers(
    reader: &BagReader,
    args: &PlayArgs,
    names: &Names,
    node: &mut Node,
    report: &mut PlayReport,
) -> Result<HashMap<String, TopicPublisher>> {
    let mut publishers: HashMap<String, TopicPublisher> = HashMap::new();
    for ch in reader.channels() {
        if !args.topics.is_empty() && !args.topics.contains(&ch.topic) {
            continue;
        }
        if publishers.contains_key(&ch.topic) {
            continue;
        }
        let out_topic = names.resolve(&ch.topic);
        match make_publisher(node, &ch.type_name, &out_topic)? {
            Some(publisher) => {
                publishers.insert(ch.topic.clone(), TopicPublisher { out_topic, publisher });
            }
            None => report.skipped_topics.push(format!("{} ({})", ch.topic, ch.type_name)),
        }
    }
    Ok(publishers)
}

/// Waits (bounded by `--wait-timeout`) for a subscriber on each `--wait-for` topic.
fn wait_for_subscribers(args: &PlayArgs, publishers: &HashMap<String, TopicPublisher>, node: &Node) {
    let deadline = Instant::now() + Duration::from_secs_f64(args.wait_timeout.max(0.0));
    for topic in &args.wait_for {
        let found = publishers.iter().find(|(t, p)| *t == topic || p.out_topic == *topic).map(|(_, p)| p);
        let Some(p) = found else {
            eprintln!("[play] --wait-for {topic}: not a topic of this bag; not waiting");
            continue;
        };
        while p.publisher.subscriptions(node) == 0 {
            if Instant::now() >= deadline {
                eprintln!("[play] no subscriber on {topic} after {} s; playing anyway", args.wait_timeout);
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    if !args.wait_for.is_empty() {
        // Let the just-matched readers finish their handshake (reliable heartbeats).
        std::thread::sleep(Duration::from_millis(300));
    }
}

/// One pass over the bag's messages, each published at its log time (from `first`) / `rate`
/// after the pass started.
fn publish_pass(
    messages: &[BagMessage],
    first: u64,
    publishers: &HashMap<String, TopicPublisher>,
    rate: f64,
    report: &mut PlayReport,
) {
    let pass_start = Instant::now();
    for m in messages {
        let Some(p) = publishers.get(m.topic()) else {
            continue;
        };
        let offset = Duration::from_secs_f64(m.log_time.saturating_sub(first) as f64 / 1e9 / rate);
        let due = pass_start + offset;
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
        match p.publisher.publish_cdr(&m.data) {
            Ok(()) => report.published += 1,
            Err(e) => {
                report.failed += 1;
                eprintln!("[play] {} at log time {}: {e}", p.out_topic, m.log_time);
            }
        }
    }
}
