//! TODO(#2): bag
