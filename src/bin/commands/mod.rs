//! One file per command (ripgrep's shape): each holds the command's arguments (clap derive)
//! and its `run`, which turns them into library calls and prints the outcome. What a command
//! does with the data (what a conversion reads, what is cleaned up after a failure) is the
//! library's; this file only declares.

pub mod collect;
pub mod contact_sheet;
pub mod convert;
pub mod eval;
pub mod experts;
pub mod info;
pub mod merge;
pub mod record;
pub mod render;
pub mod report;
pub mod schema;
pub mod sim;
pub mod tasks;
pub mod validate;
