//! TODO(#2): msgs
