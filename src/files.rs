//! The lowest level of bytes on disk, shared by the renderer, the formats and the readers of
//! other people's files: PNG encoding ([`encode_png`], every colour type surgvla writes), atomic
//! file writes ([`write_atomically`]: a temporary `.name.partial` beside the file, renamed when
//! complete, so a crash never leaves a truncated file under its final name), the one way an
//! input file is opened ([`open_regular`]: regular files only, so a FIFO, socket or device never
//! blocks or feeds a reader), and reading ahead for readers that skip ([`ReadAhead`]: the
//! kernel's own read-ahead stops where reads are not in order; one that knows what it will
//! skip names only what it will read: [`ReadAhead::reading_spans`]). Imports nothing of the
//! crate.

mod pixels;

pub use pixels::{PngLevel, PngPixels};
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

/// `O_NONBLOCK`: opening a FIFO with it never waits for a writer (reads of a regular file are
/// unaffected).
#[cfg(target_os = "linux")]
const OPEN_NONBLOCKING: i32 = 0o4000;
#[cfg(target_os = "macos")]
const OPEN_NONBLOCKING: i32 = 0x0004;

/// Reads `buf.len()` bytes of `file` from byte `offset` on, without using (or moving) the
/// handle's position: threads may read through one handle at once, with no lock.
pub fn read_exact_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
    }
    #[cfg(windows)]
    {
        let mut done = 0;
        while done < buf.len() {
            let at = offset.saturating_add(done as u64);
            match std::os::windows::fs::FileExt::seek_read(file, &mut buf[done..], at)? {
                0 => return Err(std::io::ErrorKind::UnexpectedEof.into()),
                read => done += read,
            }
        }
        Ok(())
    }
}

/// Bytes a reader has the kernel read ahead of where it reads ([`ReadAhead`]).
pub const READ_AHEAD_BYTES: u64 = 4 << 20;

/// A reader's window of read-ahead in one file: the kernel is asked to bring the next
/// [`READ_AHEAD_BYTES`] the reader will read into the page cache in the background
/// ([`read_ahead`]), each byte once. A reader that skips parts of a file (an edit's dropped
/// episodes, the large columns it copies rather than reads) defeats the kernel's own
/// read-ahead, and each of its small reads would wait for the disk. One that knows the parts
/// it will skip names only those it will read ([`ReadAhead::reading_spans`]), so that what it
/// skips is not read from the disk.
#[derive(Clone, Copy, Debug, Default)]
pub struct ReadAhead {
    /// Where the file was asked to be read to.
    asked_to: u64,
}

impl ReadAhead {
    /// About to read `file` at byte `at`: asks for it to be read ahead up to
    /// [`READ_AHEAD_BYTES`] past `at` (not past `end`), leaving out what was asked before.
    /// Returns the span asked for, if any.
    pub fn reading(&mut self, file: &File, at: u64, end: u64) -> Option<std::ops::Range<u64>> {
        self.reading_spans(file, std::iter::once(at..end)).pop()
    }

    /// About to read `file` where the first of `spans` starts, and then the rest of them (in
    /// the file's order, the parts between them to be skipped): asks for the first
    /// [`READ_AHEAD_BYTES`] of them to be read ahead, leaving out what was asked before and
    /// what lies between them. Returns the spans asked for (adjacent ones as one).
    pub fn reading_spans(
        &mut self,
        file: &File,
        spans: impl IntoIterator<Item = std::ops::Range<u64>>,
    ) -> Vec<std::ops::Range<u64>> {
        let mut left = READ_AHEAD_BYTES;
        let mut asked: Vec<std::ops::Range<u64>> = Vec::new();
        for span in spans {
            if left == 0 {
                break;
            }
            let end = span.end.min(span.start.saturating_add(left));
            left -= end.saturating_sub(span.start);
            let from = self.asked_to.max(span.start);
            if end <= from {
                continue;
            }
            self.asked_to = end;
            match asked.last_mut() {
                Some(last) if last.end == from => last.end = end,
                _ => asked.push(from..end),
            }
        }
        for span in &asked {
            read_ahead(file, span.start, span.end - span.start);
        }
        asked
    }
}

/// Asks the kernel to bring `len` bytes of `file` from byte `offset` into the page cache in
/// the background (`posix_fadvise` WILLNEED), for reads that come soon. Advice only: an error
/// changes nothing, and other systems do nothing.
#[cfg(target_os = "linux")]
#[allow(unsafe_code)]
pub fn read_ahead(file: &File, offset: u64, len: u64) {
    use std::os::fd::AsRawFd;
    /// `POSIX_FADV_WILLNEED` (fcntl.h).
    const WILL_NEED: i32 = 3;
    unsafe extern "C" {
        fn posix_fadvise(fd: i32, offset: i64, len: i64, advice: i32) -> i32;
    }
    // (A length of 0 would mean "to the end of the file".)
    let (Ok(offset), Ok(len)) = (i64::try_from(offset), i64::try_from(len)) else {
        return;
    };
    if len > 0 {
        // SAFETY: posix_fadvise takes a descriptor and three integers and reads no memory of
        // ours; the descriptor is open for as long as `file` is borrowed.
        unsafe {
            posix_fadvise(file.as_raw_fd(), offset, len, WILL_NEED);
        }
    }
}

/// Other systems read ahead on their own terms.
#[cfg(not(target_os = "linux"))]
pub fn read_ahead(_file: &File, _offset: u64, _len: u64) {}

/// Opens `path` (links followed) for reading if it is a regular file. Anything else (a FIFO,
/// a socket, a device, a directory) is refused with [`std::io::ErrorKind::InvalidInput`]
/// before it is opened, as opening a FIFO waits for a writer for ever; the file is then opened
/// non-blocking and checked again, so one swapped in between cannot block either.
pub fn open_regular(path: &Path) -> std::io::Result<File> {
    let not_regular =
        || std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a regular file");
    if !std::fs::metadata(path)?.is_file() {
        return Err(not_regular());
    }
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(any(target_os = "linux", target_os = "macos"))]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(OPEN_NONBLOCKING);
    }
    let file = options.open(path)?;
    if !file.metadata()?.is_file() {
        return Err(not_regular());
    }
    Ok(file)
}

/// The bytes of the regular file `path` ([`open_regular`]).
pub fn read_regular(path: &Path) -> std::io::Result<Vec<u8>> {
    let mut file = open_regular(path)?;
    let mut bytes = Vec::with_capacity(file.metadata().map_or(0, |m| m.len() as usize));
    file.read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// The text of the regular file `path` ([`open_regular`]).
pub fn read_regular_to_string(path: &Path) -> std::io::Result<String> {
    String::from_utf8(read_regular(path)?)
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e.utf8_error()))
}

/// Encodes row-major `pixels` of `layout` as PNG; the sample count must fit the size.
pub fn encode_png(
    width: usize,
    height: usize,
    layout: PngPixels,
    pixels: &[u8],
    level: PngLevel,
) -> Result<Vec<u8>, png::EncodingError> {
    let mut out = Vec::with_capacity(pixels.len() / 2);
    encode_png_into(&mut out, width, height, layout, pixels, level)?;
    Ok(out)
}

/// [`encode_png`] appending to `out`.
pub fn encode_png_into(
    out: &mut Vec<u8>,
    width: usize,
    height: usize,
    layout: PngPixels,
    pixels: &[u8],
    level: PngLevel,
) -> Result<(), png::EncodingError> {
    if level == PngLevel::Fast
        && let Some(written) = fast_png::encode(out, width, height, layout, pixels)
    {
        return written;
    }
    let (colour, depth) = match layout {
        PngPixels::Grey8 => (png::ColorType::Grayscale, png::BitDepth::Eight),
        PngPixels::Rgb8 => (png::ColorType::Rgb, png::BitDepth::Eight),
        PngPixels::Rgba8 => (png::ColorType::Rgba, png::BitDepth::Eight),
        PngPixels::Grey16 => (png::ColorType::Grayscale, png::BitDepth::Sixteen),
    };
    let mut encoder = png::Encoder::new(out, width as u32, height as u32);
    encoder.set_color(colour);
    encoder.set_depth(depth);
    encoder.set_compression(match level {
        PngLevel::Fast => png::Compression::Fast,
        PngLevel::Default => png::Compression::Balanced,
        PngLevel::Best => png::Compression::High,
    });
    if level == PngLevel::Fast && matches!(layout, PngPixels::Rgb8 | PngPixels::Rgba8) {
        // Rendered colour: the Paeth filter on every row gives the adaptive choice's size
        // (34.9 kB a 224 x 224 frame either way) in 15 % less time (BENCHMARKS.md, issue 27).
        encoder.set_filter(png::Filter::Paeth);
    }
    let mut writer = encoder.write_header()?;
    writer.write_image_data(pixels)?;
    writer.finish()
}

mod fast_png;

/// The temporary name of `path` while it is being written (`.name.partial`).
pub fn temporary_name(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.partial"))
}

/// A file write that failed, naming the file (not its temporary name).
#[derive(Debug, thiserror::Error)]
#[error("writing {path}")]
pub struct WriteError {
    pub path: PathBuf,
    #[source]
    pub source: std::io::Error,
}

/// Writes `bytes` to `path` through a temporary name and a rename, in a folder that exists;
/// returns the size. On failure the temporary file is removed.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<u64, WriteError> {
    let temporary = temporary_name(path);
    std::fs::write(&temporary, bytes)
        .and_then(|()| std::fs::rename(&temporary, path))
        .map_err(|source| {
            let _ = std::fs::remove_file(&temporary);
            WriteError {
                path: path.to_path_buf(),
                source,
            }
        })?;
    Ok(bytes.len() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each byte is asked for once, never past the end given, from where the reader is.
    #[test]
    fn a_read_ahead_window_asks_for_each_byte_once() {
        let root = std::env::temp_dir().join(format!("surgvla-ahead-{}", std::process::id()));
        std::fs::create_dir_all(&root).unwrap();
        let path = root.join("f.bin");
        std::fs::write(&path, b"x").unwrap();
        let file = File::open(&path).unwrap();
        let window = READ_AHEAD_BYTES;
        let mut ahead = ReadAhead::default();
        assert_eq!(ahead.reading(&file, 0, u64::MAX), Some(0..window));
        assert_eq!(
            ahead.reading(&file, 10, u64::MAX),
            Some(window..window + 10)
        );
        assert_eq!(ahead.reading(&file, 10, u64::MAX), None, "asked already");
        // Capped at the end, then nothing more once the end is asked for.
        assert_eq!(
            ahead.reading(&file, 100, 500),
            None,
            "the end lies in what was asked"
        );
        assert_eq!(
            ahead.reading(&file, 3 * window, 3 * window + 7),
            Some(3 * window..3 * window + 7)
        );
        assert_eq!(ahead.reading(&file, 3 * window + 7, 3 * window + 7), None);
        // A reader that jumps back asks for nothing it asked for before.
        assert_eq!(ahead.reading(&file, 0, u64::MAX), None);
        std::fs::remove_dir_all(&root).unwrap();
    }

    /// Spans to be read are asked for up to a window's worth of their own bytes, what lies
    /// between them left out, adjacent ones in one piece, each byte once.
    #[test]
    fn a_read_ahead_of_spans_leaves_out_what_lies_between_them() {
        let root = std::env::temp_dir().join(format!("surgvla-spans-{}", std::process::id()));
        std::fs::create_dir_all(&root).unwrap();
        let path = root.join("f.bin");
        std::fs::write(&path, b"x").unwrap();
        let file = File::open(&path).unwrap();
        let mb = 1 << 20;
        assert_eq!(
            READ_AHEAD_BYTES,
            4 * mb,
            "the spans below are a window's worth"
        );
        let mut ahead = ReadAhead::default();
        let spans = [0..mb, 2 * mb..3 * mb, 3 * mb..4 * mb, 10 * mb..13 * mb];
        assert_eq!(
            ahead.reading_spans(&file, spans.clone()),
            vec![0..mb, 2 * mb..4 * mb, 10 * mb..11 * mb]
        );
        // Read on to the second: the window reaches 1 MiB further into the last.
        assert_eq!(
            ahead.reading_spans(&file, spans[1..].iter().cloned()),
            vec![11 * mb..12 * mb]
        );
        let first = std::iter::once(0..mb);
        assert_eq!(ahead.reading_spans(&file, first), vec![], "asked already");
        assert_eq!(ahead.reading_spans(&file, []), vec![]);
        std::fs::remove_dir_all(&root).unwrap();
    }

    /// The advice has the kernel read what it names: a page dropped from the page cache is
    /// back in it after [`read_ahead`], without being read.
    #[cfg(target_os = "linux")]
    #[test]
    fn read_ahead_brings_the_pages_it_names_into_the_page_cache() {
        let root = std::env::temp_dir().join(format!("surgvla-ahead-cache-{}", std::process::id()));
        std::fs::create_dir_all(&root).unwrap();
        let path = root.join("f.bin");
        std::fs::write(&path, vec![7u8; 16 << 20]).unwrap();
        let file = File::open(&path).unwrap();
        page_cache::drop(&file);
        let probe = 6 << 20;
        assert!(
            !page_cache::cached(&file, probe),
            "{} keeps a file's pages cached after DONTNEED: this test needs a disk-backed temporary folder",
            root.display()
        );
        read_ahead(&file, 5 << 20, 2 << 20);
        assert!(
            page_cache::comes_into(&file, probe, 20),
            "the page read ahead is not in the page cache"
        );
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn atomic_writes_leave_the_file_or_nothing() {
        let root = std::env::temp_dir().join(format!("surgvla-files-{}", std::process::id()));
        let path = root.join("a/b.bin");
        assert!(write_atomically(&path, b"abc").is_err(), "no folder a");
        std::fs::create_dir_all(root.join("a")).unwrap();
        assert_eq!(write_atomically(&path, b"abc").unwrap(), 3);
        assert_eq!(std::fs::read(&path).unwrap(), b"abc");
        assert!(!temporary_name(&path).exists());
        let blocked = root.join("a/b.bin/c.bin");
        let error = write_atomically(&blocked, b"x").unwrap_err();
        assert_eq!(error.path, blocked);
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn png_layouts_round_trip_their_size() {
        for (layout, bytes) in [
            (PngPixels::Grey8, 6),
            (PngPixels::Rgb8, 18),
            (PngPixels::Rgba8, 24),
            (PngPixels::Grey16, 12),
        ] {
            assert_eq!(layout.bytes() * 6, bytes);
            let png = encode_png(3, 2, layout, &vec![7; bytes], PngLevel::Fast).unwrap();
            assert_eq!(&png[1..4], b"PNG");
        }
        assert!(encode_png(3, 2, PngPixels::Rgb8, &[0; 5], PngLevel::Fast).is_err());
    }
}

/// The page cache as tests see it: a file's pages dropped from it, and whether one is in it
/// (`mincore` of a mapping of the file, which reads nothing).
#[cfg(test)]
#[cfg(target_os = "linux")]
#[allow(unsafe_code)]
pub(crate) mod page_cache {
    use std::fs::File;
    use std::os::fd::AsRawFd;

    unsafe extern "C" {
        fn posix_fadvise(fd: i32, offset: i64, len: i64, advice: i32) -> i32;
        fn mmap(at: *mut u8, len: usize, prot: i32, flags: i32, fd: i32, offset: i64) -> *mut u8;
        fn mincore(at: *mut u8, len: usize, resident: *mut u8) -> i32;
        fn munmap(at: *mut u8, len: usize) -> i32;
        fn sysconf(name: i32) -> i64;
    }
    const DONT_NEED: i32 = 4;
    const PROT_READ: i32 = 1;
    const MAP_SHARED: i32 = 1;
    const PAGE_SIZE: i32 = 30;

    /// Writes `file`'s dirty pages and drops all of them from the page cache.
    pub(crate) fn drop(file: &File) {
        file.sync_all().expect("sync");
        // SAFETY: a descriptor and integers; no memory of ours is read.
        unsafe { posix_fadvise(file.as_raw_fd(), 0, 0, DONT_NEED) };
    }

    /// Whether the page holding byte `offset` of `file` is in the page cache.
    pub(crate) fn cached(file: &File, offset: u64) -> bool {
        // SAFETY: sysconf takes an integer and reads no memory of ours.
        let page = usize::try_from(unsafe { sysconf(PAGE_SIZE) }).expect("page size");
        let len = usize::try_from(file.metadata().expect("metadata").len()).expect("length");
        let mut resident = vec![0u8; len.div_ceil(page)];
        // SAFETY: a read-only mapping of the whole open file, never dereferenced, unmapped
        // before returning; `resident` has one byte per page of it.
        unsafe {
            let at = mmap(
                std::ptr::null_mut(),
                len,
                PROT_READ,
                MAP_SHARED,
                file.as_raw_fd(),
                0,
            );
            assert!(!at.is_null() && at as isize != -1, "mmap");
            assert_eq!(mincore(at, len, resident.as_mut_ptr()), 0, "mincore");
            munmap(at, len);
        }
        let index = usize::try_from(offset).expect("offset") / page;
        resident.get(index).is_some_and(|r| r & 1 == 1)
    }

    /// Whether the page holding byte `offset` comes into the page cache within `secs` seconds
    /// (a read-ahead is done in the background).
    pub(crate) fn comes_into(file: &File, offset: u64, secs: u64) -> bool {
        let asked = std::time::Instant::now();
        while !cached(file, offset) {
            if asked.elapsed() > std::time::Duration::from_secs(secs) {
                return false;
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        true
    }
}
