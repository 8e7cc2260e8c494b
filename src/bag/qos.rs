//! The QoS a topic is recorded with: rosbag2's `offered_qos_profiles` (metadata version 9:
//! policy names as strings, durations as `{sec, nsec}`), so `ros2 bag play` offers each topic
//! as its publisher did — above all the map latched (transient local), as a map server offers it.

use serde_yaml::{Mapping, Value};

/// rmw's `RMW_DURATION_INFINITE` as rosbag2 writes it: no deadline, lifespan or lease.
const INFINITE_SEC: i64 = 9_223_372_036;
const INFINITE_NSEC: i64 = 854_775_807;

/// Durability a topic was published with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Durability {
    /// Each message goes to the subscribers present when it is sent (streams: poses, images).
    #[default]
    Volatile,
    /// The last message is kept for late subscribers (latched: the map, static data).
    TransientLocal,
}

/// The one profile a topic of ours is offered with: reliable, keep last (1 when latched, as
/// map servers do, else 10, rclcpp's default depth), automatic liveliness, no deadlines.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OfferedQos {
    pub durability: Durability,
}

impl OfferedQos {
    pub const LATCHED: OfferedQos = OfferedQos { durability: Durability::TransientLocal };

    /// `offered_qos_profiles` for `metadata.yaml`: a list of one profile.
    pub fn profiles(&self) -> Value {
        Value::Sequence(vec![self.profile()])
    }

    /// The same list as the YAML text rosbag2's MCAP storage keeps in channel metadata.
    pub fn profiles_yaml(&self) -> String {
        serde_yaml::to_string(&self.profiles()).map(|s| s.trim_end().to_string()).unwrap_or_default()
    }

    fn profile(&self) -> Value {
        let (durability, depth) = match self.durability {
            Durability::Volatile => ("volatile", 10),
            Durability::TransientLocal => ("transient_local", 1),
        };
        let mut p = Mapping::new();
        let mut put = |k: &str, v: Value| {
            p.insert(Value::from(k), v);
        };
        put("history", Value::from("keep_last"));
        put("depth", Value::from(depth));
        put("reliability", Value::from("reliable"));
        put("durability", Value::from(durability));
        put("deadline", infinite());
        put("lifespan", infinite());
        put("liveliness", Value::from("automatic"));
        put("liveliness_lease_duration", infinite());
        put("avoid_ros_namespace_conventions", Value::from(false));
        Value::Mapping(p)
    }
}

fn infinite() -> Value {
    let mut d = Mapping::new();
    d.insert(Value::from("sec"), Value::from(INFINITE_SEC));
    d.insert(Value::from("nsec"), Value::from(INFINITE_NSEC));
    Value::Mapping(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latched_profile_is_reliable_transient_local_depth_one() {
        let v = OfferedQos::LATCHED.profiles();
        let p = &v[0];
        assert_eq!(p["durability"], Value::from("transient_local"));
        assert_eq!(p["reliability"], Value::from("reliable"));
        assert_eq!(p["depth"], Value::from(1));
        assert_eq!(p["deadline"]["sec"], Value::from(INFINITE_SEC));
        assert_eq!(OfferedQos::default().profiles()[0]["durability"], Value::from("volatile"));
    }

    #[test]
    fn channel_text_parses_back_to_the_metadata_list() {
        let q = OfferedQos::LATCHED;
        let back: Value = serde_yaml::from_str(&q.profiles_yaml()).unwrap();
        assert_eq!(back, q.profiles());
        assert!(q.profiles_yaml().starts_with("- history: keep_last"));
    }
}
