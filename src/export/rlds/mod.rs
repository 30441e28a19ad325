//! RLDS in the TFDS on-disk layout, written without TensorFlow (docs/datasets.md, "The RLDS
//! dataset"): [`RldsWriter`] (an [`crate::export::EpisodeSink`]) and [`read::RldsSource`].
//!
//! Layout, in the output folder (TFDS's `data_dir`):
//! ```text
//! <name>/<version>/dataset_info.json                   name, version, shardLengths (checked)
//! <name>/<version>/features.json                       the feature tree readers decode with
//! <name>/<version>/<name>-train.tfrecord-NNNNN-of-MMMMM  one tf.train.Example per episode
//! <name>/<version>/surgvla.json                        camera, mask ids, collection, RLDS keys
//! OPENVLA.md                                           how to fine-tune OpenVLA on it
//! surgvla_manifest.json                                every file with size and CRC-32C
//! ```
//! The split is `train`, or the one split the dataset's metadata names (`edit --split` writes
//! one dataset per split): [`options::tfds_split`]; readers take `train`, else the only split.
//! Shards roll once they reach [`RldsOptions::shard_size_mb`] (TFDS sizes shards from 64 MiB
//! up) and are written as `<name>-train.tfrecord-NNNNN` until the run finishes: only then is
//! the count `MMMMM` known, and [`crate::export::DatasetDir::rename_files`] gives them their final names (a
//! resume after an interruption there undoes the renames first). Every closed shard is a
//! checkpoint. Encodings: TFRecord framing with masked CRC-32C ([`tfrecord`]),
//! `tf.train.Example` ([`example`]), episodes ([`record`]), metadata ([`features`]).

pub mod check;
pub mod example;
pub mod features;
pub mod foreign;
mod format;
pub mod generic;
pub mod mapping;
pub mod merge;
mod openvla;
mod options;
pub mod read;
pub mod record;
pub mod tfrecord;
mod writer;

pub use foreign::open_any;
pub use format::RldsFormat;
pub use openvla::openvla_md;
pub use options::{MANIFEST, OPENVLA_GUIDE, RldsKeys, RldsOptions, SURGVLA_JSON, rlds_path};
pub use writer::{RldsShards, RldsWriter, State};
