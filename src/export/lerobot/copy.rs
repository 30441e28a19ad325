//! A data file written row group by row group, where a row group is either encoded from
//! arrays ([`DataFile::write_batch`], what `ArrowWriter` does) or copied from a row group the
//! reader left in its file ([`DataFile::copy_group`]): every column chunk but the default
//! columns' copied as stored (compressed, with its page index), the default columns
//! (timestamps, frame, episode, dataset and task indices) encoded for the episode's new place.
//! No pixel is decompressed, decoded or compressed again.
//!
//! The reader offers a group for copying ([`StoredGroup`]) only when its file's columns have
//! the types this writer gives them ([`matches_writer`]), so that a copied chunk reads as the
//! writer's own would.

use super::table::DEFAULT_COLUMNS;
use crate::episode::StoredRows;
use crate::export::dir::{Checksummed, WrittenBehind};
use arrow_array::{ArrayRef, RecordBatch};
use arrow_schema::SchemaRef;
use bytes::{Buf, Bytes};
use parquet::arrow::ArrowSchemaConverter;
use parquet::arrow::arrow_writer::{ArrowRowGroupWriterFactory, compute_leaves};
use parquet::basic::Compression;
use parquet::column::writer::ColumnCloseResult;
use parquet::errors::ParquetError;
use parquet::file::metadata::{ColumnChunkMetaData, ParquetMetaData};
use parquet::file::reader::{ChunkReader, Length};
use parquet::file::writer::SerializedFileWriter;
use parquet::schema::types::{ColumnDescPtr, ColumnDescriptor, SchemaDescriptor};
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::sync::Arc;

/// A data file's bytes go out a mebibyte at a time: the parquet writer passes copied chunks on
/// 8 KiB at a time, a system call each without this buffer.
const WRITE_BUFFER_BYTES: usize = 1 << 20;

/// The default columns whose values differ from row to row within an episode, which a copied
/// group stores without a dictionary.
const DISTINCT_PER_ROW: [&str; 3] = ["timestamp", "frame_index", "index"];

/// Where an episode's rows are stored: one whole row group of a data file (its footer read
/// with the page index).
pub(super) struct StoredGroup {
    pub(super) file: Arc<Path>,
    /// The file, opened once by the reader for every group copied from it (its own handle,
    /// read at offsets: [`crate::files::read_exact_at`]).
    pub(super) handle: Arc<File>,
    pub(super) metadata: Arc<ParquetMetaData>,
    pub(super) row_group: usize,
}

impl StoredGroup {
    /// The group's rows.
    pub(super) fn rows(&self) -> u64 {
        (self.metadata.row_groups().get(self.row_group))
            .map_or(0, |g| u64::try_from(g.num_rows()).unwrap_or(0))
    }
}

/// A data file being written (see the module overview).
pub(super) struct DataFile {
    writer: SerializedFileWriter<BufWriter<Checksummed<WrittenBehind>>>,
    factory: ArrowRowGroupWriterFactory,
    schema: SchemaRef,
    groups: usize,
    /// The writers of the default columns alone, for a copied group (making a writer for every
    /// column, a compressor each, cost more than encoding the default columns).
    defaults: DefaultColumns,
    /// The buffer the last copied group's bytes were read into, kept for the next one's (a
    /// new one would be zeroed first, each time).
    spare: Vec<u8>,
}

/// The default columns of a data file's schema, with a factory of their column writers alone
/// (the same properties: the chunks they make are the whole file's writer's).
struct DefaultColumns {
    factory: ArrowRowGroupWriterFactory,
    /// Per default column, in schema order: its place in [`DEFAULT_COLUMNS`], its field, and
    /// its first leaf among the file's.
    columns: Vec<(usize, arrow_schema::FieldRef, usize)>,
    /// Leaves in the file's schema.
    leaves: usize,
}

impl DefaultColumns {
    fn new(
        schema: &SchemaRef,
        properties: parquet::file::properties::WriterProperties,
    ) -> Result<Self, ParquetError> {
        let mut columns = Vec::new();
        let mut leaves = 0;
        for field in schema.fields() {
            if let Some(place) = DEFAULT_COLUMNS.iter().position(|d| d == field.name()) {
                columns.push((place, field.clone(), leaves));
            }
            leaves += leaf_count(field.data_type());
        }
        let fields: Vec<arrow_schema::FieldRef> =
            columns.iter().map(|(_, f, _)| f.clone()).collect();
        // Stored without compression: a zstd codec costs more to make (its contexts ask the
        // CPU for its features, which a virtual machine answers slowly) than a copied episode's
        // few hundred bytes of indices gain from it. Columns whose values differ row by row
        // (the timestamp, frame and dataset indices) are stored plain: a dictionary of every
        // value is larger than the values, and slower to build.
        let properties = (fields.iter()).fold(properties.into_builder(), |builder, field| {
            let column = parquet::schema::types::ColumnPath::new(vec![field.name().clone()]);
            let distinct = DISTINCT_PER_ROW.contains(&field.name().as_str());
            (builder.set_column_compression(column.clone(), Compression::UNCOMPRESSED))
                .set_column_dictionary_enabled(column, !distinct)
        });
        let alone = Arc::new(arrow_schema::Schema::new(fields));
        let writer =
            parquet::arrow::ArrowWriter::try_new(std::io::sink(), alone, Some(properties.build()))?;
        let (_, factory) = writer.into_serialized_writer()?;
        Ok(DefaultColumns {
            factory,
            columns,
            leaves,
        })
    }

    /// The chunks of one row group's leaves (None for every leaf but the default columns'):
    /// `defaults`, in [`DEFAULT_COLUMNS`] order, encoded for row group `group`.
    fn encode(
        &self,
        group: usize,
        defaults: &[ArrayRef],
    ) -> Result<Vec<Option<Chunk>>, ParquetError> {
        let mut chunks: Vec<Option<Chunk>> = (0..self.leaves).map(|_| None).collect();
        let mut writers = self.factory.create_column_writers(group)?.into_iter();
        for (place, field, first_leaf) in &self.columns {
            let column = defaults.get(*place).ok_or_else(|| {
                ParquetError::General(format!("no values for default column {}", field.name()))
            })?;
            for (k, leaf) in compute_leaves(field, column)?.into_iter().enumerate() {
                let mut writer = (writers.next())
                    .ok_or_else(|| ParquetError::General("more leaves than columns".into()))?;
                writer.write(&leaf)?;
                let slot = chunks
                    .get_mut(first_leaf + k)
                    .ok_or_else(|| ParquetError::General("a leaf past the schema's".into()))?;
                *slot = Some(Chunk::Encoded(Box::new(writer.close()?)));
            }
        }
        Ok(chunks)
    }
}

/// A column chunk of a row group being put together.
enum Chunk {
    Encoded(Box<parquet::arrow::arrow_writer::ArrowColumnChunk>),
    Copied(Box<ColumnCloseResult>),
}

impl DataFile {
    /// Writes `file` as `ArrowWriter` would with `properties` (its Arrow schema in the
    /// footer), the writer taken apart.
    pub(super) fn create(
        file: File,
        schema: SchemaRef,
        properties: parquet::file::properties::WriterProperties,
    ) -> Result<Self, ParquetError> {
        let output = BufWriter::with_capacity(
            WRITE_BUFFER_BYTES,
            Checksummed::new(WrittenBehind::new(file)),
        );
        let defaults = DefaultColumns::new(&schema, properties.clone())?;
        let writer =
            parquet::arrow::ArrowWriter::try_new(output, schema.clone(), Some(properties))?;
        let (writer, factory) = writer.into_serialized_writer()?;
        Ok(DataFile {
            writer,
            factory,
            schema,
            groups: 0,
            defaults,
            spare: Vec::new(),
        })
    }

    pub(super) fn bytes_written(&self) -> usize {
        self.writer.bytes_written()
    }

    /// Writes the footer and closes the file; returns its size and CRC-32C (for
    /// [`crate::export::dir::DatasetDir::commit_summed`]).
    pub(super) fn close(self) -> Result<(u64, u32), ParquetError> {
        let buffered = self.writer.into_inner()?;
        let summed = (buffered.into_inner())
            .map_err(|e| ParquetError::External(Box::new(e.into_error())))?;
        summed
            .finish()
            .map_err(|e| ParquetError::External(Box::new(e)))
    }

    /// Appends `batch` as a row group of its own, encoded (the bytes `ArrowWriter::write` and
    /// `flush` give).
    pub(super) fn write_batch(&mut self, batch: &RecordBatch) -> Result<(), ParquetError> {
        write_group(
            &mut self.writer,
            &self.factory,
            &self.schema,
            batch,
            self.groups,
        )?;
        self.groups += 1;
        Ok(())
    }

    /// Appends `stored`'s row group, its columns named as `rows` says: the default columns
    /// encoded from `defaults` (in [`DEFAULT_COLUMNS`] order), every other column copied.
    pub(super) fn copy_group(
        &mut self,
        stored: &StoredGroup,
        rows: &StoredRows,
        defaults: &[ArrayRef],
    ) -> Result<(), ParquetError> {
        let mut chunks = self.defaults.encode(self.groups, defaults)?;
        let input = stored.metadata.file_metadata().schema_descr();
        let group = (stored.metadata.row_groups().get(stored.row_group))
            .ok_or_else(|| ParquetError::General(format!("no row group {}", stored.row_group)))?;
        let output = self.writer.schema_descr();
        for (leaf, chunk_slot) in chunks.iter_mut().enumerate() {
            if chunk_slot.is_some() {
                continue;
            }
            let descr = output.column(leaf);
            let parts = descr.path().parts();
            let stored_name = (parts.first())
                .and_then(|name| rows.column_of(name))
                .ok_or_else(|| {
                    ParquetError::General(format!("no stored column for {}", descr.path()))
                })?;
            let found = (0..input.num_columns()).find(|&j| {
                let theirs = input.column(j);
                let theirs = theirs.path().parts();
                theirs.first().map(String::as_str) == Some(stored_name) && theirs[1..] == parts[1..]
            });
            let Some(j) = found.filter(|&j| same_leaf(&input.column(j), &descr)) else {
                return Err(ParquetError::General(format!(
                    "the stored rows have no column {stored_name} of {}'s type",
                    descr.path()
                )));
            };
            let chunk = group.column(j);
            // The page index travels with the chunk when it points inside it (the input's word).
            let offset_index = of_group(stored.metadata.offset_index(), stored.row_group, j)
                .filter(|index| pages_inside(index, chunk));
            let column_index = offset_index
                .as_ref()
                .and_then(|_| of_group(stored.metadata.column_index(), stored.row_group, j));
            *chunk_slot = Some(Chunk::Copied(Box::new(ColumnCloseResult {
                bytes_written: u64::try_from(chunk.compressed_size()).unwrap_or(0),
                rows_written: stored.rows(),
                metadata: renamed(chunk, descr)?,
                bloom_filter: None,
                column_index,
                offset_index,
            })));
        }
        let region = Region::read(stored, &chunks, std::mem::take(&mut self.spare))?;
        let appended = self.append(chunks, &region);
        self.spare = region.into_buffer();
        appended
    }

    /// Appends one row group of `chunks` (every leaf's, in order); copied ones are read from
    /// `input`.
    fn append(&mut self, chunks: Vec<Option<Chunk>>, input: &Region) -> Result<(), ParquetError> {
        let mut group = self.writer.next_row_group()?;
        for chunk in chunks {
            match chunk {
                Some(Chunk::Encoded(chunk)) => chunk.append_to_row_group(&mut group)?,
                Some(Chunk::Copied(close)) => group.append_column(input, *close)?,
                None => return Err(ParquetError::General("a column chunk missing".into())),
            }
        }
        group.close()?;
        self.groups += 1;
        Ok(())
    }
}

/// Appends `batch` as row group `group` of a file of `schema`, its columns encoded in parallel
/// (the episodes table has hundreds of small ones): the bytes `ArrowWriter::write` and `flush`
/// give.
pub(super) fn write_group<W: std::io::Write + Send>(
    writer: &mut parquet::file::writer::SerializedFileWriter<W>,
    factory: &ArrowRowGroupWriterFactory,
    schema: &arrow_schema::Schema,
    batch: &RecordBatch,
    group: usize,
) -> Result<(), ParquetError> {
    use rayon::prelude::*;
    let mut leaves = Vec::new();
    for (field, column) in schema.fields().iter().zip(batch.columns()) {
        leaves.extend(compute_leaves(field, column)?);
    }
    let columns = factory.create_column_writers(group)?;
    if columns.len() != leaves.len() {
        return Err(ParquetError::General(format!(
            "{} leaves for {} columns",
            leaves.len(),
            columns.len()
        )));
    }
    let chunks = (columns.into_par_iter())
        .zip(leaves)
        .map(|(mut column, leaf)| {
            column.write(&leaf)?;
            column.close()
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut row_group = writer.next_row_group()?;
    for chunk in chunks {
        chunk.append_to_row_group(&mut row_group)?;
    }
    row_group.close()?;
    Ok(())
}

/// Where `chunks` lie in their file, in bytes: from the first one's start (its dictionary page,
/// if any) to the last one's end; empty for no chunks. Offsets a footer gives negative count as
/// 0 (a footer is checked when read: `footer_problem`).
pub(super) fn chunks_span<'a>(
    chunks: impl IntoIterator<Item = &'a ColumnChunkMetaData>,
) -> std::ops::Range<u64> {
    let spans = chunks.into_iter().map(|c| {
        let start = c.dictionary_page_offset().unwrap_or(c.data_page_offset());
        let start = u64::try_from(start).unwrap_or(0);
        let size = u64::try_from(c.compressed_size()).unwrap_or(0);
        start..start.saturating_add(size)
    });
    let (start, end) = spans.fold((u64::MAX, 0), |(a, b), c| (a.min(c.start), b.max(c.end)));
    start.min(end)..end
}

/// The bytes of a row group's copied chunks, read in one go (the parquet writer asks for each
/// chunk by its offset in the file).
struct Region {
    /// Where the bytes start in the file.
    start: u64,
    /// The buffer they were read into: they are its first `length` bytes.
    bytes: Bytes,
    length: usize,
}

impl Region {
    /// The span of `chunks`' copied ones in `stored`'s file (checked to lie inside the file
    /// when its footer was read), read into `buffer` (grown as needed, its bytes past the span
    /// left as they were).
    fn read(
        stored: &StoredGroup,
        chunks: &[Option<Chunk>],
        buffer: Vec<u8>,
    ) -> Result<Region, ParquetError> {
        let copied = chunks.iter().filter_map(|c| match c {
            Some(Chunk::Copied(close)) => Some(&close.metadata),
            _ => None,
        });
        let span = chunks_span(copied);
        let length = usize::try_from(span.end - span.start).unwrap_or(0);
        Region::read_span(&stored.handle, span.start, length, buffer)
    }

    /// `length` bytes of `file` from `start`, read into `buffer` (grown as needed).
    fn read_span(
        file: &File,
        start: u64,
        length: usize,
        mut buffer: Vec<u8>,
    ) -> Result<Region, ParquetError> {
        if buffer.len() < length {
            buffer.resize(length, 0);
        }
        if length > 0 {
            crate::files::read_exact_at(file, &mut buffer[..length], start)?;
        }
        Ok(Region {
            start,
            bytes: Bytes::from(buffer),
            length,
        })
    }

    /// The buffer back, once the bytes handed out are gone (empty if one is still held).
    fn into_buffer(self) -> Vec<u8> {
        self.bytes.try_into_mut().map(Vec::from).unwrap_or_default()
    }

    /// `length` bytes from file offset `start`.
    fn slice(&self, start: u64, length: usize) -> Result<Bytes, ParquetError> {
        let from = (start.checked_sub(self.start)).and_then(|f| usize::try_from(f).ok());
        let range = from.and_then(|from| Some(from..from.checked_add(length)?));
        match range.filter(|r| r.end <= self.length) {
            Some(range) => Ok(self.bytes.slice(range)),
            None => Err(ParquetError::EOF(format!(
                "{length} bytes at {start} lie outside the {} read at {}",
                self.length, self.start
            ))),
        }
    }
}

impl Length for Region {
    fn len(&self) -> u64 {
        self.start + self.length as u64
    }
}

impl ChunkReader for Region {
    type T = bytes::buf::Reader<Bytes>;

    fn get_read(&self, start: u64) -> Result<Self::T, ParquetError> {
        let rest = self.len().saturating_sub(start);
        Ok(self
            .slice(start, usize::try_from(rest).unwrap_or(0))?
            .reader())
    }

    fn get_bytes(&self, start: u64, length: usize) -> Result<Bytes, ParquetError> {
        self.slice(start, length)
    }
}

/// Row group `group`'s entry for column `column` in a page index.
fn of_group<T: Clone>(all: Option<&Vec<Vec<T>>>, group: usize, column: usize) -> Option<T> {
    all?.get(group)?.get(column).cloned()
}

/// Whether every page `index` locates lies inside `chunk`'s bytes.
fn pages_inside(
    index: &parquet::file::page_index::offset_index::OffsetIndexMetaData,
    chunk: &ColumnChunkMetaData,
) -> bool {
    let start = chunk
        .dictionary_page_offset()
        .unwrap_or_else(|| chunk.data_page_offset());
    let end = start.saturating_add(chunk.compressed_size());
    index.page_locations().iter().all(|page| {
        let size = i64::from(page.compressed_page_size);
        page.offset >= start && size >= 0 && page.offset.saturating_add(size) <= end
    })
}

/// The parquet leaves a field of `data_type` has (structs: one per field, nested).
fn leaf_count(data_type: &arrow_schema::DataType) -> usize {
    use arrow_schema::DataType;
    match data_type {
        DataType::Struct(fields) => fields.iter().map(|f| leaf_count(f.data_type())).sum(),
        DataType::List(f)
        | DataType::LargeList(f)
        | DataType::FixedSizeList(f, _)
        | DataType::Map(f, _) => leaf_count(f.data_type()),
        _ => 1,
    }
}

/// Two leaves store values alike (type, levels, annotations), whatever their names.
fn same_leaf(a: &ColumnDescriptor, b: &ColumnDescriptor) -> bool {
    a.physical_type() == b.physical_type()
        && a.max_def_level() == b.max_def_level()
        && a.max_rep_level() == b.max_rep_level()
        && a.logical_type_ref() == b.logical_type_ref()
        && a.converted_type() == b.converted_type()
        && a.type_length() == b.type_length()
}

/// `chunk`'s metadata for the column `descr` (its name now): everything else as stored.
fn renamed(
    chunk: &ColumnChunkMetaData,
    descr: ColumnDescPtr,
) -> Result<ColumnChunkMetaData, ParquetError> {
    let mut builder = ColumnChunkMetaData::builder(descr)
        .set_compression_codec(chunk.compression_codec())
        .set_encodings_mask(*chunk.encodings_mask())
        .set_total_compressed_size(chunk.compressed_size())
        .set_total_uncompressed_size(chunk.uncompressed_size())
        .set_num_values(chunk.num_values())
        .set_data_page_offset(chunk.data_page_offset())
        .set_dictionary_page_offset(chunk.dictionary_page_offset())
        .set_unencoded_byte_array_data_bytes(chunk.unencoded_byte_array_data_bytes())
        .set_repetition_level_histogram(chunk.repetition_level_histogram().cloned())
        .set_definition_level_histogram(chunk.definition_level_histogram().cloned());
    if let Some(statistics) = chunk.statistics() {
        // Columns that sort signed also get the deprecated `min` and `max` from parquet's
        // writers, which reading a footer does not remember.
        let signed = chunk.column_descr().sort_order().is_signed();
        builder = builder.set_statistics(with_old_min_max(statistics.clone(), signed));
    }
    if let Some(stats) = chunk.page_encoding_stats() {
        builder = builder.set_page_encoding_stats(stats.clone());
    }
    if let Some(mask) = chunk.page_encoding_stats_mask() {
        builder = builder.set_page_encoding_stats_mask(*mask);
    }
    builder.build()
}

/// `statistics` written with the deprecated `min` and `max` too when `old` (as the column
/// writer that made them wrote them).
fn with_old_min_max(
    statistics: parquet::file::statistics::Statistics,
    old: bool,
) -> parquet::file::statistics::Statistics {
    use parquet::file::statistics::Statistics as S;
    match statistics {
        S::Boolean(v) => S::Boolean(v.with_backwards_compatible_min_max(old)),
        S::Int32(v) => S::Int32(v.with_backwards_compatible_min_max(old)),
        S::Int64(v) => S::Int64(v.with_backwards_compatible_min_max(old)),
        S::Int96(v) => S::Int96(v.with_backwards_compatible_min_max(old)),
        S::Float(v) => S::Float(v.with_backwards_compatible_min_max(old)),
        S::Double(v) => S::Double(v.with_backwards_compatible_min_max(old)),
        S::ByteArray(v) => S::ByteArray(v.with_backwards_compatible_min_max(old)),
        S::FixedLenByteArray(v) => S::FixedLenByteArray(v.with_backwards_compatible_min_max(old)),
    }
}

/// Whether `input`'s columns store every non-default column of `writer_schema` (what the writer
/// writes for the features) as the writer does, by name: then its row groups can be copied.
pub(super) fn matches_writer(
    input: &SchemaDescriptor,
    writer_schema: &arrow_schema::Schema,
) -> bool {
    let Ok(expected) = ArrowSchemaConverter::new().convert(writer_schema) else {
        return false;
    };
    expected.columns().iter().all(|want| {
        let parts = want.path().parts();
        if parts
            .first()
            .is_some_and(|name| DEFAULT_COLUMNS.contains(&name.as_str()))
        {
            return true;
        }
        input
            .columns()
            .iter()
            .any(|have| have.path().parts() == parts && same_leaf(have, want))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// The span of chunks runs from the first one's dictionary page (or its data, without one)
    /// to the last byte of any of them, whatever their order; no chunks span nothing.
    #[test]
    fn chunks_span_from_the_first_page_to_the_last_byte() {
        let schema = parquet::schema::parser::parse_message_type(
            "message m { required int64 a; required int64 b; required int64 c; }",
        )
        .expect("schema");
        let descr = SchemaDescriptor::new(Arc::new(schema));
        let chunk = |leaf: usize, dictionary: Option<i64>, data: i64, size: i64| {
            ColumnChunkMetaData::builder(descr.column(leaf))
                .set_dictionary_page_offset(dictionary)
                .set_data_page_offset(data)
                .set_total_compressed_size(size)
                .build()
                .expect("chunk")
        };
        let (a, b, c) = (
            chunk(0, None, 4, 100),
            chunk(1, Some(104), 150, 96),
            chunk(2, None, 200, 10),
        );
        assert_eq!(chunks_span([&a, &b, &c]), 4..210);
        assert_eq!(
            chunks_span([&c, &b]),
            104..210,
            "the dictionary page starts b"
        );
        assert_eq!(chunks_span([&b, &a]), 4..200);
        assert_eq!(chunks_span([&a]), 4..104);
        assert!(chunks_span(std::iter::empty()).is_empty());
    }

    /// A region read into the last one's buffer holds its own bytes alone (not the longer
    /// last one's past them), and gives the buffer back for the next.
    #[test]
    fn a_region_reuses_its_buffer_and_reads_only_its_span() {
        let path = std::env::temp_dir().join(format!("surgvla-region-{}", std::process::id()));
        let content: Vec<u8> = (0..=255u8).cycle().take(4096).collect();
        std::fs::write(&path, &content).expect("write");
        let file = File::open(&path).expect("open");
        std::fs::remove_file(&path).expect("removed (still open)");
        let mut buffer = Vec::new();
        for (start, length) in [(100u64, 3000usize), (7, 10), (0, 0), (4000, 96), (1, 4095)] {
            let region = Region::read_span(&file, start, length, buffer).expect("read");
            assert_eq!(region.len(), start + length as u64);
            let at = usize::try_from(start).expect("small");
            let whole = region.get_bytes(start, length).expect("inside");
            assert_eq!(&whole[..], &content[at..at + length]);
            let mut read = Vec::new();
            std::io::Read::read_to_end(&mut region.get_read(start).expect("reader"), &mut read)
                .expect("read");
            assert_eq!(read, &content[at..at + length], "nothing past the span");
            assert!(region.get_bytes(start, length + 1).is_err());
            assert!(region.get_bytes(start.wrapping_sub(1), 1).is_err());
            drop((whole, read));
            buffer = region.into_buffer();
            assert!(buffer.len() >= length, "the buffer comes back");
        }
    }
    use arrow_array::{BinaryArray, Int64Array};
    use arrow_schema::{DataType, Field, Schema};
    use parquet::arrow::arrow_reader::{ArrowReaderMetadata, ArrowReaderOptions};
    use parquet::file::metadata::PageIndexPolicy;

    fn schema(image: &str) -> SchemaRef {
        let mut fields = vec![Field::new(image, DataType::Binary, true)];
        fields.extend(
            DEFAULT_COLUMNS
                .iter()
                .map(|c| Field::new(*c, DataType::Int64, true)),
        );
        Arc::new(Schema::new(fields))
    }

    fn batch(schema: &SchemaRef, rng: &mut SplitMix64, rows: usize, first: i64) -> RecordBatch {
        let images: Vec<Vec<u8>> = (0..rows)
            .map(|_| (0..300).map(|_| (rng.next_u64() % 7) as u8).collect())
            .collect();
        let mut columns: Vec<ArrayRef> =
            vec![Arc::new(BinaryArray::from_iter_values(images.iter()))];
        for c in 0..DEFAULT_COLUMNS.len() as i64 {
            columns.push(Arc::new(Int64Array::from_iter_values(
                (0..rows as i64).map(|r| first + r * c),
            )));
        }
        RecordBatch::try_new(schema.clone(), columns).expect("batch")
    }

    fn data_file(path: &Path, schema: &SchemaRef) -> DataFile {
        let file = File::create(path).expect("create");
        DataFile::create(file, schema.clone(), Default::default()).expect("data file")
    }

    fn metadata(path: &Path) -> Arc<ParquetMetaData> {
        let file = File::open(path).expect("open");
        let options = ArrowReaderOptions::new()
            .with_page_index_policy(PageIndexPolicy::Required)
            .with_encoding_stats_as_mask(false);
        ArrowReaderMetadata::load(&file, options)
            .expect("footer")
            .metadata()
            .clone()
    }

    fn read(path: &Path) -> Vec<RecordBatch> {
        let file = File::open(path).expect("open");
        parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file)
            .expect("reader")
            .build()
            .expect("build")
            .collect::<Result<_, _>>()
            .expect("batches")
    }

    #[test]
    fn a_copied_row_group_reads_as_its_source_renamed_with_new_default_columns() {
        let dir = std::env::temp_dir().join(format!("surgvla-copy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let (input, output) = (dir.join("in.parquet"), dir.join("out.parquet"));
        let mut rng = SplitMix64::new(7);
        let theirs = schema("depth");
        let mut file = data_file(&input, &theirs);
        let groups = [
            batch(&theirs, &mut rng, 40, 0),
            batch(&theirs, &mut rng, 25, 100),
        ];
        for group in &groups {
            file.write_batch(group).expect("write");
        }
        file.close().expect("close");
        // The second group copied under a new name, its default columns made anew; an encoded
        // group before it, so that the copy lands at another offset.
        let ours = schema("observation.depth");
        let mut out = data_file(&output, &ours);
        let fresh = batch(&ours, &mut rng, 10, 500);
        out.write_batch(&fresh).expect("write");
        let stored = StoredGroup {
            file: Arc::from(input.as_path()),
            handle: Arc::new(File::open(&input).expect("open")),
            metadata: metadata(&input),
            row_group: 1,
        };
        assert_eq!(stored.rows(), 25);
        let rows = StoredRows {
            columns: vec![("depth".into(), "observation.depth".into())],
            handle: Arc::new(()),
        };
        let defaults = batch(&ours, &mut rng, 25, 1000).columns()[1..].to_vec();
        out.copy_group(&stored, &rows, &defaults).expect("copy");
        out.close().expect("close");

        let read_back = read(&output);
        assert_eq!(read_back.len(), 1, "35 rows come in one batch");
        let all = &read_back[0];
        assert_eq!(all.num_rows(), 35);
        let copied = all.slice(10, 25);
        assert_eq!(copied.column(0), groups[1].column(0), "the copied column");
        assert_eq!(
            &copied.columns()[1..],
            &defaults[..],
            "the default columns made anew"
        );
        assert_eq!(all.slice(0, 10).columns(), fresh.columns());
        // The copied chunk's bytes are the input's, and its page index came along.
        let copied_meta = metadata(&output);
        let (a, b) = (
            stored.metadata.row_group(1).column(0),
            copied_meta.row_group(1).column(0),
        );
        let bytes = |path: &Path, chunk: &ColumnChunkMetaData| {
            let all = std::fs::read(path).expect("read");
            let start = chunk
                .dictionary_page_offset()
                .unwrap_or(chunk.data_page_offset()) as usize;
            all[start..start + chunk.compressed_size() as usize].to_vec()
        };
        assert_eq!(bytes(&input, a), bytes(&output, b));
        let offsets = copied_meta.offset_index().expect("offset index");
        let pages = offsets[1][0].page_locations();
        assert!(!pages.is_empty());
        assert!(pages[0].offset >= b.data_page_offset());
        assert!(
            copied_meta
                .column_index()
                .is_some_and(|c| c[1].len() == DEFAULT_COLUMNS.len() + 1)
        );
        // A stored column of another type is refused, not copied.
        let wrong = StoredRows {
            columns: vec![("frame_index".into(), "observation.depth".into())],
            handle: Arc::new(()),
        };
        let mut out = data_file(&dir.join("wrong.parquet"), &ours);
        assert!(out.copy_group(&stored, &wrong, &defaults).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn files_match_the_writer_by_name_and_type() {
        let theirs = ArrowSchemaConverter::new()
            .convert(&schema("depth"))
            .expect("schema");
        assert!(matches_writer(&theirs, &schema("depth")));
        assert!(!matches_writer(&theirs, &schema("observation.depth")));
        let mut fields: Vec<Field> = (schema("depth").fields().iter())
            .map(|f| f.as_ref().clone())
            .collect();
        fields[0] = Field::new("depth", DataType::Utf8, true);
        assert!(!matches_writer(&theirs, &Schema::new(fields)));
    }
}
