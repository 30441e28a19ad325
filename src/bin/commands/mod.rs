//! One file per command (ripgrep's shape): each holds the command's arguments (clap derive)
//! and its `run`, which turns them into library calls and prints the outcome. What a command
//! does with the data (what a conversion reads, what is cleaned up after a failure) is the
//! library's; this file only declares.

pub(crate) mod collect;
pub(crate) mod contact_sheet;
pub(crate) mod convert;
pub(crate) mod edit;
pub(crate) mod eval;
pub(crate) mod experts;
pub(crate) mod info;
pub(crate) mod ingest;
pub(crate) mod merge;
pub(crate) mod record;
pub(crate) mod render;
pub(crate) mod report;
pub(crate) mod schema;
pub(crate) mod sim;
pub(crate) mod tasks;
pub(crate) mod validate;
