//! The node's services: the std_srvs/Trigger ones (`~/load_map` reads `node.map_path` again and
//! hands the map to the node, answering how many points it loaded or why it could not;
//! `~/relocalize` drops the `/initialpose` gate, [`super::initial_pose`]) and the server thread
//! every service runs on (the lifecycle's too, [`super::lifecycle_services`]).
//!
//! Services use ros2-client's `Enhanced` request/reply mapping (the one of rmw_fastrtps, ROS 2's
//! default middleware; rmw_cyclonedds uses another mapping that ros2-client supports only on one
//! host, so a `ros2 service call` through Cyclone DDS may not reach the node).

use std::future::Future;
use std::path::PathBuf;

use anyhow::{anyhow, Result};
use futures::future::Either;
use ros2_client::{Message, Node, ServiceMapping, ServiceTypeName};
use serde::{Deserialize, Serialize};

use super::dds;
use super::map_file;
use crate::frame::MapCloud;

/// `std_srvs/srv/Trigger` request (an empty ROS struct carries one placeholder byte).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TriggerRequest {
    pub structure_needs_at_least_one_member: u8,
}
impl Message for TriggerRequest {}

/// `std_srvs/srv/Trigger` response.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TriggerResponse {
    pub success: bool,
    pub message: String,
}
impl Message for TriggerResponse {}

/// The `std_srvs/Trigger` type name.
pub fn trigger_type() -> ServiceTypeName {
    ServiceTypeName::new("std_srvs", "Trigger")
}

/// The mapping the node's services use.
pub const SERVICE_MAPPING: ServiceMapping = ServiceMapping::Enhanced;

/// What `~/load_map` answers for `map_path` (empty: not configured), and the map it loaded.
pub fn load_map_answer(map_path: &str, frame_id: &str) -> (TriggerResponse, Option<MapCloud>) {
    if map_path.is_empty() {
        let message = "no map_path set: nothing to load (the map comes from the map topic)".to_string();
        return (TriggerResponse { success: false, message }, None);
    }
    match map_file::load(&PathBuf::from(map_path), frame_id) {
        Ok(loaded) => {
            let message = format!(
                "{} points from {map_path} ({} non-finite left out)",
                loaded.map.points.len(),
                loaded.non_finite
            );
            (TriggerResponse { success: true, message }, Some(loaded.map))
        }
        Err(e) => (TriggerResponse { success: false, message: e.to_string() }, None),
    }
}

/// Serves the std_srvs/Trigger `service` (e.g. `/cam0/angle_i2p/load_map`) on its own thread,
/// answering each request with `handle`'s response (logged), until `stop` completes.
pub fn spawn_trigger(
    node: &mut Node,
    service: &str,
    mut handle: impl FnMut() -> TriggerResponse + Send + 'static,
    log: fn(String),
    stop: impl Future<Output = ()> + Send + 'static,
) -> Result<std::thread::JoinHandle<()>> {
    let name = service.to_string();
    let answer = move |_: TriggerRequest| {
        let response = handle();
        log(format!("{name}: {}", response.message));
        response
    };
    spawn_server(node, service, &trigger_type(), answer, log, stop)
}

/// Serves `service` of type `type_name` on its own thread, answering each request with
/// `handle`'s response, until `stop` completes (then the server is dropped, and with it its
/// DDS reader and writer: a node that cleans up serves nothing twice when configured again).
pub fn spawn_server<Q, A>(
    node: &mut Node,
    service: &str,
    type_name: &ServiceTypeName,
    mut handle: impl FnMut(Q) -> A + Send + 'static,
    log: fn(String),
    stop: impl Future<Output = ()> + Send + 'static,
) -> Result<std::thread::JoinHandle<()>>
where
    Q: Message + Clone + Send + 'static,
    A: Message + Send + 'static,
{
    let qos = dds::reliable(10);
    let server = node
        .create_server::<Q, A>(SERVICE_MAPPING, &dds::topic_name(service)?, type_name, qos.clone(), qos)
        .map_err(|e| anyhow!("cannot create service {service}: {e:?}"))?;
    let name = service.to_string();
    std::thread::Builder::new()
        .name(format!("service {name}"))
        .spawn(move || {
            futures::executor::block_on(async move {
                futures::pin_mut!(stop);
                loop {
                    let next = server.async_receive_request();
                    futures::pin_mut!(next);
                    let (id, request) = match futures::future::select(next, &mut stop).await {
                        Either::Left((Ok(r), _)) => r,
                        Either::Left((Err(e), _)) => {
                            log(format!("{name}: unreadable request: {e:?}"));
                            continue;
                        }
                        Either::Right(_) => break,
                    };
                    if let Err(e) = server.async_send_response(id, handle(request)).await {
                        log(format!("{name}: response not sent: {e:?}"));
                    }
                }
            })
        })
        .map_err(|e| anyhow!("spawning the {service} thread: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn load_map_answers_what_it_did() {
        let (r, map) = load_map_answer("", "map");
        assert!(!r.success && map.is_none(), "{r:?}");
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("m.ply");
        std::fs::write(&path, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n").unwrap();
        let (r, map) = load_map_answer(path.to_str().unwrap(), "world");
        assert!(r.success, "{r:?}");
        assert!(r.message.starts_with("1 points"), "{r:?}");
        assert_eq!(map.map(|m| m.frame_id), Some("world".to_string()));
        std::fs::write(&path, "not a ply").unwrap();
        let (r, map) = load_map_answer(path.to_str().unwrap(), "world");
        assert!(!r.success && map.is_none() && r.message.contains("m.ply"), "{r:?}");
    }
}
