//! TODO(#2): synth
