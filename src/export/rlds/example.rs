//! `tf.train.Example`, hand-encoded (RLDS stores one episode per Example): `Example{features =
//! 1}`, `Features{map<string, Feature> feature = 1}` (entries `{key = 1, value = 2}`, written in
//! key order so the bytes are deterministic), `Feature{oneof bytes_list = 1, float_list = 2,
//! int64_list = 3}`; float and int64 lists packed in field 1, bytes repeated in field 1.
//! [`decode_example`] reads the same subset back (for tests and the RLDS source).

use std::collections::BTreeMap;

/// One feature's values.
#[derive(Clone, Debug, PartialEq)]
pub enum Feature {
    Bytes(Vec<Vec<u8>>),
    Float(Vec<f32>),
    Int64(Vec<i64>),
}

const LEN: u64 = 2;
const FIXED32: u64 = 5;

fn varint(out: &mut Vec<u8>, mut value: u64) {
    while value >= 0x80 {
        out.push((value as u8) | 0x80);
        value >>= 7;
    }
    out.push(value as u8);
}

/// Bytes `value` takes as a varint.
fn varint_len(value: u64) -> usize {
    (64 - (value | 1).leading_zeros() as usize).div_ceil(7)
}

/// The tag and length of a length-delimited field whose payload follows.
fn field_header(out: &mut Vec<u8>, number: u64, payload_len: usize) {
    varint(out, (number << 3) | LEN);
    varint(out, payload_len as u64);
}

/// Bytes a length-delimited field of `payload_len` bytes takes.
fn field_len(number: u64, payload_len: usize) -> usize {
    varint_len((number << 3) | LEN) + varint_len(payload_len as u64) + payload_len
}

/// A feature's oneof field number and the length of its list message.
fn list_len(feature: &Feature) -> (u64, usize) {
    match feature {
        Feature::Bytes(values) => (1, values.iter().map(|v| field_len(1, v.len())).sum()),
        Feature::Float(values) if values.is_empty() => (2, 0),
        Feature::Float(values) => (2, field_len(1, 4 * values.len())),
        Feature::Int64(values) if values.is_empty() => (3, 0),
        Feature::Int64(values) => (3, field_len(1, packed_int64_len(values))),
    }
}

fn packed_int64_len(values: &[i64]) -> usize {
    values.iter().map(|v| varint_len(*v as u64)).sum()
}

/// Writes a feature's list message (its values in field 1).
fn write_list(out: &mut Vec<u8>, feature: &Feature) {
    match feature {
        Feature::Bytes(values) => {
            for value in values {
                field_header(out, 1, value.len());
                out.extend_from_slice(value);
            }
        }
        Feature::Float(values) if !values.is_empty() => {
            field_header(out, 1, 4 * values.len());
            for value in values {
                out.extend_from_slice(&value.to_le_bytes());
            }
        }
        Feature::Int64(values) if !values.is_empty() => {
            field_header(out, 1, packed_int64_len(values));
            for value in values {
                varint(out, *value as u64);
            }
        }
        // Empty numeric lists are empty messages.
        Feature::Float(_) | Feature::Int64(_) => {}
    }
}

/// The serialized Example of `features`, written in one pass into a buffer of its exact size
/// (an episode's Example holds all its images: megabytes, not copied from message to message).
pub fn encode_example(features: &BTreeMap<String, Feature>) -> Vec<u8> {
    // (entry length, feature field length, oneof number, list length) per feature.
    let sizes: Vec<(usize, usize, u64, usize)> = features
        .iter()
        .map(|(key, feature)| {
            let (number, list) = list_len(feature);
            let feature_len = field_len(number, list);
            let entry = field_len(1, key.len()) + field_len(2, feature_len);
            (entry, feature_len, number, list)
        })
        .collect();
    let map_len: usize = sizes.iter().map(|(entry, ..)| field_len(1, *entry)).sum();
    let mut out = Vec::with_capacity(field_len(1, map_len));
    field_header(&mut out, 1, map_len);
    for ((key, feature), (entry, feature_len, number, list)) in features.iter().zip(sizes) {
        field_header(&mut out, 1, entry);
        field_header(&mut out, 1, key.len());
        out.extend_from_slice(key.as_bytes());
        field_header(&mut out, 2, feature_len);
        field_header(&mut out, number, list);
        write_list(&mut out, feature);
    }
    out
}

/// A serialized Example that is not what [`encode_example`] writes.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("malformed tf.train.Example: {0}")]
pub struct ExampleError(pub &'static str);

/// Reads protobuf fields: (number, wire type, payload or varint value).
struct Fields<'a> {
    bytes: &'a [u8],
}

enum Value<'a> {
    Varint(u64),
    Bytes(&'a [u8]),
    Fixed32([u8; 4]),
}

fn read_varint(bytes: &mut &[u8]) -> Result<u64, ExampleError> {
    let mut value = 0u64;
    for shift in (0..64).step_by(7) {
        let (&byte, rest) = bytes
            .split_first()
            .ok_or(ExampleError("truncated varint"))?;
        *bytes = rest;
        value |= u64::from(byte & 0x7f) << shift;
        if byte < 0x80 {
            return Ok(value);
        }
    }
    Err(ExampleError("varint too long"))
}

impl<'a> Iterator for Fields<'a> {
    type Item = Result<(u64, Value<'a>), ExampleError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.bytes.is_empty() {
            return None;
        }
        let mut read = || -> Result<(u64, Value<'a>), ExampleError> {
            let tag = read_varint(&mut self.bytes)?;
            let value = match tag & 7 {
                0 => Value::Varint(read_varint(&mut self.bytes)?),
                LEN => {
                    let len = read_varint(&mut self.bytes)? as usize;
                    if len > self.bytes.len() {
                        return Err(ExampleError("field longer than its message"));
                    }
                    let (payload, rest) = self.bytes.split_at(len);
                    self.bytes = rest;
                    Value::Bytes(payload)
                }
                FIXED32 => {
                    if self.bytes.len() < 4 {
                        return Err(ExampleError("truncated fixed32"));
                    }
                    let (payload, rest) = self.bytes.split_at(4);
                    self.bytes = rest;
                    Value::Fixed32([payload[0], payload[1], payload[2], payload[3]])
                }
                _ => return Err(ExampleError("unsupported wire type")),
            };
            Ok((tag >> 3, value))
        };
        Some(read())
    }
}

fn fields(bytes: &[u8]) -> Fields<'_> {
    Fields { bytes }
}

fn decode_feature(bytes: &[u8]) -> Result<Feature, ExampleError> {
    let mut feature = None;
    for item in fields(bytes) {
        let (number, value) = item?;
        let Value::Bytes(list) = value else {
            return Err(ExampleError("a feature's list is not length-delimited"));
        };
        let mut decoded = match number {
            1 => Feature::Bytes(Vec::new()),
            2 => Feature::Float(Vec::new()),
            3 => Feature::Int64(Vec::new()),
            _ => return Err(ExampleError("unknown feature kind")),
        };
        for item in fields(list) {
            match (&mut decoded, item?) {
                (Feature::Bytes(values), (1, Value::Bytes(v))) => values.push(v.to_vec()),
                (Feature::Float(values), (1, Value::Bytes(packed))) => {
                    if packed.len() % 4 != 0 {
                        return Err(ExampleError("packed floats not a multiple of 4 bytes"));
                    }
                    values.extend(
                        packed
                            .chunks_exact(4)
                            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
                    );
                }
                (Feature::Float(values), (1, Value::Fixed32(v))) => {
                    values.push(f32::from_le_bytes(v));
                }
                (Feature::Int64(values), (1, Value::Bytes(mut packed))) => {
                    while !packed.is_empty() {
                        values.push(read_varint(&mut packed)? as i64);
                    }
                }
                (Feature::Int64(values), (1, Value::Varint(v))) => values.push(v as i64),
                _ => return Err(ExampleError("unexpected field in a feature list")),
            }
        }
        feature = Some(decoded);
    }
    feature.ok_or(ExampleError("a feature without a list"))
}

/// The features of a serialized Example.
pub fn decode_example(bytes: &[u8]) -> Result<BTreeMap<String, Feature>, ExampleError> {
    let mut out = BTreeMap::new();
    for item in fields(bytes) {
        let (number, value) = item?;
        let (1, Value::Bytes(map)) = (number, value) else {
            return Err(ExampleError("an Example holds only its features"));
        };
        for entry in fields(map) {
            let (1, Value::Bytes(entry)) = entry? else {
                return Err(ExampleError("Features holds only map entries"));
            };
            let (mut key, mut feature) = (None, None);
            for part in fields(entry) {
                match part? {
                    (1, Value::Bytes(k)) => {
                        key = Some(
                            String::from_utf8(k.to_vec())
                                .map_err(|_| ExampleError("a key that is not UTF-8"))?,
                        );
                    }
                    (2, Value::Bytes(f)) => feature = Some(decode_feature(f)?),
                    _ => return Err(ExampleError("unexpected field in a map entry")),
                }
            }
            let key = key.ok_or(ExampleError("a map entry without a key"))?;
            out.insert(
                key,
                feature.ok_or(ExampleError("a map entry without a value"))?,
            );
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_one_feature_example_has_the_protobuf_bytes() {
        let features = BTreeMap::from([("a".to_string(), Feature::Int64(vec![1]))]);
        assert_eq!(
            encode_example(&features),
            [
                0x0a, 0x0c, 0x0a, 0x0a, 0x0a, 0x01, b'a', 0x12, 0x05, 0x1a, 0x03, 0x0a, 0x01, 0x01
            ]
        );
        let floats = BTreeMap::from([("f".to_string(), Feature::Float(vec![1.0]))]);
        // 1.0f32 = 00 00 80 3f, packed in FloatList field 1.
        assert_eq!(
            encode_example(&floats),
            [
                0x0a, 0x0f, 0x0a, 0x0d, 0x0a, 0x01, b'f', 0x12, 0x08, 0x12, 0x06, 0x0a, 0x04, 0x00,
                0x00, 0x80, 0x3f
            ]
        );
    }

    /// Protobuf's nesting written the plain way: each message built, then copied into its
    /// parent's field.
    fn nested_reference(features: &BTreeMap<String, Feature>) -> Vec<u8> {
        fn field(out: &mut Vec<u8>, number: u64, payload: &[u8]) {
            field_header(out, number, payload.len());
            out.extend_from_slice(payload);
        }
        let mut map = Vec::new();
        for (key, feature) in features {
            let mut list = Vec::new();
            let number = match feature {
                Feature::Bytes(values) => {
                    values.iter().for_each(|v| field(&mut list, 1, v));
                    1
                }
                Feature::Float(values) => {
                    if !values.is_empty() {
                        let packed: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
                        field(&mut list, 1, &packed);
                    }
                    2
                }
                Feature::Int64(values) => {
                    if !values.is_empty() {
                        let mut packed = Vec::new();
                        values.iter().for_each(|v| varint(&mut packed, *v as u64));
                        field(&mut list, 1, &packed);
                    }
                    3
                }
            };
            let mut value = Vec::new();
            field(&mut value, number, &list);
            let mut entry = Vec::new();
            field(&mut entry, 1, key.as_bytes());
            field(&mut entry, 2, &value);
            field(&mut map, 1, &entry);
        }
        let mut out = Vec::new();
        field(&mut out, 1, &map);
        out
    }

    #[test]
    fn the_one_pass_encoder_writes_the_nested_bytes_at_their_exact_size() {
        let mut rng = crate::rng::SplitMix64::new(25);
        for _ in 0..200 {
            let mut features = BTreeMap::new();
            for f in 0..rng.next_u64() % 6 {
                // Lengths crossing the varint boundaries (127/128, 16383/16384).
                let n = [0, 1, 127, 128, 16_383, 16_384][(rng.next_u64() % 6) as usize]
                    / (1 + (rng.next_u64() % 3) as usize);
                let feature = match rng.next_u64() % 3 {
                    0 => Feature::Bytes(
                        (0..rng.next_u64() % 4)
                            .map(|_| vec![rng.next_u64() as u8; n])
                            .collect(),
                    ),
                    1 => Feature::Float((0..n).map(|_| rng.next_f64() as f32).collect()),
                    _ => Feature::Int64(
                        (0..n)
                            .map(|_| (rng.next_u64() >> (rng.next_u64() % 64)) as i64)
                            .collect(),
                    ),
                };
                features.insert(format!("k{f}/{}", "x".repeat(n % 200)), feature);
            }
            let bytes = encode_example(&features);
            assert_eq!(bytes, nested_reference(&features));
            assert_eq!(bytes.len(), bytes.capacity());
            assert_eq!(decode_example(&bytes), Ok(features));
        }
    }

    #[test]
    fn examples_round_trip_with_every_kind_and_empty_lists() {
        let features = BTreeMap::from([
            (
                "steps/observation/image".to_string(),
                Feature::Bytes(vec![b"\x89PNG".to_vec(), Vec::new(), vec![0xff; 300]]),
            ),
            (
                "steps/action".to_string(),
                Feature::Float(vec![0.5, -1.25, 3e-7]),
            ),
            (
                "steps/is_first".to_string(),
                Feature::Int64(vec![1, 0, -5, i64::MAX, i64::MIN]),
            ),
            ("empty/floats".to_string(), Feature::Float(Vec::new())),
            ("empty/ints".to_string(), Feature::Int64(Vec::new())),
            ("empty/bytes".to_string(), Feature::Bytes(Vec::new())),
        ]);
        let bytes = encode_example(&features);
        assert_eq!(decode_example(&bytes), Ok(features));
        assert!(decode_example(&bytes[..bytes.len() - 1]).is_err());
    }
}
