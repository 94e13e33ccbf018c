//! The simulator: truth motion, sensor models, frame encoders (the core's own).
pub mod accel;
pub mod fog;
pub mod gnss;
pub mod launch;
pub mod star;
pub mod truth;
