//! Judging a PLY or PCD frame file as its readers (plyfile, Open3D, PCL) would read it, before
//! anything trusts it: the header must end within [`MAX_HEADER_BYTES`], declare only types and
//! layouts those readers know, and a body whose size follows from it; the body must then hold
//! exactly that, with finite `x y z`. Every size is checked against the bytes present before
//! anything is allocated, so a header claiming 10^12 points, a header without an end or a
//! compressed PCD declaring gigabytes (an LZF bomb) are refused in microseconds.
//!
//! [`header`] reads the header only (what `validate --quick` does with the file's length);
//! [`frame_problem`] reads all of it (validate, and merge before it copies a frame).

use super::files::CloudFileFormat;

/// A frame's file larger than this is not one surgvla writes (a million points of PCD with a
/// mask channel is about 20 MB).
pub const MAX_FRAME_BYTES: u64 = 256 << 20;
/// The longest header read: ours are about 250 bytes.
pub const MAX_HEADER_BYTES: usize = 64 << 10;
/// The most a compressed PCD body may expand (LZF's largest back reference: 264 bytes from 2).
const MAX_LZF_RATIO: u64 = 132;

/// A frame file's header: how many points, where the body starts, and what it holds.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    /// Points (PLY: the `vertex` element's count).
    pub points: u64,
    /// Bytes before the body.
    pub header_bytes: usize,
    /// The body's layout.
    body: Body,
}

#[derive(Clone, Debug, PartialEq)]
enum Body {
    /// Fixed-size rows: the body is exactly `bytes` long; `elements` are (rows, properties).
    Binary {
        little_endian: bool,
        elements: Vec<(u64, Vec<Property>)>,
    },
    /// Whitespace-separated numbers, one row per line.
    Ascii { elements: Vec<(u64, Vec<Property>)> },
    /// PCD `binary_compressed`: LZF of the fields one after another.
    Compressed { fields: Vec<Property> },
}

/// One property (PLY) or field (PCD): its scalar type and, for a PLY list, the count's type.
#[derive(Clone, Debug, PartialEq)]
struct Property {
    name: String,
    scalar: Scalar,
    /// PCD's COUNT (PLY scalars: 1).
    count: u64,
    /// A PLY list's length type.
    list: Option<Scalar>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    Int(u8),
    UInt(u8),
    Float(u8),
}

impl Scalar {
    fn bytes(self) -> u64 {
        match self {
            Scalar::Int(n) | Scalar::UInt(n) | Scalar::Float(n) => u64::from(n),
        }
    }

    fn ply(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::Int(1),
            "uchar" | "uint8" => Scalar::UInt(1),
            "short" | "int16" => Scalar::Int(2),
            "ushort" | "uint16" => Scalar::UInt(2),
            "int" | "int32" => Scalar::Int(4),
            "uint" | "uint32" => Scalar::UInt(4),
            "float" | "float32" => Scalar::Float(4),
            "double" | "float64" => Scalar::Float(8),
            _ => return None,
        })
    }

    fn pcd(kind: &str, size: &str) -> Option<Scalar> {
        Some(match (kind, size) {
            ("I", "1" | "2" | "4" | "8") => Scalar::Int(size.parse().ok()?),
            ("U", "1" | "2" | "4" | "8") => Scalar::UInt(size.parse().ok()?),
            ("F", "4" | "8") => Scalar::Float(size.parse().ok()?),
            _ => return None,
        })
    }

    /// The value at the start of `bytes` as f64 (an integer read exactly up to 2^53).
    fn read(self, bytes: &[u8], little_endian: bool) -> f64 {
        let mut word = [0u8; 8];
        let n = self.bytes() as usize;
        if little_endian {
            word[..n].copy_from_slice(&bytes[..n]);
        } else {
            for (k, b) in bytes[..n].iter().rev().enumerate() {
                word[k] = *b;
            }
        }
        let raw = u64::from_le_bytes(word);
        match self {
            Scalar::Float(4) => f64::from(f32::from_bits(raw as u32)),
            Scalar::Float(_) => f64::from_bits(raw),
            Scalar::UInt(_) => raw as f64,
            Scalar::Int(n) => {
                let shift = 64 - 8 * u32::from(n);
                ((raw << shift) as i64 >> shift) as f64
            }
        }
    }
}

/// The header at the start of `bytes` (which may be only the file's first
/// [`MAX_HEADER_BYTES`]); an error says what is wrong with it.
pub fn header(bytes: &[u8], format: CloudFileFormat) -> Result<Header, String> {
    let (end_marker, what) = match format {
        CloudFileFormat::Ply => ("end_header", "PLY"),
        CloudFileFormat::Pcd => ("DATA ", "PCD"),
    };
    let window = &bytes[..bytes.len().min(MAX_HEADER_BYTES)];
    let mut header_bytes = None;
    let mut lines = Vec::new();
    let mut start = 0;
    while let Some(offset) = window[start..].iter().position(|&b| b == b'\n') {
        let line = std::str::from_utf8(&window[start..start + offset])
            .map_err(|_| format!("its {what} header is not text"))?
            .trim_end_matches('\r');
        start += offset + 1;
        lines.push(line);
        if line.starts_with(end_marker) {
            header_bytes = Some(start);
            break;
        }
    }
    let header_bytes = header_bytes.ok_or_else(|| {
        format!("its {what} header has no `{end_marker}` line within its first 64 KiB")
    })?;
    let (points, body) = match format {
        CloudFileFormat::Ply => ply_header(&lines)?,
        CloudFileFormat::Pcd => pcd_header(&lines)?,
    };
    Ok(Header {
        points,
        header_bytes,
        body,
    })
}

fn ply_header(lines: &[&str]) -> Result<(u64, Body), String> {
    if lines.first() != Some(&"ply") {
        return Err("does not begin with `ply`".into());
    }
    let mut format = None;
    let mut elements: Vec<(String, u64, Vec<Property>)> = Vec::new();
    for line in &lines[1..lines.len() - 1] {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", kind, "1.0"] => format = Some(kind.to_string()),
            ["comment", ..] | ["obj_info", ..] | [] => {}
            ["element", name, count] => {
                let count = count
                    .parse()
                    .map_err(|_| format!("element {name}'s count {count} is not a count"))?;
                elements.push((name.to_string(), count, Vec::new()));
            }
            ["property", kind, name] => {
                let scalar = Scalar::ply(kind).ok_or_else(|| format!("type {kind} unknown"))?;
                let element = elements.last_mut().ok_or("a property before any element")?;
                element.2.push(Property::scalar(name, scalar));
            }
            ["property", "list", count, item, name] => {
                let count = Scalar::ply(count).filter(|s| !matches!(s, Scalar::Float(_)));
                let item = Scalar::ply(item);
                let (Some(count), Some(item)) = (count, item) else {
                    return Err(format!("list {name} has types PLY does not know"));
                };
                let element = elements.last_mut().ok_or("a property before any element")?;
                let mut property = Property::scalar(name, item);
                property.list = Some(count);
                element.2.push(property);
            }
            _ => {
                return Err(format!(
                    "its PLY header has a line `{line}` PLY does not know"
                ));
            }
        }
    }
    if let Some((name, ..)) = elements.iter().find(|e| e.1 > 0 && e.2.is_empty()) {
        return Err(format!("its element {name} has rows but no properties"));
    }
    let vertex = elements.iter().find(|e| e.0 == "vertex");
    let Some((_, points, properties)) = vertex else {
        return Err("has no vertex element".into());
    };
    for axis in ["x", "y", "z"] {
        if !properties
            .iter()
            .any(|p| p.name == axis && p.list.is_none())
        {
            return Err(format!("its vertex element has no {axis}"));
        }
    }
    let elements = elements.iter().map(|e| (e.1, e.2.clone())).collect();
    let body = match format.as_deref() {
        Some("binary_little_endian") => Body::Binary {
            little_endian: true,
            elements,
        },
        Some("binary_big_endian") => Body::Binary {
            little_endian: false,
            elements,
        },
        Some("ascii") => Body::Ascii { elements },
        _ => return Err("has no `format ascii|binary_little_endian|binary_big_endian 1.0`".into()),
    };
    Ok((*points, body))
}

impl Property {
    fn scalar(name: &str, scalar: Scalar) -> Property {
        Property {
            name: name.to_string(),
            scalar,
            count: 1,
            list: None,
        }
    }
}

fn pcd_header(lines: &[&str]) -> Result<(u64, Body), String> {
    let mut keys = std::collections::HashMap::new();
    for line in lines.iter().filter(|l| !l.starts_with('#')) {
        let mut words = line.split_whitespace();
        if let Some(key) = words.next() {
            keys.insert(key, words.collect::<Vec<&str>>());
        }
    }
    let get = |key: &str| {
        keys.get(key)
            .ok_or_else(|| format!("its PCD header has no {key} line"))
    };
    let number = |key: &str| -> Result<u64, String> {
        match get(key)?.as_slice() {
            [value] => value
                .parse()
                .map_err(|_| format!("its {key} is not a count")),
            _ => Err(format!("its {key} line holds more than one value")),
        }
    };
    let (names, sizes, types) = (get("FIELDS")?, get("SIZE")?, get("TYPE")?);
    let counts = keys
        .get("COUNT")
        .cloned()
        .unwrap_or_else(|| vec!["1"; names.len()]);
    if sizes.len() != names.len() || types.len() != names.len() || counts.len() != names.len() {
        return Err("its FIELDS, SIZE, TYPE and COUNT lines differ in length".into());
    }
    let mut fields = Vec::new();
    for (k, name) in names.iter().enumerate() {
        let scalar = Scalar::pcd(types[k], sizes[k])
            .ok_or_else(|| format!("field {name} has TYPE {} SIZE {}", types[k], sizes[k]))?;
        let mut field = Property::scalar(name, scalar);
        field.count = counts[k]
            .parse()
            .ok()
            .filter(|c| (1..=1 << 16).contains(c))
            .ok_or_else(|| format!("field {name}'s COUNT {} is not a count", counts[k]))?;
        fields.push(field);
    }
    for axis in ["x", "y", "z"] {
        if !fields.iter().any(|f| f.name == axis && f.count == 1) {
            return Err(format!("has no field {axis}"));
        }
    }
    let points = number("POINTS")?;
    let (width, height) = (number("WIDTH")?, number("HEIGHT")?);
    if width.checked_mul(height) != Some(points) {
        return Err(format!(
            "its WIDTH {width} x HEIGHT {height} is not POINTS {points}"
        ));
    }
    let body = match get("DATA")?.as_slice() {
        ["binary"] => Body::Binary {
            little_endian: true,
            elements: vec![(points, fields)],
        },
        ["ascii"] => Body::Ascii {
            elements: vec![(points, fields)],
        },
        ["binary_compressed"] => Body::Compressed { fields },
        other => return Err(format!("its DATA {} is not one PCD knows", other.join(" "))),
    };
    Ok((points, body))
}

impl Header {
    /// The body's exact length when it follows from the header alone (binary bodies without
    /// lists), or an error when no file of `file_bytes` could hold it.
    pub fn body_bytes(&self, file_bytes: u64) -> Result<Option<u64>, String> {
        let available = file_bytes.saturating_sub(self.header_bytes as u64);
        let Body::Binary { elements, .. } = &self.body else {
            return Ok(None);
        };
        let mut total = 0u64;
        let mut fixed = true;
        for (rows, properties) in elements {
            // Every row of a list property holds at least its count.
            let row: u64 = properties.iter().map(Property::least_bytes).sum();
            fixed &= properties.iter().all(|p| p.list.is_none());
            total = rows
                .checked_mul(row)
                .and_then(|bytes| total.checked_add(bytes))
                .filter(|&t| t <= available)
                .ok_or_else(|| self.too_many(available))?;
        }
        Ok(fixed.then_some(total))
    }

    fn too_many(&self, available: u64) -> String {
        format!(
            "declares {} points (and rows) that its {available} bytes of body cannot hold",
            self.points
        )
    }
}

impl Property {
    fn least_bytes(&self) -> u64 {
        match self.list {
            Some(count) => count.bytes(),
            None => self.scalar.bytes() * self.count,
        }
    }
}

/// What is wrong with the frame file `bytes`, read whole; None when plyfile or PCL would read
/// every point it declares and every coordinate is finite. Ok: the number of points.
pub fn frame_problem(bytes: &[u8], format: CloudFileFormat) -> Result<u64, String> {
    let header = header(bytes, format)?;
    let declared = header.body_bytes(bytes.len() as u64)?;
    let body = &bytes[header.header_bytes..];
    match &header.body {
        Body::Binary {
            little_endian,
            elements,
        } => {
            let used = read_binary(body, elements, *little_endian)?;
            if declared.is_some_and(|d| d != used) || used != body.len() as u64 {
                return Err(format!(
                    "its body is {} bytes where its header declares {used}",
                    body.len()
                ));
            }
        }
        Body::Ascii { elements } => read_ascii(body, elements)?,
        Body::Compressed { fields } => read_compressed(body, header.points, fields)?,
    }
    Ok(header.points)
}

/// Walks a binary body, checking `x y z` are finite; the bytes used.
fn read_binary(
    body: &[u8],
    elements: &[(u64, Vec<Property>)],
    little_endian: bool,
) -> Result<u64, String> {
    let cut = || "its body ends before the points its header declares".to_string();
    let mut at = 0usize;
    for (rows, properties) in elements {
        for _ in 0..*rows {
            for property in properties {
                let items = match property.list {
                    Some(count) => {
                        let bytes = body.get(at..at + count.bytes() as usize).ok_or_else(cut)?;
                        at += bytes.len();
                        count.read(bytes, little_endian) as u64
                    }
                    None => property.count,
                };
                let size = property.scalar.bytes() * items;
                let bytes = usize::try_from(size)
                    .ok()
                    .and_then(|size| body.get(at..at.checked_add(size)?))
                    .ok_or_else(cut)?;
                if property.is_axis() && !property.scalar.read(bytes, little_endian).is_finite() {
                    return Err(format!("a point's {} is not finite", property.name));
                }
                at += bytes.len();
            }
        }
    }
    Ok(at as u64)
}

impl Property {
    fn is_axis(&self) -> bool {
        self.list.is_none() && matches!(self.name.as_str(), "x" | "y" | "z")
    }
}

/// Reads an ASCII body: one row per line, each property's numbers.
fn read_ascii(body: &[u8], elements: &[(u64, Vec<Property>)]) -> Result<(), String> {
    let text = std::str::from_utf8(body).map_err(|_| "its ASCII body is not text")?;
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    for (rows, properties) in elements {
        for row in 0..*rows {
            let line = lines
                .next()
                .ok_or_else(|| format!("its body ends at row {row} of {rows}"))?;
            let mut words = line.split_whitespace();
            for property in properties {
                let items = match property.list {
                    Some(_) => words
                        .next()
                        .and_then(|w| w.parse::<u64>().ok())
                        .ok_or_else(|| format!("row {row}: {} has no length", property.name))?,
                    None => property.count,
                };
                for _ in 0..items {
                    let value: f64 = words
                        .next()
                        .and_then(|w| w.parse().ok())
                        .ok_or_else(|| format!("row {row}: {} is not a number", property.name))?;
                    if property.is_axis() && !value.is_finite() {
                        return Err(format!("row {row}: {} is not finite", property.name));
                    }
                }
            }
            if words.next().is_some() {
                return Err(format!(
                    "row {row} holds more values than its header declares"
                ));
            }
        }
    }
    if lines.next().is_some() {
        return Err("its body holds more rows than its header declares".into());
    }
    Ok(())
}

/// Reads a `binary_compressed` PCD body: compressed and uncompressed sizes, then LZF of each
/// field's values in turn.
fn read_compressed(body: &[u8], points: u64, fields: &[Property]) -> Result<(), String> {
    let word = |k: usize| {
        body.get(4 * k..4 * k + 4)
            .map(|b| u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])))
            .ok_or("its compressed body has no sizes")
    };
    let (compressed, uncompressed) = (word(0)?, word(1)?);
    let stride: u64 = fields.iter().map(Property::least_bytes).sum();
    if points.checked_mul(stride) != Some(uncompressed) {
        return Err(format!(
            "its compressed body unpacks to {uncompressed} bytes, not {points} points of {stride}"
        ));
    }
    let data = &body[8..];
    if compressed != data.len() as u64 || uncompressed > compressed * MAX_LZF_RATIO {
        return Err(format!(
            "its compressed body declares {compressed} bytes unpacking to {uncompressed}, \
             which its {} bytes cannot hold",
            data.len()
        ));
    }
    let values = lzf_decompress(data, uncompressed as usize)
        .ok_or("its compressed body is not LZF of the size it declares")?;
    let mut at = 0usize;
    for field in fields {
        let size = (field.least_bytes() * points) as usize;
        if field.is_axis() {
            let step = field.scalar.bytes() as usize;
            let block = &values[at..at + size];
            if block
                .chunks_exact(step)
                .any(|v| !field.scalar.read(v, true).is_finite())
            {
                return Err(format!("a point's {} is not finite", field.name));
            }
        }
        at += size;
    }
    Ok(())
}

/// LZF (liblzf, as PCL writes it) of `input`, which must unpack to exactly `size` bytes.
fn lzf_decompress(input: &[u8], size: usize) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(size);
    let mut i = 0;
    while i < input.len() {
        let control = usize::from(input[i]);
        i += 1;
        if control < 32 {
            let literal = input.get(i..i + control + 1)?;
            if out.len() + literal.len() > size {
                return None;
            }
            out.extend_from_slice(literal);
            i += literal.len();
        } else {
            let mut length = control >> 5;
            if length == 7 {
                length += usize::from(*input.get(i)?);
                i += 1;
            }
            let back = ((control & 0x1f) << 8) + usize::from(*input.get(i)?) + 1;
            i += 1;
            length += 2;
            if back > out.len() || out.len() + length > size {
                return None;
            }
            let from = out.len() - back;
            for k in 0..length {
                out.push(out[from + k]);
            }
        }
    }
    (out.len() == size).then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::pointcloud::{Cloud, pcd::encode_pcd, ply::encode_ply};

    fn cloud() -> Cloud {
        Cloud {
            xyz_m: vec![[0.1, 0.2, 0.3], [0.4, 0.5, 0.6], [0.0; 3]],
            rgb: vec![[1, 2, 3], [4, 5, 6], [0; 3]],
            mask: vec![7, 8, 0],
            valid: 2,
        }
    }

    fn replace(bytes: &[u8], from: &str, to: &str) -> Vec<u8> {
        let text = String::from_utf8_lossy(bytes).into_owned();
        let at = text.find(from).expect("in the header");
        let mut out = bytes[..at].to_vec();
        out.extend_from_slice(to.as_bytes());
        out.extend_from_slice(&bytes[at + from.len()..]);
        out
    }

    #[test]
    fn our_frames_read_back_and_forged_headers_are_refused() {
        for format in CloudFileFormat::ALL {
            let (bytes, count) = match format {
                CloudFileFormat::Ply => (encode_ply(&cloud()), "element vertex 2"),
                CloudFileFormat::Pcd => (encode_pcd(&cloud()), "POINTS 2"),
            };
            assert_eq!(frame_problem(&bytes, format), Ok(2));
            let huge = count.replace('2', "1000000000000");
            let forged = replace(&bytes, count, &huge);
            let problem = frame_problem(&forged, format).unwrap_err();
            assert!(
                problem.contains("cannot hold") || problem.contains("WIDTH"),
                "{problem}"
            );
            let cut = &bytes[..bytes.len() - 3];
            assert!(frame_problem(cut, format).is_err(), "{format:?} cut");
            let mut longer = bytes.clone();
            longer.push(0);
            assert!(frame_problem(&longer, format).is_err(), "{format:?} longer");
            // A header that never ends, however long the file.
            let mut endless = b"ply\nformat binary_little_endian 1.0\n".to_vec();
            endless.resize(1 << 20, b'\n');
            assert!(
                frame_problem(&endless, CloudFileFormat::Ply)
                    .unwrap_err()
                    .contains("64 KiB")
            );
            // A coordinate that is not finite.
            let mut nan = bytes.clone();
            let at = header(&bytes, format).unwrap().header_bytes;
            nan[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
            assert!(frame_problem(&nan, format).unwrap_err().contains("finite"));
        }
    }

    #[test]
    fn ascii_lists_and_compressed_bodies_are_read() {
        let ply = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
                    property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                    end_header\n0 0 0\n1 1 1\n3 0 1 1\n";
        assert_eq!(frame_problem(ply, CloudFileFormat::Ply), Ok(2));
        let short =
            b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
                    property float z\nend_header\n0 0 0\n";
        assert!(frame_problem(short, CloudFileFormat::Ply).is_err());
        // Binary with a list: the face's length byte says 3, then three int32s.
        let mut binary =
            b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n\
                    property float y\nproperty float z\nelement face 1\n\
                    property list uchar int vertex_indices\nend_header\n"
                .to_vec();
        binary.extend_from_slice(&[0; 12]);
        binary.push(3);
        binary.extend_from_slice(&[0; 12]);
        assert_eq!(frame_problem(&binary, CloudFileFormat::Ply), Ok(1));
        binary.pop();
        assert!(frame_problem(&binary, CloudFileFormat::Ply).is_err());

        // A compressed PCD of two points, x y z float: 24 bytes of zeros as one literal byte
        // and a back reference of 23 (length code 7, extra 14, offset 1).
        let header = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\n\
                      HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA binary_compressed\n";
        let lzf = [0u8, 0, 0xE0, 14, 0];
        let mut pcd = header.as_bytes().to_vec();
        pcd.extend_from_slice(&(lzf.len() as u32).to_le_bytes());
        pcd.extend_from_slice(&24u32.to_le_bytes());
        pcd.extend_from_slice(&lzf);
        assert_eq!(frame_problem(&pcd, CloudFileFormat::Pcd), Ok(2));
        // The bomb: the same few bytes declaring gigabytes unpacked.
        let bomb = replace(&pcd, "WIDTH 2", "WIDTH 200000000");
        let bomb = replace(&bomb, "POINTS 2", "POINTS 200000000");
        let at = bomb.len() - lzf.len() - 4;
        let mut bomb = bomb;
        bomb[at..at + 4].copy_from_slice(&2_400_000_000u32.to_le_bytes());
        assert!(
            frame_problem(&bomb, CloudFileFormat::Pcd)
                .unwrap_err()
                .contains("cannot hold")
        );
    }
}
