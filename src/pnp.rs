//! TODO(#2): pnp
