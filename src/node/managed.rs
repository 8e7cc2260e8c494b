//! The node as a managed node (ROS 2's node lifecycle, as nav2_amcl is one): the callbacks of
//! each transition, what each state holds, and the two ways in — `~/change_state` (a lifecycle
//! manager, `ros2 lifecycle set`) and the node's own start (`node.autostart`: configure and
//! activate, as an unmanaged node always did) or stop (SIGINT/SIGTERM: shutdown).
//!
//! - unconfigured: the ROS node, its parameters and lifecycle services, `/clock`; sends nothing.
//! - inactive: + [`Configured`] (map, model, publishers, subscriptions, workers); sends only
//!   `/diagnostics`, every frame dropped and counted (`inactive`).
//! - active: the same; sends poses, TF and `/diagnostics`.
//! - finalized: nothing; the node stops.
//!
//! Callbacks succeed or fail, never error: a configure that fails has released what it made,
//! and the node is unconfigured again, as rcl's `transition_failure` has it.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use ros2_client::{Context, Node};
use thiserror::Error;
use tokio::sync::mpsc;

use super::configured::Configured;
use super::lifecycle::{self, Activity, CallbackReturn, Lifecycle, LifecycleError, State};
use super::lifecycle_services::{ChangeRequest, LifecycleServices};
use super::log::{info, lock, warn};
use super::ros_params::LiveParams;
use super::setup::{log_started, Setup};

/// Why a change of state did not happen.
#[derive(Debug, Error)]
pub enum ChangeError {
    #[error("lifecycle: {0}")]
    Refused(#[from] LifecycleError),
    #[error("lifecycle: {transition} failed, the node is {now}: {reason}")]
    Failed { transition: &'static str, now: State, reason: String },
}

/// The node's lifecycle state, services and what the current state holds.
pub struct Managed {
    state: Arc<Mutex<Lifecycle>>,
    services: LifecycleServices,
    active: Activity,
    context: Context,
    /// What configure made (inactive and active states).
    pub configured: Option<Configured>,
    /// The node's parameters (configure shows the model's constants there).
    live: LiveParams,
}

impl Managed {
    /// Serves the lifecycle on `node`; the node is unconfigured.
    pub fn new(context: &Context, node: &mut Node, s: &Setup, live: LiveParams) -> anyhow::Result<Self> {
        let state = Arc::new(Mutex::new(Lifecycle::default()));
        let services = LifecycleServices::serve(node, &s.names, &state)?;
        let context = context.clone();
        Ok(Self { state, services, active: Activity::default(), context, configured: None, live })
    }

    pub fn current(&self) -> State {
        lock(&self.state).current()
    }

    /// The `~/change_state` requests and what the current state holds, borrowed apart (the
    /// node's loop waits on both).
    pub fn parts(&mut self) -> (&mut mpsc::Receiver<ChangeRequest>, Option<&mut Configured>) {
        (&mut self.services.requests, self.configured.as_mut())
    }

    /// `node.autostart`: configure and activate, as an unmanaged node starts.
    pub async fn startup(&mut self, node: &mut Node, s: &Setup) -> Result<(), ChangeError> {
        self.change(lifecycle::CONFIGURE, node, s).await?;
        self.change(lifecycle::ACTIVATE, node, s).await
    }

    /// Takes the transition a `~/change_state` request names, and answers it; after a
    /// shutdown, waits (bounded) until the answer has gone out.
    pub async fn on_request(&mut self, request: ChangeRequest, node: &mut Node, s: &Setup) {
        let ChangeRequest { transition, reply, sent } = request;
        let resolved = lock(&self.state).resolve(transition.id, &transition.label);
        let outcome = match resolved {
            Ok(t) => self.change(t, node, s).await,
            Err(e) => Err(e.into()),
        };
        if let Err(e) = &outcome {
            warn(format!("~/change_state {} ({:?}): {e}", transition.id, transition.label));
        }
        let _ = reply.send(outcome.is_ok());
        if self.current() == State::Finalized {
            let _ = tokio::time::timeout(Duration::from_secs(1), sent).await;
        }
    }

    /// Shutdown from wherever the node is (SIGINT/SIGTERM, or the loop ended otherwise).
    pub async fn shutdown(&mut self, node: &mut Node, s: &Setup) {
        let shutdown = lock(&self.state).resolve(0, "shutdown");
        match shutdown {
            Ok(t) => {
                if let Err(e) = self.change(t, node, s).await {
                    warn(e);
                }
            }
            Err(e) => warn(format!("shutting down: {e}")),
        }
    }

    /// One change: into the transition state (an event), the callback, on by its result (an
    /// event).
    async fn change(&mut self, t: lifecycle::Transition, node: &mut Node, s: &Setup) -> Result<(), ChangeError> {
        let step = lock(&self.state).begin(t)?;
        self.services.publish(step).await;
        let outcome = self.callback(t.goal, node, s).await;
        let result = if outcome.is_ok() { CallbackReturn::Success } else { CallbackReturn::Failure };
        let step = lock(&self.state).finish(result)?;
        self.services.publish(step).await;
        info(format!("lifecycle: {} → {}", t.label, step.goal));
        outcome.map_err(|reason| ChangeError::Failed { transition: t.label, now: step.goal, reason })
    }

    /// The callback of the transition state `doing`.
    async fn callback(&mut self, doing: State, node: &mut Node, s: &Setup) -> Result<(), String> {
        match doing {
            State::Configuring => self.on_configure(node, s),
            State::Activating => {
                self.active.set(true);
                Ok(())
            }
            State::Deactivating => {
                self.active.set(false);
                Ok(())
            }
            State::CleaningUp => {
                self.release(s).await;
                Ok(())
            }
            State::ShuttingDown => {
                // Frames already queued finish as the node always stopped: published when active.
                self.release(s).await;
                self.active.set(false);
                Ok(())
            }
            other => Err(format!("no callback for state {other}")),
        }
    }

    fn on_configure(&mut self, node: &mut Node, s: &Setup) -> Result<(), String> {
        let configured = Configured::configure(&self.context, node, s, &self.active).map_err(|e| format!("{e:#}"))?;
        if let Some(running) = configured.localizer_params() {
            self.show_running(node, running);
        }
        self.configured = Some(configured);
        log_started(s, &self.context, &s.names.fully_qualified());
        Ok(())
    }

    /// The parameters the localizers run with on the node's parameter services: the model's
    /// constants (`network.*`, from its metadata) replace the params' values they overrode.
    fn show_running(&self, node: &mut Node, running: &crate::params::LocalizerParams) {
        let changed = match self.live.adopt(running) {
            Ok(changed) => changed,
            Err(e) => return warn(format!("the model's constants are not shown as parameters: {e}")),
        };
        for p in changed {
            match node.set_parameter(&p.name, p.value.clone()) {
                Ok(()) => info(format!("parameter {} is {:?}, the model's", p.name, p.value)),
                Err(e) => warn(format!("parameter {}: the model's value not shown: {e}", p.name)),
            }
        }
    }

    async fn release(&mut self, s: &Setup) {
        if let Some(configured) = self.configured.take() {
            configured.release(s).await;
        }
    }
}
