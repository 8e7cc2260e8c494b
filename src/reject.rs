//! TODO(#2): reject
