//! The `lifecycle_msgs` package on the wire, written out as serde structs as the node's other
//! ROS types are (ros2-client 0.12 has none of them): the messages `State`, `Transition`,
//! `TransitionDescription`, `TransitionEvent` and the services `ChangeState`, `GetState`,
//! `GetAvailableStates`, `GetAvailableTransitions` (the last also serves
//! `~/get_transition_graph`). Field order is the `.msg`/`.srv` order, which is the CDR order.

use ros2_client::{Message, MessageTypeName, ServiceTypeName};
use serde::{Deserialize, Serialize};

use super::lifecycle;

/// `lifecycle_msgs/msg/State`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct State {
    pub id: u8,
    pub label: String,
}
impl Message for State {}

/// `lifecycle_msgs/msg/Transition`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Transition {
    pub id: u8,
    pub label: String,
}
impl Message for Transition {}

/// `lifecycle_msgs/msg/TransitionDescription`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TransitionDescription {
    pub transition: Transition,
    pub start_state: State,
    pub goal_state: State,
}
impl Message for TransitionDescription {}

/// `lifecycle_msgs/msg/TransitionEvent`, published on `~/transition_event` at each step.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TransitionEvent {
    /// When the step was taken (ns since the epoch, the node's wall clock).
    pub timestamp: u64,
    pub transition: Transition,
    pub start_state: State,
    pub goal_state: State,
}
impl Message for TransitionEvent {}

/// `lifecycle_msgs/srv/ChangeState` request.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ChangeStateRequest {
    pub transition: Transition,
}
impl Message for ChangeStateRequest {}

/// `lifecycle_msgs/srv/ChangeState` response: whether the transition was taken and its
/// callback succeeded.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ChangeStateResponse {
    pub success: bool,
}
impl Message for ChangeStateResponse {}

/// The request of `GetState`, `GetAvailableStates` and `GetAvailableTransitions`: an empty ROS
/// struct carries one placeholder byte.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct EmptyRequest {
    pub structure_needs_at_least_one_member: u8,
}
impl Message for EmptyRequest {}

/// `lifecycle_msgs/srv/GetState` response.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct GetStateResponse {
    pub current_state: State,
}
impl Message for GetStateResponse {}

/// `lifecycle_msgs/srv/GetAvailableStates` response.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct GetAvailableStatesResponse {
    pub available_states: Vec<State>,
}
impl Message for GetAvailableStatesResponse {}

/// `lifecycle_msgs/srv/GetAvailableTransitions` response (also `~/get_transition_graph`'s).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct GetAvailableTransitionsResponse {
    pub available_transitions: Vec<TransitionDescription>,
}
impl Message for GetAvailableTransitionsResponse {}

/// `lifecycle_msgs/msg/TransitionEvent`'s type name.
pub fn transition_event_type() -> MessageTypeName {
    MessageTypeName::new("lifecycle_msgs", "TransitionEvent")
}

/// A `lifecycle_msgs/srv/<name>` type name (`ChangeState`, `GetState`, …).
pub fn service_type(name: &str) -> ServiceTypeName {
    ServiceTypeName::new("lifecycle_msgs", name)
}

impl From<lifecycle::State> for State {
    fn from(s: lifecycle::State) -> Self {
        Self { id: s.id(), label: s.label().to_string() }
    }
}

impl From<lifecycle::Transition> for Transition {
    fn from(t: lifecycle::Transition) -> Self {
        Self { id: t.id, label: t.label.to_string() }
    }
}

impl From<lifecycle::Transition> for TransitionDescription {
    fn from(t: lifecycle::Transition) -> Self {
        Self { transition: t.into(), start_state: t.start.into(), goal_state: t.goal.into() }
    }
}

impl TransitionEvent {
    /// The event of one step, taken at `timestamp` ns.
    pub fn of(step: lifecycle::Transition, timestamp: u64) -> Self {
        let TransitionDescription { transition, start_state, goal_state } = step.into();
        Self { timestamp, transition, start_state, goal_state }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::to_cdr;

    /// The bytes a ROS peer reads: CDR of `uint64 timestamp`, then each `uint8 id` right after
    /// what came before and `string label` (its length, with the NUL, 4-aligned).
    #[test]
    fn a_transition_event_is_laid_out_as_cdr() {
        let event = TransitionEvent::of(lifecycle::CONFIGURE, 7);
        assert_eq!(event.goal_state, State { id: 10, label: "configuring".into() });
        let bytes = to_cdr(&event);
        let mut want = vec![0, 1, 0, 0];
        want.extend(7u64.to_le_bytes());
        for (id, label) in [(1u8, "configure"), (1, "unconfigured"), (10, "configuring")] {
            want.push(id);
            while (want.len() - 4) % 4 != 0 {
                want.push(0);
            }
            want.extend((label.len() as u32 + 1).to_le_bytes());
            want.extend(label.as_bytes());
            want.push(0);
        }
        assert_eq!(bytes, want);
    }
}
