//! TODO(#2): consistency
