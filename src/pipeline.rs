//! TODO(#2): pipeline
