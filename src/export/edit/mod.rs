//! `surgvla edit`: a dataset's episodes kept, dropped, split, renamed and re-labelled in one
//! pass, written in the input's own format with its options ([`crate::export::DatasetFormat::options_like`]),
//! video copied sample for sample (never decoded), statistics recomputed over what is kept,
//! and the files other tools wrote carried over. What is kept and where it goes: [`plan`]
//! (selectors, splits); the episodes as the output gets them: [`picked`]; the run: [`run`].

pub mod picked;
pub mod plan;
pub mod run;

pub use picked::{Changes, Picked, Uncopyable};
pub use plan::{Chosen, Comparison, Selection, Selector, Splits, choose};
pub use run::{DryOutput, DryRun, EditRequest, Output, Planned, dry_run, plan};
