//! Robot recordings in: the readers `surgvla ingest` builds on. ROS message definitions
//! ([`msgdef`], with [`builtin`] definitions of the common types for bags that carry none), the
//! two wire formats decoded by definition ([`decode`]: ROS 1 and CDR), and ROS 1 bags read as a
//! stream ([`ros1`]). Everything here reads untrusted files: sizes are checked before
//! allocating, and a damaged input is an error naming the file and the offset.
//!
//! This file only declares the modules.

pub mod builtin;
pub mod decode;
pub mod msgdef;
pub mod ros1;
