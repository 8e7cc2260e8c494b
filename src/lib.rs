//! angle-i2p: reject outlier 2D–3D correspondences with angle-based spatial consistency
//! (Angle-I2P) and localize a camera against a point map with robust PnP.
//!
//! Data flows one way: messages → [`frame::Frame`] → rejection → pose → messages.
//! The core (`geometry`, `consistency`, `reject`, `pnp`, `verify`, `pipeline`, `eval`) is pure and
//! free of I/O; `msgs` and `bag` are the edges.

pub mod app;
pub mod bag;
pub mod camera;
pub mod consistency;
pub mod eval;
pub mod frame;
pub use geometry::align;
pub mod geometry;
pub mod limits;
pub mod map_index;
pub mod msgs;
pub mod node;
pub mod npy;
pub mod params;
pub mod pipeline;
pub mod play;
pub mod pnp;
pub mod reject;
pub mod report;
pub mod rng;
pub mod synth;
pub mod tf_buffer;
pub mod verify;
