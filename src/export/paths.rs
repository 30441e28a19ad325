//! The one way from a dataset's metadata to a path. Names and templates in another tool's
//! metadata (LeRobot feature keys, `video_path`, an RLDS dataset's `name`, a manifest's file
//! list) are untrusted text: every one becomes a path only through [`component`],
//! [`relative`] or [`fill`], which refuse what could point outside the dataset folder (an
//! absolute path, `..`, a separator inside a name, control characters) and check a template's
//! placeholders and widths before formatting it.
//!
//! The checks are on the text only: symbolic links the dataset folder itself holds are followed
//! when reading (a Hugging Face hub snapshot is a tree of links into `../../blobs/`); what is
//! refused is a path that the metadata's text points outside.

use std::path::PathBuf;

/// The widest zero-padding a template may ask for (`{episode_index:06d}`); u64 has 20 digits.
pub const MAX_WIDTH: usize = 20;
/// The longest name or template accepted, in bytes (file systems allow 255 per component).
pub const MAX_NAME_BYTES: usize = 1024;

/// Why a name or template from metadata cannot become a path.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum UnsafeName {
    #[error("is empty")]
    Empty,
    #[error("is \".\" or \"..\", which leave the folder")]
    Dots,
    #[error("holds a path separator ('/' or '\\')")]
    Separator,
    #[error("holds a control character")]
    Control,
    #[error("is absolute")]
    Absolute,
    #[error("is longer than {MAX_NAME_BYTES} bytes")]
    TooLong,
    #[error("has the unknown placeholder {{{0}}}")]
    UnknownPlaceholder(String),
    #[error("has the format {0:?}, where only an integer width (such as 03d) is allowed")]
    BadFormat(String),
    #[error("pads to {0} digits (at most {MAX_WIDTH})")]
    Width(usize),
    #[error("has an unmatched brace")]
    Brace,
}

/// A value for a template's placeholder.
#[derive(Clone, Copy, Debug)]
pub enum Field<'a> {
    /// A name, which must itself be a safe [`component`] (a feature key).
    Name(&'a str),
    /// An index, which may be zero-padded (`{chunk_index:03d}`).
    Index(u64),
}

/// `name` as one path component: refused when empty, `.` or `..`, holding a separator or a
/// control character, or too long.
pub fn component(name: &str) -> Result<&str, UnsafeName> {
    if name.is_empty() {
        return Err(UnsafeName::Empty);
    }
    if name.len() > MAX_NAME_BYTES {
        return Err(UnsafeName::TooLong);
    }
    if name == "." || name == ".." {
        return Err(UnsafeName::Dots);
    }
    if name.contains(['/', '\\']) {
        return Err(UnsafeName::Separator);
    }
    if name.chars().any(char::is_control) {
        return Err(UnsafeName::Control);
    }
    Ok(name)
}

/// Whether `name` is a plain name: 1 to 64 ASCII letters, digits, `_` or `-`. The rule for
/// names surgvla itself puts in file names and keys (a split, an RLDS observation key, a
/// camera), where [`component`] would allow more than the reader of the name (TFDS parsing a
/// shard's file name, a Python attribute) does.
pub fn is_plain_name(name: &str) -> bool {
    (1..=64).contains(&name.len())
        && (name.chars()).all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

/// `path` (`/`-separated, as metadata writes it) as a path relative to the dataset folder: not
/// absolute, and each component safe ([`component`]; an empty one, as in `a//b`, is refused).
pub fn relative(path: &str) -> Result<PathBuf, UnsafeName> {
    if path.len() > MAX_NAME_BYTES {
        return Err(UnsafeName::TooLong);
    }
    if path.starts_with('/') || path.starts_with('\\') || path.get(1..2) == Some(":") {
        return Err(UnsafeName::Absolute);
    }
    let mut out = PathBuf::new();
    for part in path.split('/') {
        out.push(component(part)?);
    }
    Ok(out)
}

/// Fills a Python-style path template (`videos/{video_key}/chunk-{chunk_index:03d}/...`, as
/// LeRobot's `info.json` writes them) in one pass: each placeholder must be one of `fields`; a
/// name is inserted as it is (never scanned again), an index formatted with at most
/// [`MAX_WIDTH`] digits of padding; `{{` and `}}` are literal braces. The result must be a safe
/// [`relative`] path.
pub fn fill(template: &str, fields: &[(&str, Field<'_>)]) -> Result<PathBuf, UnsafeName> {
    if template.len() > MAX_NAME_BYTES {
        return Err(UnsafeName::TooLong);
    }
    let mut out = String::with_capacity(template.len() + 32);
    let mut rest = template;
    while let Some(at) = rest.find(['{', '}']) {
        out.push_str(&rest[..at]);
        let tail = &rest[at..];
        if let Some(after) = tail.strip_prefix("{{") {
            out.push('{');
            rest = after;
            continue;
        }
        if let Some(after) = tail.strip_prefix("}}") {
            out.push('}');
            rest = after;
            continue;
        }
        if tail.starts_with('}') {
            return Err(UnsafeName::Brace);
        }
        let end = tail.find('}').ok_or(UnsafeName::Brace)?;
        let inside = &tail[1..end];
        if inside.contains('{') {
            return Err(UnsafeName::Brace);
        }
        let (name, spec) = inside.split_once(':').unwrap_or((inside, ""));
        let value = fields
            .iter()
            .find_map(|(n, v)| (*n == name).then_some(*v))
            .ok_or_else(|| UnsafeName::UnknownPlaceholder(name.to_string()))?;
        match value {
            Field::Name(text) => {
                if !spec.is_empty() {
                    return Err(UnsafeName::BadFormat(spec.to_string()));
                }
                out.push_str(component(text)?);
            }
            Field::Index(number) => {
                let (zero, width) = index_format(spec)?;
                if zero {
                    out.push_str(&format!("{number:0>width$}"));
                } else {
                    out.push_str(&format!("{number:>width$}"));
                }
            }
        }
        rest = &tail[end + 1..];
    }
    out.push_str(rest);
    relative(&out)
}

/// An index's format spec: "" or "d" (no padding), "Nd" (spaces), "0Nd" (zeros): (zeros?, N).
fn index_format(spec: &str) -> Result<(bool, usize), UnsafeName> {
    let bad = || UnsafeName::BadFormat(spec.to_string());
    if spec.is_empty() || spec == "d" {
        return Ok((false, 0));
    }
    let digits = spec.strip_suffix('d').ok_or_else(bad)?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return Err(bad());
    }
    let zero = digits.starts_with('0');
    let significant = digits.trim_start_matches('0');
    let width: usize = match significant {
        "" => 0,
        text => text.parse().unwrap_or(usize::MAX),
    };
    if width > MAX_WIDTH {
        return Err(UnsafeName::Width(width));
    }
    Ok((zero, width))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn a_plain_name_is_one_to_64_letters_digits_underscores_or_dashes() {
        for plain in ["train", "val-2", "wrist_cam", "A", &"x".repeat(64)] {
            assert!(is_plain_name(plain), "{plain}");
        }
        for not_plain in ["", "..", "a/b", "a.b", "val train", "é", &"x".repeat(65)] {
            assert!(!is_plain_name(not_plain), "{not_plain}");
        }
    }

    const V30: &str = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4";

    #[test]
    fn lerobot_templates_fill_as_python_formats_them() {
        let fields = [
            ("video_key", Field::Name("observation.images.rgb")),
            ("chunk_index", Field::Index(2)),
            ("file_index", Field::Index(17)),
        ];
        assert_eq!(
            fill(V30, &fields).unwrap(),
            Path::new("videos/observation.images.rgb/chunk-002/file-017.mp4")
        );
        let fields = [("episode_index", Field::Index(5))];
        assert_eq!(
            fill("e_{episode_index:6d}_{episode_index}{{x}}", &fields).unwrap(),
            Path::new("e_     5_5{x}")
        );
    }

    #[test]
    fn names_that_leave_the_folder_are_refused() {
        for (name, why) in [
            ("", UnsafeName::Empty),
            ("..", UnsafeName::Dots),
            (".", UnsafeName::Dots),
            ("../../../x", UnsafeName::Separator),
            ("a/b", UnsafeName::Separator),
            ("a\\b", UnsafeName::Separator),
            ("a\0b", UnsafeName::Control),
            ("a\nb", UnsafeName::Control),
        ] {
            assert_eq!(component(name), Err(why), "{name:?}");
        }
        assert_eq!(component(&"x".repeat(2000)), Err(UnsafeName::TooLong));
        assert_eq!(
            component("observation.images.rgb"),
            Ok("observation.images.rgb")
        );
        assert_eq!(relative("/etc/passwd"), Err(UnsafeName::Absolute));
        assert_eq!(relative("C:/x"), Err(UnsafeName::Absolute));
        assert_eq!(relative("videos/../../x"), Err(UnsafeName::Dots));
        assert_eq!(relative("videos//x"), Err(UnsafeName::Empty));
        assert_eq!(
            relative("videos/a/b.mp4").unwrap(),
            Path::new("videos/a/b.mp4")
        );
    }

    #[test]
    fn hostile_templates_are_refused_before_formatting() {
        let key = |k| {
            [
                ("video_key", Field::Name(k)),
                ("chunk_index", Field::Index(0)),
            ]
        };
        // A key holding its own placeholder is inserted once, not expanded again (no loop).
        let looping = fill("v/{video_key}", &key("{video_key:1d}")).unwrap();
        assert_eq!(looping, Path::new("v/{video_key:1d}"));
        assert_eq!(
            fill("v/{video_key}", &key("../../x")),
            Err(UnsafeName::Separator)
        );
        assert_eq!(fill("../{video_key}", &key("a")), Err(UnsafeName::Dots));
        assert_eq!(
            fill("/abs/{video_key}", &key("a")),
            Err(UnsafeName::Absolute)
        );
        assert_eq!(
            fill("{video_key}/{chunk_index:70000d}", &key("a")),
            Err(UnsafeName::Width(70000))
        );
        assert_eq!(
            fill("{chunk_index:099999999999999999999999d}", &key("a")),
            Err(UnsafeName::Width(usize::MAX))
        );
        assert_eq!(
            fill("{chunk_index:x}", &key("a")),
            Err(UnsafeName::BadFormat("x".into()))
        );
        assert_eq!(
            fill("{video_key:>9}", &key("a")),
            Err(UnsafeName::BadFormat(">9".into()))
        );
        assert_eq!(
            fill("{home}", &key("a")),
            Err(UnsafeName::UnknownPlaceholder("home".into()))
        );
        assert_eq!(fill("{video_key", &key("a")), Err(UnsafeName::Brace));
        assert_eq!(fill("a}b", &key("a")), Err(UnsafeName::Brace));
        assert_eq!(
            fill(&"{video_key}".repeat(200), &key("a")),
            Err(UnsafeName::TooLong)
        );
    }

    #[test]
    fn random_templates_never_panic_and_never_leave_the_folder() {
        let mut rng = crate::rng::SplitMix64::new(24);
        let pieces = [
            "{",
            "}",
            "{{",
            "}}",
            "..",
            "/",
            "\\",
            "a",
            ":",
            "0",
            "9",
            "d",
            "{video_key}",
            "{chunk_index:03d}",
            "\0",
            "\u{e9}",
        ];
        for _ in 0..20_000 {
            let n = (rng.next_u64() % 12) as usize;
            let text: String = (0..n)
                .map(|_| pieces[(rng.next_u64() % pieces.len() as u64) as usize])
                .collect();
            let fields = [
                ("video_key", Field::Name(&text)),
                ("chunk_index", Field::Index(rng.next_u64())),
            ];
            if let Ok(path) = fill(&text, &fields) {
                assert!(path.is_relative(), "{text:?}");
                assert!(
                    path.components()
                        .all(|c| matches!(c, std::path::Component::Normal(_))),
                    "{text:?} -> {path:?}"
                );
            }
        }
    }
}
