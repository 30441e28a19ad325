//! ROS message definitions: the text a bag carries for each type (a ROS 1 connection's
//! `message_definition`, an MCAP schema of encoding `ros1msg` or `ros2msg`, a rosbag2
//! `message_definitions` row) parsed into [`MessageDefs`], the field layout the decoder
//! ([`crate::ingest::decode`]) walks.
//!
//! The text is the type's own fields, then each type it uses after a line of 80 `=` and a line
//! `MSG: pkg/Type`. A field is `TYPE NAME` (comments after `#`; `TYPE NAME=VALUE` is a constant
//! and takes no bytes); `TYPE` is a primitive, `pkg/Type` (ROS 2 also `pkg/msg/Type`), a bare
//! `Type` of the same package, or `Header` (`std_msgs/Header`), with `[]` (a sequence), `[N]` (a
//! fixed array) or `[<=N]` (a bounded sequence) after it. Definitions are untrusted: their
//! size, field count and nesting are bounded, and a type that contains itself is refused.

use std::collections::BTreeMap;

/// The largest definition text read.
pub const MAX_DEFINITION_BYTES: usize = 1 << 20;
/// The most fields one type may have.
pub const MAX_FIELDS: usize = 4096;
/// The deepest nesting of types decoded (a self-containing type is refused before this).
pub const MAX_DEPTH: usize = 32;

/// A problem in a message definition.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DefinitionError {
    #[error("the definition of {type_name} is over {MAX_DEFINITION_BYTES} bytes")]
    TooLarge { type_name: String },
    #[error("the definition of {type_name}, line {line}: {problem}")]
    Line {
        type_name: String,
        line: usize,
        problem: String,
    },
    #[error("{type_name} uses {missing}, which its definition does not include")]
    Missing { type_name: String, missing: String },
    #[error("{type_name} contains itself (through {through})")]
    Recursive { type_name: String, through: String },
}

/// A primitive ROS type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Primitive {
    Bool,
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
    String,
    /// ROS 1 `time` (u32 sec, u32 nsec); ROS 2's is the message `builtin_interfaces/Time`.
    Time,
    /// ROS 1 `duration` (i32 sec, i32 nsec).
    Duration,
}

impl Primitive {
    fn parse(name: &str) -> Option<Primitive> {
        Some(match name {
            "bool" => Primitive::Bool,
            "int8" => Primitive::I8,
            // ROS 1's `byte` is signed in the docs but written as uint8 by every tool; `char`
            // is uint8.
            "uint8" | "byte" | "char" => Primitive::U8,
            "int16" => Primitive::I16,
            "uint16" => Primitive::U16,
            "int32" => Primitive::I32,
            "uint32" => Primitive::U32,
            "int64" => Primitive::I64,
            "uint64" => Primitive::U64,
            "float32" => Primitive::F32,
            "float64" => Primitive::F64,
            "string" | "wstring" => Primitive::String,
            "time" => Primitive::Time,
            "duration" => Primitive::Duration,
            _ => return None,
        })
    }

    /// Its size in bytes (a string's length prefix for strings).
    pub fn size(self) -> usize {
        match self {
            Primitive::Bool | Primitive::I8 | Primitive::U8 => 1,
            Primitive::I16 | Primitive::U16 => 2,
            Primitive::I32 | Primitive::U32 | Primitive::F32 | Primitive::String => 4,
            Primitive::I64 | Primitive::U64 | Primitive::F64 => 8,
            Primitive::Time | Primitive::Duration => 8,
        }
    }
}

/// A field's element type.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Element {
    Primitive(Primitive),
    /// A message type, by its full name `pkg/Type`.
    Message(String),
}

/// How many elements a field holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Count {
    One,
    /// `T[N]`: exactly N, no length written.
    Fixed(usize),
    /// `T[]` or `T[<=N]`: a length, then that many.
    Sequence,
}

/// One field of a message type.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Field {
    pub name: String,
    pub element: Element,
    pub count: Count,
}

/// Message types by full name (`pkg/Type`), each its fields in order.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MessageDefs {
    types: BTreeMap<String, Vec<Field>>,
}

/// `pkg/msg/Type` -> `pkg/Type`; a bare `Type` -> `package/Type`; `Header` -> `std_msgs/Header`.
pub fn full_name(name: &str, package: &str) -> String {
    let parts: Vec<&str> = name.split('/').collect();
    match parts.as_slice() {
        [pkg, "msg", ty] => format!("{pkg}/{ty}"),
        [pkg, ty] => format!("{pkg}/{ty}"),
        ["Header"] => "std_msgs/Header".into(),
        [ty] => format!("{package}/{ty}"),
        _ => name.to_string(),
    }
}

impl MessageDefs {
    /// The types of `text`, the definition of `type_name` with its dependencies.
    pub fn parse(type_name: &str, text: &str) -> Result<MessageDefs, DefinitionError> {
        let mut defs = MessageDefs::default();
        defs.add(type_name, text)?;
        defs.check(&full_name(type_name, ""))?;
        Ok(defs)
    }

    /// Adds the types of `text` (the definition of `type_name` and its dependencies); a type
    /// already known keeps its first definition.
    pub fn add(&mut self, type_name: &str, text: &str) -> Result<(), DefinitionError> {
        let main = full_name(type_name, "");
        if text.len() > MAX_DEFINITION_BYTES {
            return Err(DefinitionError::TooLarge { type_name: main });
        }
        let mut current = main.clone();
        let mut lines: Vec<(usize, &str)> = Vec::new();
        let mut sections: Vec<(String, Vec<(usize, &str)>)> = Vec::new();
        for (number, line) in text.lines().enumerate() {
            let trimmed = line.trim();
            if trimmed.len() >= 3 && trimmed.chars().all(|c| c == '=') {
                sections.push((std::mem::take(&mut current), std::mem::take(&mut lines)));
                continue;
            }
            if let Some(name) = trimmed.strip_prefix("MSG:") {
                current = full_name(name.trim(), "");
                continue;
            }
            lines.push((number + 1, line));
        }
        sections.push((current, lines));
        for (name, lines) in sections {
            if name.is_empty() || self.types.contains_key(&name) {
                continue;
            }
            let package = name.split('/').next().unwrap_or_default().to_string();
            let mut fields = Vec::new();
            for (number, line) in lines {
                let bad = |problem: String| DefinitionError::Line {
                    type_name: name.clone(),
                    line: number,
                    problem,
                };
                if let Some(field) = parse_field(line, &package).map_err(bad)? {
                    if fields.len() == MAX_FIELDS {
                        return Err(bad(format!("more than {MAX_FIELDS} fields")));
                    }
                    fields.push(field);
                }
            }
            self.types.insert(name, fields);
        }
        Ok(())
    }

    /// The fields of `type_name` (a full name), if known.
    pub fn fields(&self, type_name: &str) -> Option<&[Field]> {
        self.types.get(type_name).map(Vec::as_slice)
    }

    /// Whether `type_name` is defined.
    pub fn knows(&self, type_name: &str) -> bool {
        self.types.contains_key(type_name)
    }

    /// Checks that every type `type_name` uses is defined and none contains itself.
    pub fn check(&self, type_name: &str) -> Result<(), DefinitionError> {
        self.check_from(
            type_name,
            &mut Vec::new(),
            &mut std::collections::BTreeSet::new(),
        )
    }

    /// Checks `name` (reached through `path`); `done` holds the types already checked, so each
    /// is walked once however many fields use it.
    fn check_from(
        &self,
        name: &str,
        path: &mut Vec<String>,
        done: &mut std::collections::BTreeSet<String>,
    ) -> Result<(), DefinitionError> {
        if done.contains(name) {
            return Ok(());
        }
        let root = path.first().cloned().unwrap_or_else(|| name.to_string());
        if path.iter().any(|p| p == name) {
            return Err(DefinitionError::Recursive {
                type_name: root,
                through: name.to_string(),
            });
        }
        let Some(fields) = self.types.get(name) else {
            return Err(DefinitionError::Missing {
                type_name: root,
                missing: name.to_string(),
            });
        };
        path.push(name.to_string());
        for field in fields {
            if let Element::Message(inner) = &field.element {
                self.check_from(inner, path, done)?;
            }
        }
        path.pop();
        done.insert(name.to_string());
        Ok(())
    }
}

/// One line of a definition: a field, nothing (blank, comment, constant), or what is wrong.
fn parse_field(line: &str, package: &str) -> Result<Option<Field>, String> {
    let line = line.split('#').next().unwrap_or_default().trim();
    if line.is_empty() {
        return Ok(None);
    }
    let mut words = line.split_whitespace();
    let (Some(ty), Some(name)) = (words.next(), words.next()) else {
        return Err(format!("{line:?} is not TYPE NAME"));
    };
    // A constant (`uint8 RED=1`, `string NAME = text`) or a ROS 2 default value: no bytes of
    // its own beyond the field (a default is a field; a constant is not).
    if name.contains('=') || words.clone().next().is_some_and(|w| w.starts_with('=')) {
        return Ok(None);
    }
    let (element_name, count) = match ty.split_once('[') {
        None => (ty, Count::One),
        Some((element, rest)) => {
            let inside = rest
                .strip_suffix(']')
                .ok_or_else(|| format!("{ty:?} has no closing ]"))?;
            let count = if inside.is_empty() || inside.starts_with("<=") {
                Count::Sequence
            } else {
                let n: usize = inside
                    .parse()
                    .map_err(|_| format!("{ty:?}: {inside:?} is not an array length"))?;
                if n > 1 << 24 {
                    return Err(format!("{ty:?}: a fixed array of {n} is too long"));
                }
                Count::Fixed(n)
            };
            (element, count)
        }
    };
    // `string<=10` is a bounded string: a string.
    let element_name = element_name.split("<=").next().unwrap_or(element_name);
    let element = match Primitive::parse(element_name) {
        Some(primitive) => Element::Primitive(primitive),
        None => {
            let valid = element_name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/');
            if !valid || element_name.is_empty() {
                return Err(format!("{element_name:?} is not a type name"));
            }
            Element::Message(full_name(element_name, package))
        }
    };
    if !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(format!("{name:?} is not a field name"));
    }
    Ok(Some(Field {
        name: name.to_string(),
        element,
        count,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    const POSE_STAMPED: &str = "# A pose with a reference frame\nstd_msgs/Header header\ngeometry_msgs/Pose pose\n\n================================================================================\nMSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n\n================================================================================\nMSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation\n\n================================================================================\nMSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n\n================================================================================\nMSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w\n";

    #[test]
    fn a_ros1_definition_with_its_dependencies() {
        let defs = MessageDefs::parse("geometry_msgs/PoseStamped", POSE_STAMPED).expect("parse");
        let fields = defs.fields("geometry_msgs/PoseStamped").expect("main type");
        assert_eq!(fields.len(), 2);
        assert_eq!(
            fields[1].element,
            Element::Message("geometry_msgs/Pose".into())
        );
        let pose = defs.fields("geometry_msgs/Pose").expect("pose");
        assert_eq!(
            pose[0].element,
            Element::Message("geometry_msgs/Point".into()),
            "a bare name is of its own package"
        );
        let header = defs.fields("std_msgs/Header").expect("header");
        assert_eq!(header[1].element, Element::Primitive(Primitive::Time));
    }

    #[test]
    fn arrays_constants_defaults_and_ros2_names() {
        let text = "uint8 RED=1\nstring NAME = a # constant\nint32[] a\nfloat64[9] k\nuint8[<=4] b\nstring<=8 s\nbuiltin_interfaces/msg/Time t\nint32 x 5\n";
        let mut defs = MessageDefs::default();
        defs.add("pkg/msg/T", text).expect("parse");
        let fields = defs.fields("pkg/T").expect("T");
        let summary: Vec<(&str, Count)> =
            fields.iter().map(|f| (f.name.as_str(), f.count)).collect();
        assert_eq!(
            summary,
            [
                ("a", Count::Sequence),
                ("k", Count::Fixed(9)),
                ("b", Count::Sequence),
                ("s", Count::One),
                ("t", Count::One),
                ("x", Count::One),
            ]
        );
        assert_eq!(
            fields[4].element,
            Element::Message("builtin_interfaces/Time".into())
        );
        assert!(matches!(
            defs.check("pkg/T"),
            Err(DefinitionError::Missing { missing, .. }) if missing == "builtin_interfaces/Time"
        ));
    }

    #[test]
    fn hostile_definitions_are_refused_by_name() {
        let recursive = "a/B b\n================================================================================\nMSG: a/B\na/A back\n";
        assert!(matches!(
            MessageDefs::parse("a/A", recursive),
            Err(DefinitionError::Recursive { .. })
        ));
        for bad in ["int32", "int32[x] a", "int32[ a", "in$t b", "int32 a-b"] {
            let error = MessageDefs::parse("a/A", bad).expect_err(bad);
            assert!(error.to_string().contains("line 1"), "{error}");
        }
        let huge = "int32 a\n".repeat(MAX_DEFINITION_BYTES / 8 + 1);
        assert!(matches!(
            MessageDefs::parse("a/A", &huge),
            Err(DefinitionError::TooLarge { .. })
        ));
        let long = "uint8[100000000] a";
        assert!(MessageDefs::parse("a/A", long).is_err());
    }
}
