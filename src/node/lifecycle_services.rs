//! The lifecycle as a managed node serves it (rclcpp_lifecycle's services, which nav2's
//! lifecycle manager and `ros2 lifecycle` call): `~/get_state`, `~/get_available_states`,
//! `~/get_available_transitions` and `~/get_transition_graph`, answered from the shared state
//! on their own threads; `~/change_state`, whose requests go to the node's loop (a transition
//! builds or releases what the loop runs, [`super::managed`]) and are answered when the
//! transition is done; and `~/transition_event` (reliable), one event per step.
//!
//! Like the node's other services these use ros2-client's `Enhanced` request/reply mapping
//! (rmw_fastrtps's; see [`super::services`]).

use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use anyhow::{anyhow, Result};
use ros2_client::{Node, Publisher};
use tokio::sync::{mpsc, oneshot};

use super::dds;
use super::lifecycle::{self, Lifecycle, GRAPH};
use super::lifecycle_msgs::{self as wire, EmptyRequest};
use super::log::{lock, now_ns, warn};
use super::services::{self, SERVICE_MAPPING};
use crate::params::Names;

/// A `~/change_state` request, handed to the node's loop.
pub struct ChangeRequest {
    /// The transition asked for, by id or label.
    pub transition: wire::Transition,
    /// Where the loop answers whether the transition was taken and succeeded.
    pub reply: oneshot::Sender<bool>,
    /// Completes once the answer has gone out (the loop waits for it before the process ends
    /// after a shutdown transition, so the caller hears that it succeeded).
    pub sent: oneshot::Receiver<()>,
}

/// The lifecycle's services and events.
pub struct LifecycleServices {
    /// The `~/change_state` requests, one at a time.
    pub requests: mpsc::Receiver<ChangeRequest>,
    events: Publisher<wire::TransitionEvent>,
    events_topic: String,
    /// The server threads (they live as long as the process).
    _threads: Vec<JoinHandle<()>>,
}

impl LifecycleServices {
    /// Serves the lifecycle of the node `names` on `node`, reading `state`.
    pub fn serve(node: &mut Node, names: &Names, state: &Arc<Mutex<Lifecycle>>) -> Result<Self> {
        let events_topic = names.resolve("~/transition_event");
        let qos = dds::reliable(10);
        let topic = node
            .create_topic(&dds::topic_name(&events_topic)?, wire::transition_event_type(), &qos)
            .map_err(|e| anyhow!("creating topic {events_topic}: {e:?}"))?;
        let events = node
            .create_publisher::<wire::TransitionEvent>(&topic, Some(qos))
            .map_err(|e| anyhow!("creating publisher on {events_topic}: {e:?}"))?;
        let (tx, requests) = mpsc::channel(4);
        let mut threads = vec![spawn_change_state(node, &names.resolve("~/change_state"), tx)?];
        threads.extend(spawn_reads(node, names, state)?);
        Ok(Self { requests, events, events_topic, _threads: threads })
    }

    /// Announces one step on `~/transition_event`.
    pub async fn publish(&self, step: lifecycle::Transition) {
        let event = wire::TransitionEvent::of(step, u64::try_from(now_ns()).unwrap_or(0));
        if let Err(e) = self.events.async_publish(event).await {
            warn(format!("publishing on {} failed: {e:?}", self.events_topic));
        }
    }
}

/// The four read-only services, answered from `state`.
fn spawn_reads(node: &mut Node, names: &Names, state: &Arc<Mutex<Lifecycle>>) -> Result<Vec<JoinHandle<()>>> {
    let never = std::future::pending::<()>;
    let log = |m: String| warn(m);
    let transitions = |list: Vec<lifecycle::Transition>| wire::GetAvailableTransitionsResponse {
        available_transitions: list.into_iter().map(Into::into).collect(),
    };
    let current = state.clone();
    let get_state = move |_: EmptyRequest| wire::GetStateResponse { current_state: lock(&current).current().into() };
    let get_states = |_: EmptyRequest| wire::GetAvailableStatesResponse {
        available_states: lifecycle::State::ALL.into_iter().map(Into::into).collect(),
    };
    let current = state.clone();
    let get_available = move |_: EmptyRequest| transitions(lock(&current).available());
    let get_graph = move |_: EmptyRequest| transitions(GRAPH.to_vec());
    let available_type = wire::service_type("GetAvailableTransitions");
    Ok(vec![
        services::spawn_server(
            node,
            &names.resolve("~/get_state"),
            &wire::service_type("GetState"),
            get_state,
            log,
            never(),
        )?,
        services::spawn_server(
            node,
            &names.resolve("~/get_available_states"),
            &wire::service_type("GetAvailableStates"),
            get_states,
            log,
            never(),
        )?,
        services::spawn_server(
            node,
            &names.resolve("~/get_available_transitions"),
            &available_type,
            get_available,
            log,
            never(),
        )?,
        services::spawn_server(
            node,
            &names.resolve("~/get_transition_graph"),
            &available_type,
            get_graph,
            log,
            never(),
        )?,
    ])
}

/// `~/change_state` on its own thread: each request goes to the node's loop through `to_loop`,
/// and its answer back to the caller once the loop has run the transition.
fn spawn_change_state(node: &mut Node, service: &str, to_loop: mpsc::Sender<ChangeRequest>) -> Result<JoinHandle<()>> {
    let qos = dds::reliable(10);
    let server = node
        .create_server::<wire::ChangeStateRequest, wire::ChangeStateResponse>(
            SERVICE_MAPPING,
            &dds::topic_name(service)?,
            &wire::service_type("ChangeState"),
            qos.clone(),
            qos,
        )
        .map_err(|e| anyhow!("cannot create service {service}: {e:?}"))?;
    let name = service.to_string();
    std::thread::Builder::new()
        .name(format!("service {name}"))
        .spawn(move || {
            futures::executor::block_on(async move {
                loop {
                    let (id, request) = match server.async_receive_request().await {
                        Ok(r) => r,
                        Err(e) => {
                            warn(format!("{name}: unreadable request: {e:?}"));
                            continue;
                        }
                    };
                    let (reply, answer) = oneshot::channel();
                    let (sent_tx, sent) = oneshot::channel();
                    let change = ChangeRequest { transition: request.transition, reply, sent };
                    if to_loop.send(change).await.is_err() {
                        // The node's loop has ended: nothing can change state any more.
                        break;
                    }
                    let success = answer.await.unwrap_or(false);
                    if let Err(e) = server.async_send_response(id, wire::ChangeStateResponse { success }).await {
                        warn(format!("{name}: response not sent: {e:?}"));
                    }
                    let _ = sent_tx.send(());
                }
            })
        })
        .map_err(|e| anyhow!("spawning the {service} thread: {e}"))
}
