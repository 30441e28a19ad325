//! Decoding a ROS message's bytes by its definition ([`MessageDefs`]) into a [`RosValue`], in
//! either of ROS's two wire formats ([`Wire`]): ROS 1's (little-endian, packed; strings and
//! sequences a `u32` length then the elements) and ROS 2's CDR (XCDR1: a 4-byte encapsulation
//! header saying the byte order, every primitive aligned to its own size counted from the byte
//! after the header; strings a `u32` length counting a final NUL).
//!
//! The bytes are untrusted: every length is checked against the bytes left before anything is
//! allocated, `uint8` / `int8` arrays (images) are copied in one piece, nesting is bounded, and a
//! message shorter than its definition is an error naming the field, never a panic.

use crate::ingest::msgdef::{Count, Element, Field, MAX_DEPTH, MessageDefs, Primitive};

/// A ROS wire format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wire {
    /// ROS 1 serialisation (bags, `ros1` MCAP channels).
    Ros1,
    /// ROS 2's CDR (`cdr` channels and rosbag2 files), byte order from its header.
    Cdr,
}

/// A decoded value.
#[derive(Clone, Debug, PartialEq)]
pub enum RosValue {
    Bool(bool),
    Int(i64),
    UInt(u64),
    Float(f64),
    String(String),
    /// ROS 1 `time` / `duration`: seconds and nanoseconds.
    Time {
        sec: i64,
        nsec: i64,
    },
    /// A `uint8` / `int8` array (image data, bytes).
    Bytes(Vec<u8>),
    Array(Vec<RosValue>),
    /// A message's fields, in definition order.
    Message(Vec<(String, RosValue)>),
}

impl RosValue {
    /// The field `name` of a message.
    pub fn field(&self, name: &str) -> Option<&RosValue> {
        match self {
            RosValue::Message(fields) => fields.iter().find(|(n, _)| n == name).map(|(_, v)| v),
            _ => None,
        }
    }

    /// The value at a dotted path of fields, e.g. `header.stamp`.
    pub fn at(&self, path: &str) -> Option<&RosValue> {
        path.split('.')
            .try_fold(self, |value, name| value.field(name))
    }

    /// A number as f64.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            RosValue::Float(v) => Some(v),
            RosValue::Int(v) => Some(v as f64),
            RosValue::UInt(v) => Some(v as f64),
            _ => None,
        }
    }

    /// An integer as i64.
    pub fn as_i64(&self) -> Option<i64> {
        match *self {
            RosValue::Int(v) => Some(v),
            RosValue::UInt(v) => i64::try_from(v).ok(),
            _ => None,
        }
    }

    pub fn as_str(&self) -> Option<&str> {
        match self {
            RosValue::String(s) => Some(s),
            _ => None,
        }
    }

    /// Nanoseconds of a time: ROS 1 `time`, or a ROS 2 `builtin_interfaces/Time` message
    /// (`sec`, `nanosec`).
    pub fn as_time_ns(&self) -> Option<i64> {
        let (sec, nsec) = match self {
            RosValue::Time { sec, nsec } => (*sec, *nsec),
            RosValue::Message(_) => (
                self.field("sec")?.as_i64()?,
                self.field("nanosec")?.as_i64()?,
            ),
            _ => return None,
        };
        sec.checked_mul(1_000_000_000)?.checked_add(nsec)
    }
}

/// Bytes that do not decode as their type.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    #[error("{type_name} is not defined")]
    UnknownType { type_name: String },
    #[error("{field} needs {needed} bytes at offset {offset}, the message has {len}")]
    Short {
        field: String,
        needed: u64,
        offset: usize,
        len: usize,
    },
    #[error("{field} is not UTF-8 text")]
    NotText { field: String },
    #[error("CDR encapsulation {0:02x?} is not plain CDR (XCDR1, either byte order)")]
    Encapsulation([u8; 2]),
    #[error("{type_name} nests deeper than {MAX_DEPTH} types")]
    TooDeep { type_name: String },
    #[error("{field}: {count} elements of a type that takes no bytes")]
    Empty { field: String, count: u64 },
    #[error("{field}: more values than the message's bytes can hold")]
    TooManyValues { field: String },
}

/// Elements of a zero-size type a sequence may claim (no bytes bound them).
const MAX_EMPTY_ELEMENTS: u64 = 1 << 16;

/// Decodes `bytes`, a message of `type_name` (`pkg/Type` or ROS 2's `pkg/msg/Type`) in `wire`.
pub fn decode(
    defs: &MessageDefs,
    type_name: &str,
    wire: Wire,
    bytes: &[u8],
) -> Result<RosValue, DecodeError> {
    let (little, body) = body(wire, bytes)?;
    let mut reader = Reader::new(defs, wire, little, body);
    let type_name = crate::ingest::msgdef::full_name(type_name, "");
    let root = FieldPath {
        parent: None,
        name: &type_name,
    };
    reader.message(&type_name, &root, 0)
}

/// The first field of a message of `type_name` only (a `header`, say, without the image
/// after it): what the first pass over a recording reads.
pub fn decode_first_field(
    defs: &MessageDefs,
    type_name: &str,
    wire: Wire,
    bytes: &[u8],
) -> Result<Option<RosValue>, DecodeError> {
    let type_name = crate::ingest::msgdef::full_name(type_name, "");
    let fields = defs
        .fields(&type_name)
        .ok_or_else(|| DecodeError::UnknownType {
            type_name: type_name.clone(),
        })?;
    let Some(first) = fields.first() else {
        return Ok(None);
    };
    let (little, body) = body(wire, bytes)?;
    let mut reader = Reader::new(defs, wire, little, body);
    let path = FieldPath {
        parent: None,
        name: &first.name,
    };
    reader.field(first, &path, 1).map(Some)
}

/// The byte order and the bytes after the CDR header (all of them for ROS 1).
fn body(wire: Wire, bytes: &[u8]) -> Result<(bool, &[u8]), DecodeError> {
    match wire {
        Wire::Ros1 => Ok((true, bytes)),
        Wire::Cdr => {
            let header: [u8; 2] = match bytes {
                [a, b, _, _, ..] => [*a, *b],
                _ => {
                    return Err(DecodeError::Short {
                        field: "the CDR header".into(),
                        needed: 4,
                        offset: 0,
                        len: bytes.len(),
                    });
                }
            };
            match header {
                [0, 1] => Ok((true, &bytes[4..])),
                [0, 0] => Ok((false, &bytes[4..])),
                other => Err(DecodeError::Encapsulation(other)),
            }
        }
    }
}

/// Where a value is in its message (`header.stamp.sec`), for errors only: built on the stack as
/// the reader descends, written out only when something is wrong.
#[derive(Clone, Copy)]
struct FieldPath<'p> {
    parent: Option<&'p FieldPath<'p>>,
    name: &'p str,
}

impl std::fmt::Display for FieldPath<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(parent) = self.parent {
            write!(f, "{parent}.")?;
        }
        f.write_str(self.name)
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    little: bool,
    /// CDR: primitives aligned to their size.
    aligned: bool,
    defs: &'a MessageDefs,
    /// Values still allowed: every value but an empty message takes a byte, so a message of
    /// `n` bytes holds at most `n` + [`MAX_EMPTY_ELEMENTS`] (nested arrays of empty types
    /// cannot multiply past it).
    values_left: u64,
    /// The fewest bytes of each message type, computed once per type.
    least: std::collections::HashMap<String, u64>,
}

impl<'a> Reader<'a> {
    fn new(defs: &'a MessageDefs, wire: Wire, little: bool, bytes: &'a [u8]) -> Self {
        Reader {
            bytes,
            at: 0,
            little,
            aligned: wire == Wire::Cdr,
            defs,
            values_left: bytes.len() as u64 + MAX_EMPTY_ELEMENTS,
            least: std::collections::HashMap::new(),
        }
    }
}

impl Reader<'_> {
    fn message(
        &mut self,
        type_name: &str,
        path: &FieldPath<'_>,
        depth: usize,
    ) -> Result<RosValue, DecodeError> {
        if depth > MAX_DEPTH {
            return Err(DecodeError::TooDeep {
                type_name: type_name.into(),
            });
        }
        let fields = self
            .defs
            .fields(type_name)
            .ok_or_else(|| DecodeError::UnknownType {
                type_name: type_name.into(),
            })?;
        let mut values = Vec::with_capacity(fields.len());
        for field in fields {
            let path = FieldPath {
                parent: (depth > 0).then_some(path),
                name: &field.name,
            };
            values.push((field.name.clone(), self.field(field, &path, depth)?));
        }
        Ok(RosValue::Message(values))
    }

    fn field(
        &mut self,
        field: &Field,
        path: &FieldPath<'_>,
        depth: usize,
    ) -> Result<RosValue, DecodeError> {
        let count = match field.count {
            Count::One => return self.element(&field.element, path, depth),
            Count::Fixed(n) => n as u64,
            Count::Sequence => u64::from(self.u32(path)?),
        };
        if let Element::Primitive(Primitive::U8 | Primitive::I8) = field.element {
            return Ok(RosValue::Bytes(self.take(count, path)?.to_vec()));
        }
        let least = self.least_size(&field.element, 0);
        if least == 0 && count > MAX_EMPTY_ELEMENTS {
            return Err(DecodeError::Empty {
                field: path.to_string(),
                count,
            });
        }
        self.need(count.saturating_mul(least), path)?;
        let mut elements = Vec::with_capacity(count as usize);
        for _ in 0..count {
            elements.push(self.element(&field.element, path, depth)?);
        }
        Ok(RosValue::Array(elements))
    }

    fn element(
        &mut self,
        element: &Element,
        path: &FieldPath<'_>,
        depth: usize,
    ) -> Result<RosValue, DecodeError> {
        self.values_left =
            self.values_left
                .checked_sub(1)
                .ok_or_else(|| DecodeError::TooManyValues {
                    field: path.to_string(),
                })?;
        match element {
            Element::Message(name) => self.message(name, path, depth + 1),
            Element::Primitive(primitive) => self.primitive(*primitive, path),
        }
    }

    /// The fewest bytes one element takes (what bounds a sequence's count), each message type
    /// computed once; 0 past the deepest nesting decoded.
    fn least_size(&mut self, element: &Element, depth: usize) -> u64 {
        let name = match element {
            Element::Primitive(p) => return p.size() as u64,
            Element::Message(_) if depth > MAX_DEPTH => return 0,
            Element::Message(name) => name,
        };
        if let Some(&least) = self.least.get(name) {
            return least;
        }
        let defs = self.defs;
        let least = defs.fields(name).map_or(0, |fields| {
            fields
                .iter()
                .map(|f| match f.count {
                    Count::Sequence => 4,
                    Count::Fixed(n) => {
                        (n as u64).saturating_mul(self.least_size(&f.element, depth + 1))
                    }
                    Count::One => self.least_size(&f.element, depth + 1),
                })
                .fold(0u64, u64::saturating_add)
        });
        self.least.insert(name.clone(), least);
        least
    }

    fn primitive(
        &mut self,
        primitive: Primitive,
        path: &FieldPath<'_>,
    ) -> Result<RosValue, DecodeError> {
        Ok(match primitive {
            Primitive::Bool => RosValue::Bool(self.fixed::<1>(path)?[0] != 0),
            Primitive::I8 => RosValue::Int(i64::from(self.fixed::<1>(path)?[0] as i8)),
            Primitive::U8 => RosValue::UInt(u64::from(self.fixed::<1>(path)?[0])),
            Primitive::I16 => RosValue::Int(i64::from(i16::from_le_bytes(self.ordered(path)?))),
            Primitive::U16 => RosValue::UInt(u64::from(u16::from_le_bytes(self.ordered(path)?))),
            Primitive::I32 => RosValue::Int(i64::from(i32::from_le_bytes(self.ordered(path)?))),
            Primitive::U32 => RosValue::UInt(u64::from(self.u32(path)?)),
            Primitive::I64 => RosValue::Int(i64::from_le_bytes(self.ordered(path)?)),
            Primitive::U64 => RosValue::UInt(u64::from_le_bytes(self.ordered(path)?)),
            Primitive::F32 => RosValue::Float(f64::from(f32::from_le_bytes(self.ordered(path)?))),
            Primitive::F64 => RosValue::Float(f64::from_le_bytes(self.ordered(path)?)),
            Primitive::String => RosValue::String(self.string(path)?),
            Primitive::Time => {
                let sec = u32::from_le_bytes(self.ordered(path)?);
                let nsec = u32::from_le_bytes(self.ordered(path)?);
                RosValue::Time {
                    sec: i64::from(sec),
                    nsec: i64::from(nsec),
                }
            }
            Primitive::Duration => {
                let sec = i32::from_le_bytes(self.ordered(path)?);
                let nsec = i32::from_le_bytes(self.ordered(path)?);
                RosValue::Time {
                    sec: i64::from(sec),
                    nsec: i64::from(nsec),
                }
            }
        })
    }

    fn string(&mut self, path: &FieldPath<'_>) -> Result<String, DecodeError> {
        let len = u64::from(self.u32(path)?);
        let cdr = self.aligned;
        let bytes = self.take(len, path)?;
        // CDR counts a final NUL; ROS 1 does not (a NUL inside is kept as text).
        let text = if cdr {
            bytes.strip_suffix(&[0]).unwrap_or(bytes)
        } else {
            bytes
        };
        String::from_utf8(text.to_vec()).map_err(|_| DecodeError::NotText {
            field: path.to_string(),
        })
    }

    fn u32(&mut self, path: &FieldPath<'_>) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(self.ordered(path)?))
    }

    /// `N` bytes of a primitive of size `N`, aligned (CDR), as little-endian.
    fn ordered<const N: usize>(&mut self, path: &FieldPath<'_>) -> Result<[u8; N], DecodeError> {
        if self.aligned {
            let pad = (N - self.at % N) % N;
            self.take(pad as u64, path)?;
        }
        let mut bytes = self.fixed::<N>(path)?;
        if !self.little {
            bytes.reverse();
        }
        Ok(bytes)
    }

    fn fixed<const N: usize>(&mut self, path: &FieldPath<'_>) -> Result<[u8; N], DecodeError> {
        let bytes = self.take(N as u64, path)?;
        let mut out = [0u8; N];
        out.copy_from_slice(bytes);
        Ok(out)
    }

    fn need(&self, count: u64, path: &FieldPath<'_>) -> Result<(), DecodeError> {
        let left = (self.bytes.len() - self.at) as u64;
        if count > left {
            return Err(DecodeError::Short {
                field: path.to_string(),
                needed: count,
                offset: self.at,
                len: self.bytes.len(),
            });
        }
        Ok(())
    }

    fn take(&mut self, count: u64, path: &FieldPath<'_>) -> Result<&[u8], DecodeError> {
        self.need(count, path)?;
        let start = self.at;
        self.at += count as usize;
        Ok(&self.bytes[start..self.at])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn defs() -> MessageDefs {
        let text = "std_msgs/Header header\nuint32 height\nstring encoding\nfloat64 x\nuint8[] data\nint16[2] pair\n================================================================================\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n================================================================================\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";
        MessageDefs::parse("t/Msg", text).expect("defs")
    }

    /// The message above in CDR, little-endian, as a ROS 2 writer lays it out.
    fn cdr() -> Vec<u8> {
        let mut b = vec![0, 1, 0, 0];
        b.extend(7i32.to_le_bytes()); // stamp.sec (offset 0)
        b.extend(500u32.to_le_bytes()); // stamp.nanosec (4)
        b.extend(4u32.to_le_bytes()); // frame_id length with NUL (8)
        b.extend(b"cam\0"); // (12)
        b.extend(480u32.to_le_bytes()); // height (16)
        b.extend(5u32.to_le_bytes()); // encoding (20)
        b.extend(b"rgb8\0"); // (24..29)
        b.extend([0, 0, 0]); // pad to 32 for the float64
        b.extend(1.5f64.to_le_bytes()); // x (32)
        b.extend(3u32.to_le_bytes()); // data count (40)
        b.extend([9, 8, 7]); // (44..47)
        b.extend([0]); // pad to 48 for int16
        b.extend(3i16.to_le_bytes());
        b.extend((-4i16).to_le_bytes());
        b
    }

    #[test]
    fn cdr_little_endian_with_alignment() {
        let value = decode(&defs(), "t/Msg", Wire::Cdr, &cdr()).expect("decode");
        assert_eq!(
            value.at("header.stamp").and_then(RosValue::as_time_ns),
            Some(7_000_000_500)
        );
        assert_eq!(
            value.at("header.frame_id").and_then(RosValue::as_str),
            Some("cam")
        );
        assert_eq!(
            value.at("encoding").and_then(RosValue::as_str),
            Some("rgb8")
        );
        assert_eq!(value.at("x").and_then(RosValue::as_f64), Some(1.5));
        assert_eq!(value.at("data"), Some(&RosValue::Bytes(vec![9, 8, 7])));
        assert_eq!(
            value.at("pair"),
            Some(&RosValue::Array(vec![RosValue::Int(3), RosValue::Int(-4)]))
        );
    }

    #[test]
    fn cdr_big_endian() {
        let text = "uint16 a\nfloat64 b\nstring s\n";
        let defs = MessageDefs::parse("t/B", text).expect("defs");
        let mut b = vec![0, 0, 0, 0];
        b.extend(513u16.to_be_bytes());
        b.extend([0; 6]);
        b.extend((-2.25f64).to_be_bytes());
        b.extend(2u32.to_be_bytes());
        b.extend(b"a\0");
        let value = decode(&defs, "t/B", Wire::Cdr, &b).expect("decode");
        assert_eq!(value.at("a"), Some(&RosValue::UInt(513)));
        assert_eq!(value.at("b"), Some(&RosValue::Float(-2.25)));
        assert_eq!(value.at("s").and_then(RosValue::as_str), Some("a"));
    }

    #[test]
    fn ros1_packed() {
        let text = "uint32 seq\ntime stamp\nstring frame_id\nfloat64[] v\n";
        let defs = MessageDefs::parse("t/R", text).expect("defs");
        let mut b = Vec::new();
        b.extend(1u32.to_le_bytes());
        b.extend(10u32.to_le_bytes());
        b.extend(20u32.to_le_bytes());
        b.extend(2u32.to_le_bytes());
        b.extend(b"ab");
        b.extend(1u32.to_le_bytes());
        b.extend(0.5f64.to_le_bytes());
        let value = decode(&defs, "t/R", Wire::Ros1, &b).expect("decode");
        assert_eq!(
            value.at("stamp").and_then(RosValue::as_time_ns),
            Some(10_000_000_020)
        );
        assert_eq!(value.at("frame_id").and_then(RosValue::as_str), Some("ab"));
        assert_eq!(
            value.at("v"),
            Some(&RosValue::Array(vec![RosValue::Float(0.5)]))
        );
    }

    #[test]
    fn truncated_and_hostile_bytes_are_errors_naming_the_field() {
        let bytes = cdr();
        for cut in 0..bytes.len() {
            let error = decode(&defs(), "t/Msg", Wire::Cdr, &bytes[..cut]).expect_err("short");
            assert!(error.to_string().contains("bytes"), "{error}");
        }
        // A sequence claiming four billion elements allocates nothing.
        let defs = MessageDefs::parse("t/S", "float64[] v\n").expect("defs");
        let error = decode(&defs, "t/S", Wire::Ros1, &u32::MAX.to_le_bytes()).expect_err("huge");
        assert!(error.to_string().contains("v needs"), "{error}");
        let empty = MessageDefs::parse(
            "t/E",
            "t/Z[] z\n================================================================================\nMSG: t/Z\n",
        )
        .expect("defs");
        let error = decode(&empty, "t/E", Wire::Ros1, &u32::MAX.to_le_bytes()).expect_err("empty");
        assert!(matches!(error, DecodeError::Empty { .. }), "{error}");
        assert!(matches!(
            decode(&empty, "t/E", Wire::Cdr, &[0, 7, 0, 0]),
            Err(DecodeError::Encapsulation([0, 7]))
        ));
        let text = MessageDefs::parse("t/T", "string s\n").expect("defs");
        let mut b = 2u32.to_le_bytes().to_vec();
        b.extend([0xff, 0xfe]);
        assert!(matches!(
            decode(&text, "t/T", Wire::Ros1, &b),
            Err(DecodeError::NotText { .. })
        ));
    }

    #[test]
    fn nested_arrays_of_empty_types_and_wide_type_trees_stay_bounded() {
        // 60,000 x 60,000 empty elements: refused by the value budget, not looped through.
        let sep =
            "\n================================================================================\n";
        let text = format!("t/Y[60000] y{sep}MSG: t/Y\nt/E[60000] e{sep}MSG: t/E\n");
        let defs = MessageDefs::parse("t/Z", &text).expect("defs");
        let error = decode(&defs, "t/Z", Wire::Ros1, &[]).expect_err("budget");
        assert!(
            matches!(error, DecodeError::TooManyValues { .. }),
            "{error}"
        );
        // 30 types of 200 fields each naming the next: sizes are computed once per type.
        let mut text = String::new();
        for level in 0..30 {
            if level > 0 {
                text.push_str(&format!("{sep}MSG: t/L{level}\n"));
            }
            for f in 0..200 {
                text.push_str(&format!("t/L{} f{f}\n", level + 1));
            }
        }
        text.push_str(&format!("{sep}MSG: t/L30\nuint8 v\n"));
        let defs = MessageDefs::parse("t/L0", &text).expect("defs");
        assert!(decode(&defs, "t/L0", Wire::Ros1, &[0; 16]).is_err());
    }

    #[test]
    fn seeded_random_bytes_never_panic() {
        let defs = defs();
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let good = cdr();
        for _ in 0..2000 {
            let bytes = crate::ingest::fixtures::corrupted(&good, &mut state, 4);
            let _ = decode(&defs, "t/Msg", Wire::Cdr, &bytes);
            let _ = decode(&defs, "t/Msg", Wire::Ros1, &bytes);
        }
    }
}
