//! openpi's msgpack-numpy encoding, written from its description: a message is a msgpack map
//! with string keys; an array is a map with the *binary* keys `__ndarray__` (true), `data` (the
//! raw little-endian bytes), `dtype` (numpy's `dtype.str`, e.g. "<f4", "|u1") and `shape` (an
//! array of integers). `openpi_client.msgpack_numpy.unpackb` turns such a map into an
//! `np.ndarray` and string keys into `str`.
//!
//! The request is built here ([`Request`]); the reply is checked here ([`decode_actions`]): a map
//! with an `actions` array of shape (7,) or (H, 7), float32 or float64, every value finite.

use rmpv::Value;

/// One request: the fields in the order they are sent.
#[derive(Clone, Debug, Default)]
pub struct Request {
    fields: Vec<(Value, Value)>,
}

impl Request {
    /// A uint8 array (`|u1`).
    pub fn u8_array(mut self, key: &str, data: &[u8], shape: &[usize]) -> Self {
        self.fields
            .push((key.into(), ndarray(data.to_vec(), "|u1", shape)));
        self
    }

    /// A little-endian float32 array (`<f4`).
    pub fn f32_array(mut self, key: &str, data: &[f32], shape: &[usize]) -> Self {
        let bytes = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.fields.push((key.into(), ndarray(bytes, "<f4", shape)));
        self
    }

    /// A string.
    pub fn text(mut self, key: &str, value: &str) -> Self {
        self.fields.push((key.into(), value.into()));
        self
    }

    /// The msgpack bytes.
    pub fn encode(self) -> Vec<u8> {
        let mut bytes = Vec::new();
        // Writing into a Vec cannot fail.
        let _ = rmpv::encode::write_value(&mut bytes, &Value::Map(self.fields));
        bytes
    }
}

fn ndarray(data: Vec<u8>, dtype: &str, shape: &[usize]) -> Value {
    Value::Map(vec![
        (Value::Binary(b"__ndarray__".to_vec()), Value::Boolean(true)),
        (Value::Binary(b"data".to_vec()), Value::Binary(data)),
        (Value::Binary(b"dtype".to_vec()), dtype.into()),
        (
            Value::Binary(b"shape".to_vec()),
            Value::Array(shape.iter().map(|&n| Value::from(n as u64)).collect()),
        ),
    ])
}

/// What is wrong with a policy server's reply.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReplyError {
    #[error("the reply is not msgpack ({0})")]
    NotMsgpack(String),
    #[error("the reply is not a map but {0}")]
    NotAMap(String),
    #[error("the reply has no \"actions\" key (keys: {0})")]
    MissingActions(String),
    #[error("\"actions\" is not a numpy array ({0})")]
    NotAnArray(String),
    #[error("\"actions\" has dtype {0}; expected float32 (\"<f4\") or float64 (\"<f8\")")]
    Dtype(String),
    #[error(
        "\"actions\" has shape {0:?}; expected (7,) or (H, 7) with 1 <= H <= {MAX_ACTION_ROWS}"
    )]
    Shape(Vec<u64>),
    #[error("\"actions\" holds {got} bytes; shape and dtype need {expected}")]
    Length { got: usize, expected: usize },
    #[error("\"actions\" value [{row}, {column}] is {value}, not a finite number")]
    NotFinite {
        row: usize,
        column: usize,
        value: f64,
    },
}

/// Looks a key up in a msgpack map, whether it was sent as a string or as bytes.
fn get<'a>(map: &'a [(Value, Value)], key: &str) -> Option<&'a Value> {
    map.iter().find_map(|(k, v)| {
        let matches = match k {
            Value::String(s) => s.as_str() == Some(key),
            Value::Binary(b) => b.as_slice() == key.as_bytes(),
            _ => false,
        };
        matches.then_some(v)
    })
}

fn key_names(map: &[(Value, Value)]) -> String {
    let names: Vec<String> = map
        .iter()
        .map(|(k, _)| match k {
            Value::String(s) => s.as_str().unwrap_or("?").to_string(),
            Value::Binary(b) => String::from_utf8_lossy(b).into_owned(),
            other => other.to_string(),
        })
        .collect();
    if names.is_empty() {
        "none".into()
    } else {
        names.join(", ")
    }
}

fn type_name(value: &Value) -> String {
    match value {
        Value::Nil => "nil",
        Value::Boolean(_) => "a boolean",
        Value::Integer(_) => "an integer",
        Value::F32(_) | Value::F64(_) => "a float",
        Value::String(_) => "a string",
        Value::Binary(_) => "bytes",
        Value::Array(_) => "a list",
        Value::Map(_) => "a map",
        Value::Ext(..) => "an extension value",
    }
    .into()
}

/// The action chunk of a reply: one or more 7-D actions.
/// The longest action chunk accepted (openpi's models send 10 to 50 actions).
pub const MAX_ACTION_ROWS: u64 = 10_000;

pub fn decode_actions(bytes: &[u8]) -> Result<Vec<[f32; 7]>, ReplyError> {
    let value = parse(bytes)?;
    let Value::Map(map) = &value else {
        return Err(ReplyError::NotAMap(type_name(&value)));
    };
    let actions = get(map, "actions").ok_or_else(|| ReplyError::MissingActions(key_names(map)))?;
    let Value::Map(array) = actions else {
        return Err(ReplyError::NotAnArray(type_name(actions)));
    };
    if !matches!(get(array, "__ndarray__"), Some(Value::Boolean(true))) {
        return Err(ReplyError::NotAnArray(format!(
            "a map without __ndarray__ (keys: {})",
            key_names(array)
        )));
    }
    let field = |name: &str| {
        get(array, name).ok_or_else(|| ReplyError::NotAnArray(format!("no {name} field")))
    };
    let dtype = match field("dtype")? {
        Value::String(s) => s.as_str().unwrap_or_default().to_string(),
        Value::Binary(b) => String::from_utf8_lossy(b).into_owned(),
        other => return Err(ReplyError::Dtype(type_name(other))),
    };
    let width = match dtype.as_str() {
        "<f4" => 4,
        "<f8" => 8,
        _ => return Err(ReplyError::Dtype(format!("{dtype:?}"))),
    };
    let shape: Vec<u64> = match field("shape")? {
        Value::Array(dims) => dims
            .iter()
            .map(|d| d.as_u64().ok_or_else(|| ReplyError::Shape(Vec::new())))
            .collect::<Result<_, _>>()?,
        _ => return Err(ReplyError::Shape(Vec::new())),
    };
    let rows = match shape.as_slice() {
        [7] => 1,
        // Checked before anything is sized from it: a reply may claim any shape.
        [h, 7] if (1..=MAX_ACTION_ROWS).contains(h) => *h as usize,
        _ => return Err(ReplyError::Shape(shape)),
    };
    let Value::Binary(data) = field("data")? else {
        return Err(ReplyError::NotAnArray("data is not bytes".into()));
    };
    let expected = rows * 7 * width;
    if data.len() != expected {
        return Err(ReplyError::Length {
            got: data.len(),
            expected,
        });
    }
    let mut chunk = Vec::with_capacity(rows);
    for (row, bytes) in data.chunks_exact(7 * width).enumerate() {
        let mut action = [0f32; 7];
        for (column, value) in bytes.chunks_exact(width).enumerate() {
            let value = match *value {
                [a, b, c, d] => f64::from(f32::from_le_bytes([a, b, c, d])),
                [a, b, c, d, e, f, g, h] => f64::from_le_bytes([a, b, c, d, e, f, g, h]),
                _ => return Err(ReplyError::Dtype(format!("{dtype:?}"))),
            };
            if !value.is_finite() {
                return Err(ReplyError::NotFinite { row, column, value });
            }
            action[column] = value as f32;
        }
        chunk.push(action);
    }
    Ok(chunk)
}

fn parse(bytes: &[u8]) -> Result<Value, ReplyError> {
    let mut reader = bytes;
    let value =
        rmpv::decode::read_value(&mut reader).map_err(|e| ReplyError::NotMsgpack(e.to_string()))?;
    if !reader.is_empty() {
        return Err(ReplyError::NotMsgpack(format!(
            "{} bytes after the message",
            reader.len()
        )));
    }
    Ok(value)
}

/// The server's metadata message as JSON (arrays summarised by dtype and shape), for the
/// results; anything unreadable becomes a string saying so.
pub fn metadata_json(bytes: &[u8]) -> serde_json::Value {
    match parse(bytes) {
        Ok(value) => to_json(&value),
        Err(e) => serde_json::Value::String(e.to_string()),
    }
}

fn to_json(value: &Value) -> serde_json::Value {
    use serde_json::Value as J;
    match value {
        Value::Nil => J::Null,
        Value::Boolean(b) => J::Bool(*b),
        Value::Integer(i) => i
            .as_i64()
            .map(J::from)
            .or_else(|| i.as_u64().map(J::from))
            .unwrap_or(J::Null),
        Value::F32(f) => J::from(f64::from(*f)),
        Value::F64(f) => J::from(*f),
        Value::String(s) => J::String(s.as_str().unwrap_or_default().to_string()),
        Value::Binary(b) => J::String(format!("<{} bytes>", b.len())),
        Value::Array(items) => J::Array(items.iter().map(to_json).collect()),
        Value::Map(map) => {
            if matches!(get(map, "__ndarray__"), Some(Value::Boolean(true))) {
                return serde_json::json!({
                    "dtype": get(map, "dtype").map(to_json),
                    "shape": get(map, "shape").map(to_json),
                });
            }
            J::Object(
                map.iter()
                    .map(|(k, v)| {
                        let key = match k {
                            Value::String(s) => s.as_str().unwrap_or_default().to_string(),
                            Value::Binary(b) => String::from_utf8_lossy(b).into_owned(),
                            other => other.to_string(),
                        };
                        (key, to_json(v))
                    })
                    .collect(),
            )
        }
        Value::Ext(..) => J::String("<msgpack extension>".into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reply(dtype: &str, shape: &[usize], data: Vec<u8>) -> Vec<u8> {
        let value = Value::Map(vec![("actions".into(), ndarray(data, dtype, shape))]);
        let mut bytes = Vec::new();
        rmpv::encode::write_value(&mut bytes, &value).expect("encode");
        bytes
    }

    fn f32_bytes(values: &[f32]) -> Vec<u8> {
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    #[test]
    fn a_chunk_and_a_single_action_decode() {
        let values: Vec<f32> = (0..14).map(|i| i as f32 * 0.5).collect();
        let chunk = decode_actions(&reply("<f4", &[2, 7], f32_bytes(&values))).expect("chunk");
        assert_eq!(chunk.len(), 2);
        assert_eq!(chunk[1][6], 6.5);
        let doubles: Vec<u8> = (0..7).flat_map(|i| (i as f64).to_le_bytes()).collect();
        let single = decode_actions(&reply("<f8", &[7], doubles)).expect("single");
        assert_eq!(single, vec![[0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0]]);
    }

    #[test]
    fn malformed_replies_say_what_is_wrong() {
        let seven = f32_bytes(&[0.0; 7]);
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (reply("<f4", &[6], f32_bytes(&[0.0; 6])), "shape [6]"),
            (reply("<f4", &[0, 7], Vec::new()), "shape [0, 7]"),
            (
                reply("<f4", &[1 << 62, 7], Vec::new()),
                "shape [4611686018427387904, 7]",
            ),
            (reply("<i4", &[7], seven.clone()), "dtype \"<i4\""),
            (reply("<f4", &[2, 7], seven.clone()), "holds 28 bytes"),
            (
                reply("<f4", &[7], f32_bytes(&[0.0, f32::NAN, 0., 0., 0., 0., 0.])),
                "[0, 1] is NaN",
            ),
            (vec![0x92, 0x01], "not msgpack"),
            (vec![0x01], "not a map but an integer"),
        ];
        for (bytes, expected) in cases {
            let error = decode_actions(&bytes).expect_err(expected).to_string();
            assert!(error.contains(expected), "{error} lacks {expected}");
        }
        let mut no_actions = Vec::new();
        let value = Value::Map(vec![("action".into(), Value::Nil)]);
        rmpv::encode::write_value(&mut no_actions, &value).expect("encode");
        let error = decode_actions(&no_actions)
            .expect_err("missing")
            .to_string();
        assert!(
            error.contains("no \"actions\" key (keys: action)"),
            "{error}"
        );
    }

    #[test]
    fn a_request_has_string_keys_and_binary_array_keys() {
        let bytes = Request::default()
            .u8_array("observation/image", &[1, 2, 3], &[1, 1, 3])
            .f32_array("observation/state", &[1.5], &[1])
            .text("prompt", "pick up the gauze")
            .encode();
        let Value::Map(map) = parse(&bytes).expect("msgpack") else {
            panic!("a map")
        };
        assert_eq!(
            key_names(&map),
            "observation/image, observation/state, prompt"
        );
        assert!(matches!(map[0].0, Value::String(_)));
        let Value::Map(image) = &map[0].1 else {
            panic!("an array map")
        };
        assert!(image.iter().all(|(k, _)| matches!(k, Value::Binary(_))));
        assert_eq!(get(image, "dtype"), Some(&Value::from("|u1")));
        let Value::Map(state) = &map[1].1 else {
            panic!("an array map")
        };
        assert_eq!(
            get(state, "data"),
            Some(&Value::Binary(1.5f32.to_le_bytes().to_vec()))
        );
        let json = metadata_json(&bytes);
        assert_eq!(
            json["observation/image"]["shape"],
            serde_json::json!([1, 1, 3])
        );
        assert_eq!(json["prompt"], "pick up the gauze");
    }
}
