//! RLDS in the TFDS on-disk layout, written without TensorFlow (issue 13; see
//! `../shared/spec/rlds.md`). So far the two encodings every RLDS shard is made of:
//! TFRecord framing with masked CRC-32C ([`tfrecord`]) and `tf.train.Example` ([`example`]),
//! both checked against the spec's test vectors. The sink, source, `dataset_info.json` and
//! `features.json` come next.

pub mod example;
pub mod tfrecord;
