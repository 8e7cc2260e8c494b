//! TODO(#2): eval
