//! A bounded look at an MP4 file before [`re_mp4`] parses it, and a quiet net under that parse.
//!
//! re_mp4 checks each table's entry count against its box, but it builds one sample record per
//! sample that `stsz` claims: a fixed sample size with a count of 2^32 (a 60-byte lie) would
//! make it allocate hundreds of gigabytes, an abort no `catch_unwind` stops. [`check_tables`]
//! walks the box tree re_mp4 reads (`moov/trak/mdia/minf/stbl/stsz`, the sample description) and refuses sample counts and sizes
//! the file cannot hold. What re_mp4 still panics on (tables that disagree with each other) is
//! caught by [`quietly`], whose panics a process's panic hook can keep off the user's terminal
//! ([`in_quiet_parse`]: the command line's hook does; the library installs none): the caller
//! reports the damaged file as an error naming it.

use std::cell::Cell;
use std::io::{Read, Seek, SeekFrom};

/// Boxes re_mp4 reads children of, with the bytes before their first child (after the header):
/// the path to the sample tables, the sample description and its video sample entries.
const CONTAINERS: [(&[u8; 4], u64); 15] = [
    (b"moov", 0),
    (b"trak", 0),
    (b"mdia", 0),
    (b"minf", 0),
    (b"stbl", 0),
    (b"edts", 0),
    (b"dinf", 0),
    (b"mvex", 0),
    (b"udta", 0),
    (b"stsd", 8),
    (b"avc1", 78),
    (b"av01", 78),
    (b"hvc1", 78),
    (b"hev1", 78),
    (b"vp09", 78),
];
/// Deepest nesting walked (the sample tables sit at depth 5, their codec's boxes at 7).
const MAX_DEPTH: usize = 8;
/// Boxes read before giving up (a real file has a few dozen).
const MAX_BOXES: usize = 100_000;

/// Refuses sample tables that claim more than `file_size` bytes can hold: the problem, or None.
pub(crate) fn check_tables(
    file: &mut (impl Read + Seek),
    file_size: u64,
) -> std::io::Result<Option<String>> {
    let mut budget = MAX_BOXES;
    walk(file, 0, file_size, file_size, 0, &mut budget)
}

fn walk(
    file: &mut (impl Read + Seek),
    start: u64,
    end: u64,
    file_size: u64,
    depth: usize,
    budget: &mut usize,
) -> std::io::Result<Option<String>> {
    let mut at = start;
    while at + 8 <= end {
        if *budget == 0 || depth > MAX_DEPTH {
            return Ok(Some("too many boxes".into()));
        }
        *budget -= 1;
        file.seek(SeekFrom::Start(at))?;
        let mut header = [0u8; 8];
        file.read_exact(&mut header)?;
        let kind: [u8; 4] = [header[4], header[5], header[6], header[7]];
        let (size, header_len) =
            match u32::from_be_bytes([header[0], header[1], header[2], header[3]]) {
                // "To the end of the file": only the last top-level box may say so (re_mp4
                // loops forever on a nested one).
                0 if depth == 0 => (end - at, 8),
                0 => {
                    return Ok(Some(format!(
                        "box at byte {at} has size 0 inside another box"
                    )));
                }
                1 if at + 16 > end => return Ok(Some(format!("box at byte {at} is cut short"))),
                1 => {
                    let mut large = [0u8; 8];
                    file.read_exact(&mut large)?;
                    (u64::from_be_bytes(large), 16)
                }
                size => (u64::from(size), 8),
            };
        if size < header_len || size > end - at {
            return Ok(Some(format!(
                "box {} at byte {at} claims {size} bytes, beyond its parent",
                String::from_utf8_lossy(&kind)
            )));
        }
        let children = CONTAINERS
            .iter()
            .find(|(name, _)| **name == kind)
            .map(|(_, skip)| header_len + skip)
            .filter(|first| *first <= size);
        if let Some(first) = children {
            if let Some(problem) = walk(file, at + first, at + size, file_size, depth + 1, budget)?
            {
                return Ok(Some(problem));
            }
        } else if &kind == b"stsz" && size >= header_len + 12 {
            let mut fields = [0u8; 12];
            file.read_exact(&mut fields)?;
            let sample_size = u64::from(u32::from_be_bytes([
                fields[4], fields[5], fields[6], fields[7],
            ]));
            let count = u64::from(u32::from_be_bytes([
                fields[8], fields[9], fields[10], fields[11],
            ]));
            // Each sample takes at least a byte of the file (or the fixed size claimed).
            if count.saturating_mul(sample_size.max(1)) > file_size {
                return Ok(Some(format!(
                    "its sample table claims {count} samples of {sample_size} bytes, more than the file's {file_size} bytes hold"
                )));
            }
        }
        at += size;
    }
    Ok(None)
}

thread_local! {
    /// Whether this thread is inside [`quietly`].
    static QUIET: Cell<bool> = const { Cell::new(false) };
}

/// Whether this thread is inside [`quietly`], whose panics are expected and reported as errors:
/// a panic hook leaves their message out.
pub fn in_quiet_parse() -> bool {
    QUIET.with(Cell::get)
}

/// Runs `parse`, turning a panic into `Err(())` (see [`in_quiet_parse`] for its message).
pub(crate) fn quietly<T>(parse: impl FnOnce() -> T) -> Result<T, ()> {
    QUIET.with(|quiet| quiet.set(true));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(parse));
    QUIET.with(|quiet| quiet.set(false));
    result.map_err(|_| ())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mp4_box(kind: &[u8; 4], body: &[u8]) -> Vec<u8> {
        let mut out = ((body.len() + 8) as u32).to_be_bytes().to_vec();
        out.extend_from_slice(kind);
        out.extend_from_slice(body);
        out
    }

    fn file_with_stsz(sample_size: u32, count: u32) -> Vec<u8> {
        let mut stsz = vec![0u8; 4];
        stsz.extend_from_slice(&sample_size.to_be_bytes());
        stsz.extend_from_slice(&count.to_be_bytes());
        let mut tree = mp4_box(b"stsz", &stsz);
        for kind in [b"stbl", b"minf", b"mdia", b"trak", b"moov"] {
            tree = mp4_box(kind, &tree);
        }
        let mut file = mp4_box(b"ftyp", b"isom\0\0\0\0");
        file.extend(tree);
        file.extend(mp4_box(b"mdat", &[0u8; 64]));
        file
    }

    fn check(bytes: &[u8]) -> Option<String> {
        check_tables(&mut std::io::Cursor::new(bytes), bytes.len() as u64).expect("reads")
    }

    #[test]
    fn sample_counts_the_file_cannot_hold_are_refused() {
        assert_eq!(check(&file_with_stsz(0, 10)), None);
        assert_eq!(check(&file_with_stsz(4, 10)), None);
        let lie = check(&file_with_stsz(1, u32::MAX)).expect("refused");
        assert!(lie.contains("4294967295 samples"), "{lie}");
        assert!(check(&file_with_stsz(1_000_000, 2)).is_some());
        // A box claiming more than its parent holds.
        let mut bytes = file_with_stsz(0, 1);
        bytes[16..20].copy_from_slice(&u32::MAX.to_be_bytes());
        assert!(
            check(&bytes)
                .expect("refused")
                .contains("beyond its parent")
        );
        // A nested box of size 0 (re_mp4 would loop on it); at the top level it ends the file.
        let mut bytes = file_with_stsz(0, 1);
        let stsz = bytes.windows(4).position(|w| w == b"stsz").expect("stsz") - 4;
        bytes[stsz..stsz + 4].fill(0);
        assert!(check(&bytes).expect("refused").contains("size 0 inside"));
        let mut bytes = file_with_stsz(0, 1);
        let mdat = bytes.windows(4).position(|w| w == b"mdat").expect("mdat") - 4;
        bytes[mdat..mdat + 4].fill(0);
        assert_eq!(check(&bytes), None);
    }

    #[test]
    fn a_panic_inside_is_an_error() {
        assert_eq!(quietly(|| 7), Ok(7));
        let caught: Result<(), ()> = quietly(|| {
            let empty: Vec<u8> = Vec::new();
            let _ = empty[usize::from(empty.is_empty())];
        });
        assert_eq!(caught, Err(()));
    }
}
