//! The managed-node state machine of ROS 2's node lifecycle design (design.ros2.org,
//! "Managed nodes"), as rcl_lifecycle's default state machine has it: the primary states
//! unconfigured, inactive, active and finalized, the transition states between them, the
//! transitions with the ids and labels of `lifecycle_msgs` (so `ros2 lifecycle`, rclcpp clients
//! and nav2's lifecycle manager read them as they read an rclcpp node's), and which transition
//! is valid from which state. Pure: no ROS here; [`super::managed`] runs the node's callbacks
//! and [`super::lifecycle_services`] serves it.
//!
//! A change is two steps, as in rcl: [`Lifecycle::begin`] takes a primary state into its
//! transition state (`configure`: unconfigured → configuring), the node runs its callback, and
//! [`Lifecycle::finish`] takes the transition state on by the callback's result (success →
//! inactive, failure → back to unconfigured, error → errorprocessing, whose own callback then
//! ends in unconfigured or finalized). Each step is one `~/transition_event`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use thiserror::Error;

/// A state of the lifecycle (`lifecycle_msgs/msg/State`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum State {
    Unknown,
    Unconfigured,
    Inactive,
    Active,
    Finalized,
    Configuring,
    CleaningUp,
    ShuttingDown,
    Activating,
    Deactivating,
    ErrorProcessing,
}

impl State {
    /// Every state, in `lifecycle_msgs/msg/State`'s order (what `~/get_available_states` lists,
    /// as rcl registers them: `unknown` included).
    pub const ALL: [State; 11] = [
        State::Unknown,
        State::Unconfigured,
        State::Inactive,
        State::Active,
        State::Finalized,
        State::Configuring,
        State::CleaningUp,
        State::ShuttingDown,
        State::Activating,
        State::Deactivating,
        State::ErrorProcessing,
    ];

    /// Its id: `PRIMARY_STATE_*` (0–4) or `TRANSITION_STATE_*` (10–15).
    pub fn id(self) -> u8 {
        match self {
            State::Unknown => 0,
            State::Unconfigured => 1,
            State::Inactive => 2,
            State::Active => 3,
            State::Finalized => 4,
            State::Configuring => 10,
            State::CleaningUp => 11,
            State::ShuttingDown => 12,
            State::Activating => 13,
            State::Deactivating => 14,
            State::ErrorProcessing => 15,
        }
    }

    /// Its label, as rcl_lifecycle names it.
    pub fn label(self) -> &'static str {
        match self {
            State::Unknown => "unknown",
            State::Unconfigured => "unconfigured",
            State::Inactive => "inactive",
            State::Active => "active",
            State::Finalized => "finalized",
            State::Configuring => "configuring",
            State::CleaningUp => "cleaningup",
            State::ShuttingDown => "shuttingdown",
            State::Activating => "activating",
            State::Deactivating => "deactivating",
            State::ErrorProcessing => "errorprocessing",
        }
    }

    pub fn from_id(id: u8) -> Option<State> {
        State::ALL.into_iter().find(|s| s.id() == id)
    }

    /// A primary state: one the node rests in (a transition state lasts one callback).
    pub fn is_primary(self) -> bool {
        self.id() < 10
    }
}

impl std::fmt::Display for State {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.label())
    }
}

/// What a transition's callback returned (`lifecycle_msgs/msg/Transition`'s
/// `TRANSITION_CALLBACK_*`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CallbackReturn {
    Success,
    Failure,
    Error,
}

impl CallbackReturn {
    /// `TRANSITION_CALLBACK_SUCCESS` 97, `_FAILURE` 98, `_ERROR` 99.
    pub fn id(self) -> u8 {
        match self {
            CallbackReturn::Success => 97,
            CallbackReturn::Failure => 98,
            CallbackReturn::Error => 99,
        }
    }

    /// The label of the transition it takes: `transition_success`, `_failure`, `_error`.
    fn label(self) -> &'static str {
        match self {
            CallbackReturn::Success => "transition_success",
            CallbackReturn::Failure => "transition_failure",
            CallbackReturn::Error => "transition_error",
        }
    }
}

/// A transition of the graph: its `lifecycle_msgs/msg/Transition` id and label, and the states
/// it goes from and to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Transition {
    pub id: u8,
    pub label: &'static str,
    pub start: State,
    pub goal: State,
}

const fn t(id: u8, label: &'static str, start: State, goal: State) -> Transition {
    Transition { id, label, start, goal }
}

/// `TRANSITION_CONFIGURE` … `TRANSITION_ACTIVE_SHUTDOWN`: the ones a client may ask for.
pub const CONFIGURE: Transition = t(1, "configure", State::Unconfigured, State::Configuring);
pub const CLEANUP: Transition = t(2, "cleanup", State::Inactive, State::CleaningUp);
pub const ACTIVATE: Transition = t(3, "activate", State::Inactive, State::Activating);
pub const DEACTIVATE: Transition = t(4, "deactivate", State::Active, State::Deactivating);
pub const UNCONFIGURED_SHUTDOWN: Transition = t(5, "shutdown", State::Unconfigured, State::ShuttingDown);
pub const INACTIVE_SHUTDOWN: Transition = t(6, "shutdown", State::Inactive, State::ShuttingDown);
pub const ACTIVE_SHUTDOWN: Transition = t(7, "shutdown", State::Active, State::ShuttingDown);

/// The whole graph (what `~/get_transition_graph` answers), in rcl_lifecycle's order: each
/// public transition into its transition state, then that state's success / failure / error
/// transitions (`TRANSITION_ON_*`, 10–62: taken by the node, never asked for).
pub const GRAPH: [Transition; 25] = {
    use State::*;
    [
        CONFIGURE,
        t(10, "transition_success", Configuring, Inactive),
        t(11, "transition_failure", Configuring, Unconfigured),
        t(12, "transition_error", Configuring, ErrorProcessing),
        CLEANUP,
        t(20, "transition_success", CleaningUp, Unconfigured),
        t(21, "transition_failure", CleaningUp, Inactive),
        t(22, "transition_error", CleaningUp, ErrorProcessing),
        ACTIVATE,
        t(30, "transition_success", Activating, Active),
        t(31, "transition_failure", Activating, Inactive),
        t(32, "transition_error", Activating, ErrorProcessing),
        DEACTIVATE,
        t(40, "transition_success", Deactivating, Inactive),
        t(41, "transition_failure", Deactivating, Active),
        t(42, "transition_error", Deactivating, ErrorProcessing),
        UNCONFIGURED_SHUTDOWN,
        INACTIVE_SHUTDOWN,
        ACTIVE_SHUTDOWN,
        t(50, "transition_success", ShuttingDown, Finalized),
        t(51, "transition_failure", ShuttingDown, Finalized),
        t(52, "transition_error", ShuttingDown, ErrorProcessing),
        t(60, "transition_success", ErrorProcessing, Unconfigured),
        t(61, "transition_failure", ErrorProcessing, Finalized),
        t(62, "transition_error", ErrorProcessing, Finalized),
    ]
};

/// Why a transition cannot be taken.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum LifecycleError {
    #[error("no transition labelled {label:?} from state {state}")]
    NoSuchLabel { label: String, state: State },
    #[error("transition id {id} is not available from state {state}")]
    NotAvailable { id: u8, state: State },
    #[error("state {state} is no transition state: there is no transition to finish")]
    NotTransitioning { state: State },
}

/// The node's lifecycle state: where it is and the transitions open from there.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Lifecycle {
    current: State,
}

impl Default for Lifecycle {
    /// A node starts unconfigured.
    fn default() -> Self {
        Self { current: State::Unconfigured }
    }
}

impl Lifecycle {
    pub fn current(&self) -> State {
        self.current
    }

    /// The transitions from the current state (`~/get_available_transitions`): from a primary
    /// state those a client may ask for; from a transition state its success/failure/error.
    pub fn available(&self) -> Vec<Transition> {
        GRAPH.into_iter().filter(|t| t.start == self.current).collect()
    }

    /// The transition a `~/change_state` request names, as rclcpp reads one: a non-empty label
    /// names the transition of that label from the current state (`shutdown` is 5, 6 or 7 by
    /// state) and the id is then not looked at; else the id must be one open from here.
    pub fn resolve(&self, id: u8, label: &str) -> Result<Transition, LifecycleError> {
        let open = self.available();
        if !label.is_empty() {
            return open
                .into_iter()
                .find(|t| t.label == label)
                .ok_or_else(|| LifecycleError::NoSuchLabel { label: label.to_string(), state: self.current });
        }
        open.into_iter().find(|t| t.id == id).ok_or(LifecycleError::NotAvailable { id, state: self.current })
    }

    /// Starts `transition` from the current state, into its transition state.
    pub fn begin(&mut self, transition: Transition) -> Result<Transition, LifecycleError> {
        if transition.start != self.current || transition.goal.is_primary() {
            return Err(LifecycleError::NotAvailable { id: transition.id, state: self.current });
        }
        self.current = transition.goal;
        Ok(transition)
    }

    /// Leaves the current transition state by the callback's result, and returns the
    /// transition taken.
    pub fn finish(&mut self, result: CallbackReturn) -> Result<Transition, LifecycleError> {
        let taken = GRAPH
            .into_iter()
            .find(|t| t.start == self.current && !t.start.is_primary() && t.label == result.label())
            .ok_or(LifecycleError::NotTransitioning { state: self.current })?;
        self.current = taken.goal;
        Ok(taken)
    }
}

/// Whether the node is active, shared with whoever must stay silent otherwise (the workers
/// before they localize and before they publish, the `map → odom` re-send): one flag rather
/// than the whole state, because "may I publish now" is all they ask.
#[derive(Clone, Debug, Default)]
pub struct Activity(Arc<AtomicBool>);

impl Activity {
    pub fn is_active(&self) -> bool {
        self.0.load(Ordering::Acquire)
    }

    pub fn set(&self, active: bool) {
        self.0.store(active, Ordering::Release);
    }
}

#[cfg(test)]
#[path = "lifecycle_tests.rs"]
mod tests;
