//! Robot recordings in: the readers `surgvla ingest` builds on. ROS message definitions
//! ([`msgdef`], with [`builtin`] definitions of the common types for bags that carry none), the
//! two wire formats decoded by definition ([`decode`]: ROS 1 and CDR), recordings read as
//! streams of [`recording`]'s channels and messages (ROS 1 bags: [`ros1`]; MCAP: [`mcap`], lz4 chunks by [`lz4chunk`]; ROS 2
//! bag folders: [`rosbag2`]; any of them through [`open`]), features taken from decoded messages
//! ([`extract`]: poses, joints, images, depth), the first pass over a recording for each
//! topic's times ([`stamps`]), the synchronisation rule that puts them on frames ([`sync`]),
//! the second pass that hands each frame's picked messages over ([`frames`]), made into
//! episodes ([`episodes`]) and reported in the dataset ([`report`]); [`dvrk`] maps a da Vinci
//! Research Kit recording's topics to state, action, images and task ([`map`]: more topics
//! as features from a user's map file), [`source`] reads
//! recordings as episodes any sink takes, and [`openh`] writes what Open-H asks of a
//! contribution besides the files (its README). Everything here reads untrusted files: sizes are
//! checked before allocating, and a damaged input is an error naming the file and the offset.
//!
//! This file only declares the modules.

pub mod builtin;
pub mod decode;
pub mod dvrk;
pub mod episodes;
pub mod error;
pub mod extract;
#[cfg(test)]
pub(crate) mod fixtures;
pub mod frames;
pub mod lz4chunk;
pub mod map;
pub mod mcap;
pub mod msgdef;
pub mod open;
pub mod openh;
pub mod recording;
pub mod report;
pub mod ros1;
pub mod rosbag2;
pub mod source;
pub mod stamps;
pub mod sync;
