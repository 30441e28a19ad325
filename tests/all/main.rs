//! The one integration test binary: kinematics, physics, grasping, determinism, tasks and
//! experts, collection, the LeRobot, RLDS and point-cloud formats, recordings ingested,
//! rendering and the CLI.

// Tests and benches fail by unwrapping, expecting and panicking (denied in the library).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
// A test is one scenario, read top to bottom: the 80-line limit is for the library and the CLI.
#![allow(clippy::too_many_lines)]

mod cli;
mod collect;
mod contract;
mod determinism;
mod edit;
mod eval;
mod fidelity;
mod grasping;
mod hardening;
mod history;
mod hostile;
mod ingest;
mod kinematics;
mod layers;
mod lerobot;
mod merge;
mod passthrough;
mod perturb;
mod physics;
mod pointcloud;
mod registry;
mod render;
mod rlds;
mod tasks;
mod util;
mod validate;
