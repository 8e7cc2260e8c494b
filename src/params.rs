//! TODO(#2): params
