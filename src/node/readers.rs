//! The node's subscriptions: one reader thread per topic that decodes each message and
//! converts it with the conversions bag replay uses ([`convert`]'s `*_part`), then hands it
//! to the ingest task; image-source arbitration; the map, TF and `/initialpose` readers and
//! the node's services.

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use anyhow::{Context as _, Result};
use futures::future::Either;
use futures::StreamExt;
use ros2_client::gid::Gid;
use ros2_client::{Node, Subscription};
use tokio::sync::mpsc;

use super::dds;
use super::image as img;
use super::ingest::{Input, MapSender, Routed};
use super::initial_pose::{gate_from_msg, GateWidth, InitialPose};
use super::log::{info, lock};
use super::services;
use super::topics::Topics;
use crate::frame::{CameraImage, FramePart, PartKind, Stamp};
use crate::limits::InputLimits;
use crate::msgs::{self, convert, RosMessage};
use crate::params::{MapQos, Names, NodeParams};
use crate::tf_buffer::TfHistory;

/// Spawns a reader thread that drains `sub`, converting each message and its publisher's GUID
/// with `convert` (`None`: nothing for the ingest task). (ros2-client's sample streams are not
/// `Send`, so each reader gets its own small thread; it only decodes and converts, and ends as
/// soon as the ingest side is gone — a lifecycle cleanup — dropping its subscription.)
fn spawn_reader<M, F>(sub: Subscription<M>, topic: String, to: Route, convert: F) -> Result<JoinHandle<()>>
where
    M: RosMessage + Send + 'static,
    F: Fn(M, Gid) -> Option<Input> + Send + 'static,
{
    std::thread::Builder::new()
        .name(format!("reader {topic}"))
        .spawn(move || {
            futures::executor::block_on(async move {
                let stream = sub.async_stream();
                futures::pin_mut!(stream);
                let gone = to.tx.closed();
                futures::pin_mut!(gone);
                loop {
                    let r = match futures::future::select(stream.next(), &mut gone).await {
                        Either::Left((Some(r), _)) => r,
                        Either::Left((None, _)) | Either::Right(_) => break,
                    };
                    let input = match r {
                        Ok((msg, info)) => convert(msg, info.publisher_gid()),
                        Err(e) => Some(Input::ReadError { topic: topic.clone(), reason: format!("{e:?}") }),
                    };
                    let Some(input) = input else { continue };
                    if to.tx.send(Routed { camera: to.camera, input }).await.is_err() {
                        break;
                    }
                }
            })
        })
        .with_context(|| "spawning a reader thread".to_string())
}

/// A converted part, or the reason it did not convert, for the frame at `stamp`.
fn part_or_error<E: std::fmt::Display>(kind: PartKind, stamp: Stamp, r: Result<FramePart, E>) -> Option<Input> {
    Some(match r {
        Ok(p) => Input::Part(p),
        Err(e) => Input::PartError { kind, stamp, reason: e.to_string() },
    })
}

/// Subscribes `topic` and spawns its reader; `readers` collects the threads.
fn read<M, F>(readers: &mut Readers, topic: &str, qos: &ros2_client::QosProfile, convert: F) -> Result<()>
where
    M: RosMessage + Send + 'static,
    F: Fn(M) -> Option<Input> + Send + 'static,
{
    read_with_sender(readers, topic, qos, move |m, _| convert(m))
}

/// [`read`], its converter also given who published each message (the DDS GUID).
fn read_with_sender<M, F>(readers: &mut Readers, topic: &str, qos: &ros2_client::QosProfile, convert: F) -> Result<()>
where
    M: RosMessage + Send + 'static,
    F: Fn(M, Gid) -> Option<Input> + Send + 'static,
{
    let sub = dds::subscription::<M>(readers.node, topic, qos)?;
    let to = Route { tx: readers.tx.clone(), camera: readers.camera };
    readers.threads.push(spawn_reader(sub, topic.to_string(), to, convert)?);
    Ok(())
}

/// Where a reader's inputs go: the ingest task's channel, tagged with their camera.
struct Route {
    tx: mpsc::Sender<Routed>,
    camera: Option<usize>,
}

/// What the subscriptions are made on and handed to.
pub struct Readers<'a> {
    pub node: &'a mut Node,
    pub tx: mpsc::Sender<Routed>,
    /// The camera the next subscriptions are for (`None`: the node's own, e.g. the map, TF).
    pub camera: Option<usize>,
    pub threads: Vec<JoinHandle<()>>,
}

/// The frame inputs: camera info, correspondences, the depth prior when `wants_prior`.
pub fn subscribe_frame_parts(r: &mut Readers, topics: &Topics, limits: &InputLimits, wants_prior: bool) -> Result<()> {
    let sensor = dds::sensor_data(10);
    let l = limits.clone();
    read(r, &topics.camera_info, &sensor, move |m: msgs::CameraInfo| {
        let stamp = convert::stamp(&m.header);
        part_or_error(PartKind::CameraInfo, stamp, convert::camera_info_part(&m, &l))
    })?;
    // Best effort: matches reliable and best-effort matchers alike.
    // Held to the limits here, so a flood of huge messages leaves only the limit per frame
    // waiting in the queues (#38).
    let l = limits.clone();
    read(r, &topics.correspondences, &sensor, move |m: msgs::Correspondences| {
        let stamp = convert::stamp(&m.header);
        Some(match convert::correspondences_part_within(m, &l) {
            Ok((part, fixes)) => Input::LimitedCorrespondences(part, fixes),
            Err(e) => Input::PartError { kind: PartKind::Correspondences, stamp, reason: e.to_string() },
        })
    })?;
    if wants_prior {
        let l = limits.clone();
        read(r, &topics.depth_prior, &sensor, move |m: msgs::Image| {
            let stamp = convert::stamp(&m.header);
            part_or_error(PartKind::DepthPrior, stamp, convert::depth_prior_part(&m, &l))
        })?;
    }
    Ok(())
}

/// Which image topic feeds the frames: the first that delivers wins, the other is then
/// ignored (cameras often publish both raw and compressed; one image per frame is enough).
#[derive(Clone, Default)]
struct ImageSource(Arc<AtomicU8>);

impl ImageSource {
    const COMPRESSED: u8 = 1;
    const RAW: u8 = 2;

    /// True when images of `source` are used (claiming the slot if it is free).
    fn accept(&self, source: u8, topic: &str) -> bool {
        match self.0.compare_exchange(0, source, Ordering::AcqRel, Ordering::Acquire) {
            Ok(_) => {
                info(format!("camera images from {topic}"));
                true
            }
            Err(current) => current == source,
        }
    }
}

/// A camera image message → the frame's image part (`image`: the message within the limits,
/// or why not), when `which` source feeds the frames.
fn image_part(
    source: &ImageSource,
    which: u8,
    topic: &str,
    stamp: Stamp,
    image: impl FnOnce() -> Result<CameraImage, String>,
) -> Option<Input> {
    if !source.accept(which, topic) {
        return None;
    }
    part_or_error(PartKind::Image, stamp, image().map(|image| FramePart::Image { stamp, image }))
}

/// The camera images (`debug_image`): compressed and raw, whichever delivers first. Each is
/// held to `limits.max_image_side` and `limits.max_image_pixels` before a pixel is decoded: a
/// compressed one stays compressed (its header checked; decoded only to draw the debug image),
/// a raw one is converted to RGB.
pub fn subscribe_images(r: &mut Readers, topics: &Topics, limits: &InputLimits) -> Result<()> {
    let sensor = dds::sensor_data(10);
    let source = ImageSource::default();
    let (src, topic, l) = (source.clone(), topics.image.clone(), limits.clone());
    read(r, &topics.image, &sensor, move |m: msgs::CompressedImage| {
        let stamp = convert::stamp(&m.header);
        image_part(&src, ImageSource::COMPRESSED, &topic, stamp, || img::compressed_within(m, &l))
    })?;
    let (src, topic, l) = (source, topics.image_raw.clone(), limits.clone());
    read(r, &topics.image_raw, &sensor, move |m: msgs::Image| {
        let rgb = || img::rgb_from_image_within(&m, &l).map(CameraImage::Raw);
        image_part(&src, ImageSource::RAW, &topic, convert::stamp(&m.header), rgb)
    })
}

/// The map subscription(s) of `map_qos`: reliable, keep last 1.
fn map_qos_profiles(map_qos: MapQos) -> Vec<ros2_client::QosProfile> {
    match map_qos {
        MapQos::Auto => vec![dds::latched(), dds::reliable(1)],
        MapQos::TransientLocal => vec![dds::latched()],
        MapQos::Volatile => vec![dds::reliable(1)],
    }
}

/// The map, cleaned and within `limits.max_map_points` (as bag replay takes it).
pub fn subscribe_map(r: &mut Readers, topics: &Topics, map_qos: MapQos, limits: &InputLimits) -> Result<()> {
    for qos in map_qos_profiles(map_qos) {
        let limits = limits.clone();
        read_with_sender(r, &topics.map, &qos, move |m: msgs::PointCloud2, sender| {
            Some(Input::Map(
                convert::map_part(&m, &limits).map_err(|e| e.to_string()),
                MapSender::Publisher(format!("{sender:?}")),
            ))
        })?;
    }
    Ok(())
}

/// The map topic heard but never taken (`map_source: file`): each map on it is counted
/// (`error.map_refused`) and logged with its size, so an attempt to move the robot's map shows
/// in `/diagnostics`. One volatile reader: a map latched before the node started is not heard.
pub fn refuse_map_topic(r: &mut Readers, topics: &Topics) -> Result<()> {
    let topic = topics.map.clone();
    read(r, &topics.map, &dds::reliable(1), move |m: msgs::PointCloud2| {
        let detail = format!(
            "a map on {topic} ({} points, frame {:?}) refused: node.map_source is file",
            u64::from(m.width) * u64::from(m.height),
            m.header.frame_id
        );
        Some(Input::Invalid { reason: "map_refused", detail })
    })
}

/// `/tf` and `/tf_static` into `buffer` (for `map → odom`); bad transforms, new frames over
/// its frame limit and samples evicted over its sample budget are counted (`invalid_transform`)
/// and logged, one line per message however many transforms it carried.
pub fn subscribe_tf(r: &mut Readers, topics: &Topics, buffer: &Arc<Mutex<TfHistory>>) -> Result<()> {
    for (topic, qos, is_static) in [(&topics.tf, dds::reliable(100), false), (&topics.tf_static, dds::latched(), true)]
    {
        let buffer = buffer.clone();
        read(r, topic, &qos, move |m: msgs::TFMessage| {
            let bad = lock(&buffer).update(&m, is_static);
            (!bad.is_empty()).then(|| Input::Invalid { reason: "invalid_transform", detail: bad.join("; ") })
        })?;
    }
    Ok(())
}

/// `initialpose`: sets the gate that poses must fall in (nav2 amcl's topic). Who sent it is
/// logged; one from another publisher than the last one's is counted
/// (`initialpose_publisher_changed`), so a second source of initial poses shows.
pub fn subscribe_initial_pose(
    r: &mut Readers,
    topics: &Topics,
    width: &Arc<Mutex<GateWidth>>,
    gate: &Arc<Mutex<Option<InitialPose>>>,
) -> Result<()> {
    let (gate, width) = (gate.clone(), width.clone());
    let last_sender: Mutex<Option<Gid>> = Mutex::new(None);
    read_with_sender(r, &topics.initial_pose, &dds::reliable(10), move |m: msgs::PoseWithCovarianceStamped, gid| {
        match gate_from_msg(&m, None, *lock(&width)) {
            Ok(g) => {
                let sender = format!("{gid:?}");
                info(format!(
                    "initial pose from publisher {sender}: gate {:.2} m / {:.1}°",
                    g.radius_m,
                    g.max_angle_rad.to_degrees()
                ));
                let frame_id = m.header.frame_id.trim_start_matches('/').to_owned();
                *lock(&gate) = Some(InitialPose { frame_id, gate: g });
                let previous = lock(&last_sender).replace(gid);
                previous.filter(|p| *p != gid).map(|p| Input::Invalid {
                    reason: "initialpose_publisher_changed",
                    detail: format!("an initial pose from publisher {sender}, the last one's was {p:?}"),
                })
            }
            Err(e) => Some(Input::Invalid { reason: "invalid_initialpose", detail: e.to_string() }),
        }
    })
}

/// `~/load_map`: reloads `map_path` (the node's one map).
pub fn spawn_load_map(r: &mut Readers, names: &Names, np: &NodeParams) -> Result<()> {
    let (load_map_tx, map_path, map_frame_id) = (r.tx.clone(), np.map_path.clone(), np.map_frame_id.clone());
    let load_map = move || {
        let (response, map) = services::load_map_answer(&map_path, &map_frame_id);
        if let Some(map) = map {
            let input = Input::Map(Ok(convert::DecodedMap { map, notes: Vec::new() }), MapSender::File);
            // The node is shutting down when the ingest side is gone.
            let _ = load_map_tx.blocking_send(Routed { camera: None, input });
        }
        response
    };
    let stop = until_ingest_gone(&r.tx);
    r.threads.push(services::spawn_trigger(r.node, &names.resolve("~/load_map"), load_map, info, stop)?);
    Ok(())
}

/// Completes when the ingest side is gone (the node cleans up or stops): what a service of the
/// configured node serves until.
fn until_ingest_gone(tx: &mpsc::Sender<Routed>) -> impl std::future::Future<Output = ()> + Send + 'static {
    let tx = tx.clone();
    async move { tx.closed().await }
}

/// `relocalize` of one camera (the service `name`): drops its initial-pose gate.
pub fn spawn_relocalize(r: &mut Readers, name: &str, gate: &Arc<Mutex<Option<InitialPose>>>) -> Result<()> {
    let gate = gate.clone();
    let relocalize = move || {
        let had = lock(&gate).take().is_some();
        let message = if had { "initial pose dropped: localizing globally" } else { "no initial pose was set" };
        services::TriggerResponse { success: true, message: message.into() }
    };
    r.threads.push(services::spawn_trigger(r.node, name, relocalize, info, until_ingest_gone(&r.tx))?);
    Ok(())
}
