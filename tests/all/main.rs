//! The one integration test binary: kinematics, physics, grasping, determinism and the CLI.

mod cli;
mod determinism;
mod grasping;
mod kinematics;
mod lerobot;
mod physics;
mod render;
mod util;
