//! `surgvla validate` and `info` on a corpus of broken datasets made from good ones: each defect
//! class is found by content checks (the manifest is removed first, so checksums cannot be what
//! finds it) and named with its file, episode and check; good datasets, and a byte-differently
//! rewritten good one, pass; exit codes 0 / 1 / 2; and a seeded random-corruption test over
//! every format's reader, which must never panic.

use crate::util::{surgvla, temp_root, tree};
use arrow_array::{
    Array, ArrayRef, BinaryArray, FixedSizeListArray, Float32Array, Int64Array, RecordBatch,
    StructArray,
};
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use surgvla::export::validate::{Report, ValidateOptions, validate};

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// The good datasets, made once: LeRobot v3.0, v2.1, RLDS, zarr, MCAP (2 episodes).
struct Corpus {
    lerobot: PathBuf,
    lerobot21: PathBuf,
    rlds: PathBuf,
    zarr: PathBuf,
    mcap: PathBuf,
    /// LeRobot v3.0 in video mode (H.264).
    video: PathBuf,
}

fn corpus() -> &'static Corpus {
    static CORPUS: OnceLock<Corpus> = OnceLock::new();
    CORPUS.get_or_init(|| {
        let root = crate::util::shared_root("validate-corpus");
        let lerobot = root.join("lerobot");
        let small = ["--tasks", "T1-1,T3-1", "--episodes-per-task", "1"];
        let run = |args: &[&str]| {
            let (code, _, err) = surgvla(args);
            assert_eq!(code, 0, "{args:?}: {err}");
        };
        let mut args = vec!["collect", "--out", path(&lerobot)];
        args.extend(small);
        run(&args);
        let lerobot21 = root.join("lerobot21");
        let mut args = vec![
            "collect",
            "--out",
            path(&lerobot21),
            "--lerobot-version",
            "2.1",
        ];
        args.extend(small);
        run(&args);
        let convert = |to: &str, name: &str| {
            let out = root.join(name);
            run(&["convert", path(&lerobot), "--to", to, "--out", path(&out)]);
            out
        };
        let rlds = convert("rlds", "rlds");
        let zarr = convert("zarr", "zarr");
        let mcap = convert("mcap", "mcap");
        let video = root.join("video");
        let mut args = vec!["collect", "--out", path(&video), "--video", "h264"];
        args.extend(small);
        run(&args);
        Corpus {
            lerobot,
            lerobot21,
            rlds,
            zarr,
            mcap,
            video,
        }
    })
}

fn copy_tree(from: &Path, to: &Path) {
    for (name, bytes) in tree(from) {
        let target = to.join(&name);
        std::fs::create_dir_all(target.parent().expect("parent")).expect("dir");
        std::fs::write(target, bytes).expect("copy");
    }
}

fn check(root: &Path) -> Report {
    validate(root, &ValidateOptions::default()).expect("validate runs")
}

/// A copy of `good` without its manifest (content checks only), harmed by `harm`.
fn broken(good: &Path, harm: impl FnOnce(&Path)) -> (crate::util::TempRoot, Report) {
    let copy = temp_root("validate-broken");
    copy_tree(good, &copy);
    std::fs::remove_file(copy.join("meta/surgvla_manifest.json")).ok();
    std::fs::remove_file(copy.join("surgvla_manifest.json")).ok();
    harm(&copy);
    let report = check(&copy);
    (copy, report)
}

fn assert_found(report: &Report, check: &str, file: &str, what: &str) {
    assert!(!report.valid, "{what}: reported valid");
    assert!(
        report
            .errors
            .iter()
            .any(|e| e.check == check && e.file.as_deref().is_some_and(|f| f.contains(file))),
        "{what}: no [{check}] error naming {file} in {:#?}",
        report.errors
    );
}

const DATA: &str = "data/chunk-000/file-000.parquet";

/// Rewrites a parquet file's batches through `change` (uncompressed: bytes differ anyway).
pub(crate) fn rewrite_parquet(file: &Path, change: impl Fn(RecordBatch) -> RecordBatch) {
    let batches = surgvla::export::lerobot::read::read_parquet(file).expect("read");
    let metadata = batches[0].schema().metadata().clone();
    let changed: Vec<RecordBatch> = batches.into_iter().map(change).collect();
    let schema = Arc::new(
        arrow_schema::Schema::new(changed[0].schema().fields().clone()).with_metadata(metadata),
    );
    let mut bytes = Vec::new();
    let mut writer =
        parquet::arrow::ArrowWriter::try_new(&mut bytes, schema.clone(), None).expect("writer");
    for batch in changed {
        let batch = RecordBatch::try_new(schema.clone(), batch.columns().to_vec()).expect("batch");
        writer.write(&batch).expect("write");
    }
    writer.close().expect("close");
    std::fs::write(file, bytes).expect("write file");
}

/// The batch with column `name` replaced.
pub(crate) fn with_column(batch: RecordBatch, name: &str, column: ArrayRef) -> RecordBatch {
    let schema = batch.schema();
    let index = schema.index_of(name).expect("column");
    let mut columns = batch.columns().to_vec();
    columns[index] = column;
    let mut fields: Vec<arrow_schema::FieldRef> = schema.fields().iter().cloned().collect();
    fields[index] = Arc::new(arrow_schema::Field::new(
        name,
        columns[index].data_type().clone(),
        true,
    ));
    let schema = arrow_schema::Schema::new(fields).with_metadata(schema.metadata().clone());
    RecordBatch::try_new(Arc::new(schema), columns).expect("batch")
}

fn ints(batch: &RecordBatch, name: &str) -> Vec<i64> {
    let column = batch.column_by_name(name).expect("column");
    column
        .as_any()
        .downcast_ref::<Int64Array>()
        .expect("int64")
        .values()
        .to_vec()
}

/// A float vector column's values changed by `change(row, values)`.
fn map_vectors(batch: &RecordBatch, name: &str, change: impl Fn(usize, &mut [f32])) -> ArrayRef {
    let list = batch
        .column_by_name(name)
        .expect("column")
        .as_any()
        .downcast_ref::<FixedSizeListArray>()
        .expect("list")
        .clone();
    let n = list.value_length() as usize;
    let mut values = list
        .values()
        .as_any()
        .downcast_ref::<Float32Array>()
        .expect("f32")
        .values()
        .to_vec();
    for (row, chunk) in values.chunks_mut(n).enumerate() {
        change(row, chunk);
    }
    let field = Arc::new(arrow_schema::Field::new(
        "item",
        arrow_schema::DataType::Float32,
        true,
    ));
    Arc::new(
        FixedSizeListArray::try_new(field, n as i32, Arc::new(Float32Array::from(values)), None)
            .expect("list"),
    )
}

/// The image column `name` with row `row`'s bytes replaced.
fn replace_image(batch: &RecordBatch, name: &str, row: usize, bytes: Vec<u8>) -> ArrayRef {
    let images = batch
        .column_by_name(name)
        .expect("column")
        .as_any()
        .downcast_ref::<StructArray>()
        .expect("struct")
        .clone();
    let old = images
        .column_by_name("bytes")
        .expect("bytes")
        .as_any()
        .downcast_ref::<BinaryArray>()
        .expect("binary")
        .clone();
    let mut values: Vec<Vec<u8>> = (0..old.len()).map(|i| old.value(i).to_vec()).collect();
    values[row] = bytes;
    let binary: ArrayRef = Arc::new(BinaryArray::from_iter_values(values));
    let mut columns = images.columns().to_vec();
    let index = images
        .fields()
        .iter()
        .position(|f| f.name() == "bytes")
        .expect("bytes field");
    columns[index] = binary;
    Arc::new(StructArray::new(images.fields().clone(), columns, None))
}

fn edit_json(file: &Path, change: impl FnOnce(&mut serde_json::Value)) {
    let mut value: serde_json::Value =
        serde_json::from_slice(&std::fs::read(file).expect("read")).expect("json");
    change(&mut value);
    std::fs::write(file, serde_json::to_vec(&value).expect("json")).expect("write");
}

#[test]
fn good_datasets_of_every_format_are_valid_and_described() {
    let c = corpus();
    for (root, format, episodes) in [
        (&c.lerobot, "lerobot-v3.0", 2),
        (&c.lerobot21, "lerobot-v2.1", 2),
        (&c.rlds, "rlds", 2),
        (&c.zarr, "zarr", 2),
        (&c.mcap, "mcap", 2),
    ] {
        let report = check(root);
        assert!(report.valid, "{format}: {:#?}", report.errors);
        assert!(
            report.warnings.is_empty(),
            "{format}: {:#?}",
            report.warnings
        );
        assert_eq!(report.format, format);
        assert_eq!(report.episodes, episodes, "{format}");
        assert!(report.frames > 2 * 10, "{format}: {} frames", report.frames);
        let quick = validate(
            root,
            &ValidateOptions {
                quick: true,
                ..Default::default()
            },
        )
        .expect("quick");
        assert!(quick.valid, "{format} quick: {:#?}", quick.errors);
        assert_eq!(quick.episodes, episodes, "{format} quick");
        assert_eq!(quick.frames, report.frames, "{format} quick");
    }
    // A video-mode dataset is valid, every frame decoded, without warnings.
    let video = temp_root("validate-video");
    let (code, _, err) = surgvla(&[
        "collect",
        "--tasks",
        "T1-1",
        "--episodes-per-task",
        "2",
        "--video",
        "h264",
        "--out",
        path(&video),
    ]);
    assert_eq!(code, 0, "{err}");
    let report = check(&video);
    assert!(report.valid, "{:#?}", report.errors);
    assert!(report.warnings.is_empty(), "{:#?}", report.warnings);
    let (code, stdout, _) = surgvla(&["validate", path(&video), "--json"]);
    let json: serde_json::Value = serde_json::from_str(&stdout).expect("json");
    assert_eq!((code, json["valid"].as_bool()), (0, Some(true)));
    // Video defects, found through the MP4 sample tables: a span one frame short, another
    // codec declared than the file holds, a truncated file.
    const MP4: &str = "videos/observation.images.endoscope/chunk-000/file-000.mp4";
    let (_copy, report) = broken(&video, |root| {
        let name = "videos/observation.images.endoscope/to_timestamp";
        rewrite_parquet(
            &root.join("meta/episodes/chunk-000/file-000.parquet"),
            |batch| {
                let index = batch.schema().index_of(name).expect("column");
                let mut columns = batch.columns().to_vec();
                let to = columns[index]
                    .as_any()
                    .downcast_ref::<arrow_array::Float64Array>()
                    .expect("f64");
                let shorter: Vec<f64> = to.values().iter().map(|t| t - 0.2).collect();
                columns[index] = Arc::new(arrow_array::Float64Array::from(shorter));
                RecordBatch::try_new(batch.schema(), columns).expect("batch")
            },
        )
    });
    assert_found(&report, "video", MP4, "a span one frame short");
    let (_copy, report) = broken(&video, |root| {
        let info = root.join("meta/info.json");
        let text = std::fs::read_to_string(&info).expect("info");
        std::fs::write(&info, text.replace("\"h264\"", "\"av1\"")).expect("write");
    });
    assert_found(&report, "video", MP4, "another codec declared");
    let (_copy, report) = broken(&video, |root| {
        let bytes = std::fs::read(root.join(MP4)).expect("mp4");
        std::fs::write(root.join(MP4), &bytes[..bytes.len() * 2 / 3]).expect("write");
    });
    assert_found(&report, "video", MP4, "a truncated MP4");
    // Damaged samples inside an intact sample table: only decoding finds them, with the
    // episode and frame; converting the dataset fails naming the file (exit 1).
    let (copy, report) = broken(&video, |root| {
        let mut bytes = std::fs::read(root.join(MP4)).expect("mp4");
        let mdat = bytes.windows(4).position(|w| w == b"mdat").expect("mdat");
        let middle = mdat + (bytes.len() - mdat) * 3 / 4;
        bytes[middle..middle + 64].fill(0xff);
        std::fs::write(root.join(MP4), &bytes).expect("write");
    });
    assert_found(&report, "video-decode", MP4, "a damaged sample");
    let damaged = report
        .errors
        .iter()
        .find(|e| e.check == "video-decode")
        .expect("finding");
    assert_eq!(damaged.episode, Some(1), "{damaged:?}");
    assert!(damaged.frame.is_some(), "{damaged:?}");
    let out = temp_root("validate-video-convert");
    let (code, _, err) = surgvla(&["convert", path(&copy), "--to", "rlds", "--out", path(&out)]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("file-000.mp4"), "{err}");
    // A declared frame size the video does not have: the sample entry and the decoded frames
    // disagree with it.
    let (_copy, report) = broken(&video, |root| {
        let info = root.join("meta/info.json");
        let text = std::fs::read_to_string(&info).expect("info");
        std::fs::write(
            &info,
            text.replace("224,\n        224,", "224,\n        112,"),
        )
        .expect("write");
    });
    assert_found(
        &report,
        "video-decode",
        MP4,
        "a declared size the frames lack",
    );
    // Statistics that do not describe the video: the stored accumulator's sums halved.
    let (_copy, report) = broken(&video, |root| {
        let column = "surgvla/pixel_stats/observation.images.endoscope";
        rewrite_parquet(
            &root.join("meta/episodes/chunk-000/file-000.parquet"),
            |batch| {
                let index = batch.schema().index_of(column).expect("column");
                let mut columns = batch.columns().to_vec();
                let texts = columns[index]
                    .as_any()
                    .downcast_ref::<arrow_array::StringArray>()
                    .expect("JSON text");
                let halved: Vec<String> = texts
                    .iter()
                    .map(|text| {
                        let mut stats: serde_json::Value =
                            serde_json::from_str(text.expect("stats")).expect("json");
                        for running in stats["running"].as_array_mut().expect("running") {
                            let sum = running["sum"].as_f64().expect("sum");
                            running["sum"] = serde_json::json!(sum / 2.0);
                        }
                        stats.to_string()
                    })
                    .collect();
                columns[index] = Arc::new(arrow_array::StringArray::from(halved));
                RecordBatch::try_new(batch.schema(), columns).expect("batch")
            },
        )
    });
    let stats = report
        .errors
        .iter()
        .find(|e| e.check == "video-stats")
        .unwrap_or_else(|| panic!("no video-stats finding in {:#?}", report.errors));
    assert_eq!(stats.episode, Some(0), "{stats:?}");
    // A byte-for-byte copy and a byte-differently rewritten copy (no manifest) are valid.
    let (_copy, report) = broken(&c.lerobot, |_| {});
    assert!(report.valid, "{:#?}", report.errors);
    let (_copy, report) = broken(&c.lerobot, |root| rewrite_parquet(&root.join(DATA), |b| b));
    assert!(report.valid, "rewritten: {:#?}", report.errors);
    // With the manifest kept, the rewrite is a checksum mismatch naming the file.
    let copy = temp_root("validate-manifest");
    copy_tree(&c.lerobot, &copy);
    rewrite_parquet(&copy.join(DATA), |b| b);
    assert_found(&check(&copy), "checksum", DATA, "rewritten with a manifest");
}

#[test]
fn lerobot_defects_are_each_named() {
    let good = &corpus().lerobot;
    type Harm = Box<dyn Fn(&Path)>;
    let png = |pixels: &[u8], channels: usize| {
        surgvla::media::image::encode_png(
            224,
            224,
            channels,
            pixels,
            surgvla::media::image::PngLevel::Fast,
        )
        .expect("png")
    };
    let rgba = png(&vec![7u8; 224 * 224 * 4], 4);
    let cases: Vec<(&str, Harm, &str, &str)> = vec![
        (
            "missing info.json",
            Box::new(|r: &Path| std::fs::remove_file(r.join("meta/info.json")).expect("rm")),
            "present",
            "meta/info.json",
        ),
        (
            "every data file missing",
            Box::new(|r: &Path| std::fs::remove_dir_all(r.join("data")).expect("rm")),
            "present",
            "data",
        ),
        (
            "a truncated data file",
            Box::new(|r: &Path| {
                let bytes = std::fs::read(r.join(DATA)).expect("read");
                std::fs::write(r.join(DATA), &bytes[..bytes.len() / 2]).expect("write");
            }),
            "readable",
            DATA,
        ),
        (
            "an extra column",
            Box::new(|r: &Path| {
                rewrite_parquet(&r.join(DATA), |b| {
                    let mut fields: Vec<_> = b.schema().fields().iter().cloned().collect();
                    fields.push(Arc::new(arrow_schema::Field::new(
                        "extra",
                        arrow_schema::DataType::Int64,
                        true,
                    )));
                    let mut columns = b.columns().to_vec();
                    columns.push(Arc::new(Int64Array::from(vec![0; b.num_rows()])));
                    RecordBatch::try_new(Arc::new(arrow_schema::Schema::new(fields)), columns)
                        .expect("batch")
                })
            }),
            "columns",
            DATA,
        ),
        (
            "a missing column",
            Box::new(|r: &Path| {
                rewrite_parquet(&r.join(DATA), |b| {
                    let keep: Vec<usize> = (0..b.num_columns())
                        .filter(|&i| b.schema().field(i).name() != "action")
                        .collect();
                    b.project(&keep).expect("project")
                })
            }),
            "columns",
            DATA,
        ),
        (
            "a wrong shape",
            Box::new(|r: &Path| {
                rewrite_parquet(&r.join(DATA), |b| {
                    let n = b.num_rows();
                    let field = Arc::new(arrow_schema::Field::new(
                        "item",
                        arrow_schema::DataType::Float32,
                        true,
                    ));
                    let six = FixedSizeListArray::try_new(
                        field,
                        6,
                        Arc::new(Float32Array::from(vec![0.0f32; n * 6])),
                        None,
                    )
                    .expect("list");
                    with_column(b, "action", Arc::new(six))
                })
            }),
            "types",
            DATA,
        ),
        (
            "an index gap",
            Box::new(|r: &Path| {
                rewrite_parquet(&r.join(DATA), |b| {
                    let index: Vec<i64> = ints(&b, "index")
                        .iter()
                        .enumerate()
                        .map(|(i, v)| if i >= 5 { v + 1 } else { *v })
                        .collect();
                    with_column(b, "index", Arc::new(Int64Array::from(index)))
                })
            }),
            "index",
            DATA,
        ),
        (
            "a wrong timestamp",
            Box::new(|r: &Path| {
                rewrite_parquet(&r.join(DATA), |b| {
                    let column = b
                        .column_by_name("timestamp")
                        .expect("ts")
                        .as_any()
                        .downcast_ref::<Float32Array>()
                        .expect("f32")
                        .clone();
                    let values: Vec<f32> = column
                        .values()
                        .iter()
                        .enumerate()
                        .map(|(i, v)| if i == 3 { v + 0.05 } else { *v })
                        .collect();
                    with_column(b, "timestamp", Arc::new(Float32Array::from(values)))
                })
            }),
            "timestamps",
            DATA,
        ),
        (
            "NaN in a state",
            Box::new(|r: &Path| {
                rewrite_parquet(&r.join(DATA), |b| {
                    let column = map_vectors(&b, "observation.state", |row, v| {
                        if row == 4 {
                            v[2] = f32::NAN
                        }
                    });
                    with_column(b, "observation.state", column)
                })
            }),
            "finite",
            DATA,
        ),
        (
            "a half-open gripper",
            Box::new(|r: &Path| {
                rewrite_parquet(&r.join(DATA), |b| {
                    let column = map_vectors(&b, "action", |row, v| {
                        if row == 2 {
                            v[6] = 0.5
                        }
                    });
                    with_column(b, "action", column)
                })
            }),
            "gripper",
            DATA,
        ),
        (
            "an RGBA frame",
            Box::new(move |r: &Path| {
                let rgba = rgba.clone();
                rewrite_parquet(&r.join(DATA), move |b| {
                    let column = replace_image(&b, "observation.images.endoscope", 7, rgba.clone());
                    with_column(b, "observation.images.endoscope", column)
                })
            }),
            "image",
            DATA,
        ),
        (
            "a corrupt image",
            Box::new(|r: &Path| {
                rewrite_parquet(&r.join(DATA), |b| {
                    let column = replace_image(
                        &b,
                        "observation.images.endoscope",
                        9,
                        b"\x89PNG\r\n\x1a\nbroken".to_vec(),
                    );
                    with_column(b, "observation.images.endoscope", column)
                })
            }),
            "image",
            DATA,
        ),
        (
            "shifted from/to",
            Box::new(|r: &Path| {
                let file = r.join("meta/episodes/chunk-000/file-000.parquet");
                rewrite_parquet(&file, |b| {
                    let from: Vec<i64> = ints(&b, "dataset_from_index")
                        .iter()
                        .map(|v| v + 1)
                        .collect();
                    let to: Vec<i64> = ints(&b, "dataset_to_index").iter().map(|v| v + 1).collect();
                    let b = with_column(b, "dataset_from_index", Arc::new(Int64Array::from(from)));
                    with_column(b, "dataset_to_index", Arc::new(Int64Array::from(to)))
                })
            }),
            "from_to",
            "meta/episodes",
        ),
        (
            "tasks without pandas metadata",
            Box::new(|r: &Path| {
                let file = r.join("meta/tasks.parquet");
                let batches = surgvla::export::lerobot::read::read_parquet(&file).expect("read");
                let schema = Arc::new(arrow_schema::Schema::new(
                    batches[0].schema().fields().clone(),
                ));
                let mut bytes = Vec::new();
                let mut writer =
                    parquet::arrow::ArrowWriter::try_new(&mut bytes, schema.clone(), None)
                        .expect("writer");
                for batch in batches {
                    writer
                        .write(
                            &RecordBatch::try_new(schema.clone(), batch.columns().to_vec())
                                .expect("batch"),
                        )
                        .expect("write");
                }
                writer.close().expect("close");
                std::fs::write(&file, bytes).expect("write");
            }),
            "tasks",
            "meta/tasks.parquet",
        ),
        (
            "wrong totals",
            Box::new(|r: &Path| {
                edit_json(&r.join("meta/info.json"), |v| v["total_frames"] = 5.into())
            }),
            "totals",
            "meta/info.json",
        ),
        (
            "info.json breaking its schema",
            Box::new(|r: &Path| edit_json(&r.join("meta/info.json"), |v| v["fps"] = "fast".into())),
            "schema",
            "meta/info.json",
        ),
        (
            "a missing stats file",
            Box::new(|r: &Path| std::fs::remove_file(r.join("meta/stats.json")).expect("rm")),
            "stats",
            "meta/stats.json",
        ),
        (
            "stats inconsistent with the data",
            Box::new(|r: &Path| {
                edit_json(&r.join("meta/stats.json"), |v| {
                    v["action"]["max"][0] = 9.0.into()
                })
            }),
            "stats",
            "meta/stats.json",
        ),
        (
            "an empty instruction",
            Box::new(|r: &Path| {
                let file = r.join("meta/tasks.parquet");
                rewrite_parquet(&file, |b| {
                    with_column(
                        b.clone(),
                        "task",
                        Arc::new(arrow_array::StringArray::from(vec![""; b.num_rows()])),
                    )
                })
            }),
            "instruction",
            "meta/tasks.parquet",
        ),
    ];
    for (what, harm, check_name, file) in cases {
        let (_copy, report) = broken(good, harm);
        assert_found(&report, check_name, file, what);
        let located = report
            .errors
            .iter()
            .find(|e| e.check == check_name)
            .expect("found");
        if matches!(check_name, "finite" | "gripper" | "image" | "timestamps") {
            assert!(
                located.episode.is_some() && located.frame.is_some(),
                "{what}: {located:?}"
            );
        }
    }
}

#[test]
fn other_format_defects_are_each_named() {
    let c = corpus();
    let shard = "surgvla_benchmark-train.tfrecord-00000-of-00001";
    let version = c.rlds.join("surgvla_benchmark/1.0.0");
    // RLDS: a bad CRC, a wrong shardLengths, a step count mismatch inside a record.
    let (_c1, report) = broken(&version, |r| {
        let mut bytes = std::fs::read(r.join(shard)).expect("read");
        let middle = bytes.len() / 2;
        bytes[middle] ^= 0x10;
        std::fs::write(r.join(shard), bytes).expect("write");
    });
    assert_found(&report, "crc", shard, "a flipped byte");
    let (_c2, report) = broken(&version, |r| {
        edit_json(&r.join("dataset_info.json"), |v| {
            v["splits"][0]["shardLengths"][0] = "3".into()
        })
    });
    assert_found(&report, "shard_lengths", shard, "wrong shardLengths");
    // Splits without `train`, and more than one: no split to read, and the shard is stray.
    let (_c2b, report) = broken(&version, |r| {
        edit_json(&r.join("dataset_info.json"), |v| {
            let mut val = v["splits"][0].clone();
            val["name"] = "val".into();
            let mut test = val.clone();
            test["name"] = "test".into();
            v["splits"] = serde_json::json!([val, test]);
        })
    });
    assert_found(&report, "shards", "dataset_info.json", "no split to read");
    assert_found(&report, "shards", shard, "a shard of no split");
    let (_c3, report) = broken(&version, |r| {
        use surgvla::export::rlds::example::{Feature, decode_example, encode_example};
        use surgvla::export::rlds::tfrecord::{RecordReader, write_record};
        let file = std::fs::File::open(r.join(shard)).expect("open");
        let mut reader = RecordReader::new(std::io::BufReader::new(file));
        let mut out = Vec::new();
        let mut first = true;
        while let Some(record) = reader.next_record() {
            let mut example = decode_example(&record.expect("record")).expect("example");
            if first {
                if let Some(Feature::Float(values)) = example.get_mut("steps/reward") {
                    values.pop();
                }
                first = false;
            }
            write_record(&mut out, &encode_example(&example)).expect("write");
        }
        std::fs::write(r.join(shard), out).expect("write");
    });
    assert!(!report.valid, "a step count mismatch: valid");
    assert!(
        report
            .errors
            .iter()
            .any(|e| e.check == "step_counts" && e.message.contains("steps/reward")),
        "{:#?}",
        report.errors
    );
    // zarr: episode ends that do not match the arrays.
    let (_c4, report) = broken(&c.zarr, |r| {
        let ends: Vec<u8> = [5i64, 7].iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut padded = ends.clone();
        padded.resize(100 * 8, 0);
        let frame = zstd::stream::encode_all(padded.as_slice(), 3).expect("zstd");
        std::fs::write(r.join("meta/episode_ends/0"), frame).expect("write");
    });
    assert_found(
        &report,
        "episode_ends",
        "meta/episode_ends",
        "zarr ends mismatch",
    );
    // MCAP: a corrupt chunk.
    let (_c5, report) = broken(&c.mcap, |r| {
        let file = r.join("episode_000000.mcap");
        let mut bytes = std::fs::read(&file).expect("read");
        let middle = bytes.len() / 3;
        for b in &mut bytes[middle..middle + 64] {
            *b ^= 0x5a;
        }
        std::fs::write(&file, bytes).expect("write");
    });
    assert_found(&report, "crc", "episode_000000.mcap", "corrupt MCAP chunk");
}

#[test]
fn validate_and_info_exit_codes_and_json() {
    let c = corpus();
    let (code, out, err) = surgvla(&["validate", path(&c.lerobot), "--json"]);
    assert_eq!(code, 0, "{err}");
    let json: serde_json::Value = serde_json::from_str(&out).expect("json");
    assert_eq!(json["valid"], true);
    assert_eq!(json["format"], "lerobot-v3.0");
    assert_eq!(json["errors"], serde_json::json!([]));
    let (_copy, _) = broken(&c.lerobot, |r| {
        edit_json(&r.join("meta/info.json"), |v| {
            v["total_episodes"] = 9.into()
        });
        let (code, out, err) = surgvla(&["validate", path(r), "--json"]);
        assert_eq!(code, 1, "{err}");
        let json: serde_json::Value = serde_json::from_str(&out).expect("json");
        assert_eq!(json["valid"], false);
        let error = &json["errors"][0];
        for key in ["file", "episode", "frame", "check", "message"] {
            assert!(error.get(key).is_some(), "{key} in {error}");
        }
        let (code, out, _) = surgvla(&["validate", path(r)]);
        assert_eq!(code, 1);
        assert!(
            out.contains("meta/info.json: [totals] total_episodes is 9"),
            "{out}"
        );
    });
    let nothing = temp_root("validate-nothing");
    std::fs::create_dir_all(nothing.join("stuff")).expect("dir");
    std::fs::write(nothing.join("stuff/notes.txt"), "hello").expect("write");
    let (code, _, err) = surgvla(&["validate", path(&nothing)]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("recognises"), "{err}");
    let (code, _, err) = surgvla(&["validate", path(&nothing.join("missing"))]);
    assert_eq!(code, 2, "{err}");
    let (code, out, err) = surgvla(&["info", path(&c.lerobot), "--json"]);
    assert_eq!(code, 0, "{err}");
    let info: serde_json::Value = serde_json::from_str(&out).expect("json");
    assert_eq!(info["episodes"], 2);
    assert_eq!(info["fps"], 5.0);
    assert_eq!(info["tasks"].as_object().map(|t| t.len()), Some(2));
    assert!(info["features"].as_array().is_some_and(|f| f.len() >= 8));
    assert!(info["bytes"].as_u64().is_some_and(|b| b > 100_000));
    let (code, out, _) = surgvla(&["info", path(&c.rlds)]);
    assert_eq!(code, 0);
    assert!(
        out.contains("format     rlds") && out.contains("episodes   2"),
        "{out}"
    );
}

/// The quality lint: on by default in the CLI (one summary line per check, in `--json` too),
/// off with `--no-lint`; `--fail-on warning` gates on warnings; planted defects (a gripper out
/// of its range, actions recorded two frames late, a blank camera) are each an error of their
/// own check, naming episode and frame.
#[test]
fn the_lint_reports_per_check_and_finds_planted_defects() {
    let c = corpus();
    let (code, out, err) = surgvla(&["validate", path(&c.lerobot), "--json"]);
    assert_eq!(code, 0, "{err}");
    let json: serde_json::Value = serde_json::from_str(&out).expect("json");
    let lint = json["lint"].as_array().expect("lint");
    assert!(lint.len() >= 20, "{lint:?}");
    assert!(lint.iter().all(|l| l["status"] != "error"), "{lint:?}");
    // Two episodes shorter than ACT's chunk: one warning for the dataset, not one per episode.
    let chunk: Vec<&serde_json::Value> = (json["warnings"].as_array().expect("warnings").iter())
        .filter(|w| w["check"] == "chunk-length")
        .collect();
    assert_eq!(chunk.len(), 1, "{chunk:?}");
    let (code, _, err) = surgvla(&["validate", path(&c.lerobot), "--fail-on", "warning"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("--fail-on warning"), "{err}");
    let (code, out, err) = surgvla(&["validate", path(&c.lerobot), "--no-lint", "--json"]);
    assert_eq!(code, 0, "{err}");
    let json: serde_json::Value = serde_json::from_str(&out).expect("json");
    assert_eq!(json["lint"], serde_json::json!([]));
    let (code, out, _) = surgvla(&["validate", path(&c.lerobot)]);
    assert_eq!(code, 0);
    assert!(out.contains("lint:") && out.contains("action-lag"), "{out}");
    let lint = ValidateOptions {
        lint: true,
        ..ValidateOptions::default()
    };
    let data = |root: &Path| root.join("data/chunk-000/file-000.parquet");
    let (copy, _) = broken(&c.lerobot, |root| {
        rewrite_parquet(&data(root), |batch| {
            let column = map_vectors(&batch, "action", |row, v| {
                if row == 3 {
                    v[6] = 1.5;
                }
            });
            with_column(batch, "action", column)
        });
    });
    let report = validate(&copy, &lint).expect("validate");
    let found: Vec<_> = (report.errors.iter())
        .filter(|f| f.check == "gripper-range")
        .collect();
    assert_eq!(found.len(), 1, "{:#?}", report.errors);
    assert_eq!((found[0].episode, found[0].frame), (Some(0), Some(3)));
    let (copy, _) = broken(&c.lerobot, |root| {
        rewrite_parquet(&data(root), |batch| {
            let episodes = ints(&batch, "episode_index");
            let original = map_vectors(&batch, "action", |_, _| {});
            let list = original
                .as_any()
                .downcast_ref::<FixedSizeListArray>()
                .expect("list");
            let values = list
                .values()
                .as_any()
                .downcast_ref::<Float32Array>()
                .expect("f32");
            let rows: Vec<Vec<f32>> = (0..list.len())
                .map(|r| values.values()[r * 7..r * 7 + 7].to_vec())
                .collect();
            // Each action recorded two frames late.
            let column = map_vectors(&batch, "action", |row, v| {
                if row >= 2 && episodes[row - 2] == episodes[row] {
                    v.copy_from_slice(&rows[row - 2]);
                }
            });
            with_column(batch, "action", column)
        });
    });
    let report = validate(&copy, &lint).expect("validate");
    let lag: Vec<_> = (report.errors.iter())
        .filter(|f| f.check == "action-lag")
        .collect();
    assert_eq!(lag.len(), 1, "{:#?}", report.errors);
    assert!(
        lag[0].message.contains("lags the state by 2 frames"),
        "{}",
        lag[0].message
    );
    let (copy, _) = broken(&c.lerobot, |root| {
        rewrite_parquet(&data(root), |batch| {
            let black = black_png(224, 224);
            let episodes = ints(&batch, "episode_index");
            let mut batch = batch;
            for row in (0..batch.num_rows()).filter(|&r| episodes[r] == 1) {
                let column =
                    replace_image(&batch, "observation.images.endoscope", row, black.clone());
                batch = with_column(batch, "observation.images.endoscope", column);
            }
            batch
        });
    });
    let report = validate(&copy, &lint).expect("validate");
    assert!(
        (report.errors.iter())
            .any(|f| f.check == "blank-camera" && (f.episode, f.frame) == (Some(1), Some(0))),
        "{:#?}",
        report.errors
    );
}

/// `--profile open-h`: a v3.0 dataset is refused (Open-H takes v2.1); a v2.1 image-mode one
/// lacks the videos and the README with its synchronisation section (errors, as Open-H's
/// validator has them) and warns of its 5 Hz and 224 px.
#[test]
fn the_open_h_profile_checks_the_contribution_guide() {
    let c = corpus();
    let (code, out, _) = surgvla(&[
        "validate",
        path(&c.lerobot),
        "--profile",
        "open-h",
        "--json",
    ]);
    assert_eq!(code, 1);
    let json: serde_json::Value = serde_json::from_str(&out).expect("json");
    let messages = |json: &serde_json::Value, kind: &str| -> Vec<String> {
        (json[kind].as_array().expect("findings").iter())
            .filter(|f| f["check"] == "profile")
            .map(|f| f["message"].as_str().unwrap_or_default().to_string())
            .collect()
    };
    assert!(
        (messages(&json, "errors").iter()).any(|m| m.contains("takes LeRobot v2.1")),
        "{json}"
    );
    let (code, out, _) = surgvla(&[
        "validate",
        path(&c.lerobot21),
        "--profile",
        "open-h",
        "--json",
    ]);
    assert_eq!(code, 1);
    let json: serde_json::Value = serde_json::from_str(&out).expect("json");
    let errors = messages(&json, "errors");
    assert!(errors.iter().any(|m| m.contains("template")), "{errors:?}");
    assert!(
        errors.iter().any(|m| m.contains("stores cameras as video")),
        "{errors:?}"
    );
    let warnings = messages(&json, "warnings");
    assert!(
        warnings
            .iter()
            .any(|m| m.contains("below the guide's 20 Hz")),
        "{warnings:?}"
    );
    assert!(
        warnings
            .iter()
            .any(|m| m.contains("below the guide's 480p")),
        "{warnings:?}"
    );
    // With its README documenting synchronisation, that error goes.
    let (copy, _) = broken(&c.lerobot21, |root| {
        std::fs::write(
            root.join("meta/README.md"),
            "# Data\n\n## Synchronization\n\nBy timestamp.\n",
        )
        .expect("readme");
    });
    let (_, out, _) = surgvla(&["validate", path(&copy), "--profile", "open-h", "--json"]);
    let json: serde_json::Value = serde_json::from_str(&out).expect("json");
    let errors: Vec<&serde_json::Value> = (json["errors"].as_array().expect("errors").iter())
        .filter(|f| f["check"] == "profile")
        .collect();
    assert_eq!(errors.len(), 1, "{errors:?}");
}

/// A black RGB PNG.
fn black_png(width: u32, height: u32) -> Vec<u8> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().expect("header");
    writer
        .write_image_data(&vec![0u8; (width * height * 3) as usize])
        .expect("pixels");
    writer.finish().expect("finish");
    bytes
}

/// Seeded random corruption (flipped bytes, truncations, deletions) of each format's files:
/// validation must finish with a report, never panic.
#[test]
fn random_corruption_never_panics_a_reader() {
    let c = corpus();
    let mut rng = surgvla::rng::SplitMix64::stream(7, "validate-fuzz");
    for good in [
        &c.lerobot,
        &c.lerobot21,
        &c.rlds,
        &c.zarr,
        &c.mcap,
        &c.video,
    ] {
        let files: Vec<String> = tree(good).into_keys().collect();
        for _ in 0..12 {
            let copy = temp_root("validate-fuzz");
            copy_tree(good, &copy);
            // Whether a file the manifest lists was changed or removed: the copy keeps its
            // manifest, so validation must then find a defect. The card (README.md) is known to
            // be ours only by the manifest: harmed with the manifest gone, it is another tool's.
            let mut harmed = false;
            let mut card_harmed = false;
            for _ in 0..3 {
                let name = &files[(rng.next_u64() % files.len() as u64) as usize];
                let card = name == "README.md";
                let listed = !name.ends_with("surgvla_manifest.json")
                    && name != "collect_report.json"
                    && !card;
                let file = copy.join(name);
                let Ok(original) = std::fs::read(&file) else {
                    continue;
                };
                let mut bytes = original.clone();
                match rng.next_u64() % 3 {
                    0 if !bytes.is_empty() => {
                        for _ in 0..8 {
                            let at = (rng.next_u64() % bytes.len() as u64) as usize;
                            bytes[at] = rng.next_u64() as u8;
                        }
                    }
                    1 => bytes.truncate((rng.next_u64() % (bytes.len() as u64 + 1)) as usize),
                    _ => {
                        std::fs::remove_file(&file).ok();
                        harmed |= listed;
                        card_harmed |= card;
                        continue;
                    }
                }
                harmed |= listed && bytes != original;
                card_harmed |= card && bytes != original;
                std::fs::write(&file, bytes).expect("write");
            }
            let manifest_kept = tree(&copy)
                .keys()
                .any(|name| name.ends_with("surgvla_manifest.json"));
            harmed |= card_harmed && manifest_kept;
            if let Ok(report) = validate(&copy, &ValidateOptions::default()) {
                assert!(
                    !harmed || !report.valid,
                    "{}: a harmed dataset validated",
                    copy.display()
                );
            }
            // The readers `convert` uses: every episode, or an error, never a panic. Without
            // surgvla.json an RLDS dataset is read as another tool's (ForeignRldsSource).
            if good != &c.zarr && good != &c.mcap {
                for drop_metadata in [false, true] {
                    if drop_metadata {
                        std::fs::remove_file(copy.join("surgvla_benchmark/1.0.0/surgvla.json"))
                            .ok();
                        std::fs::remove_file(copy.join("meta/surgvla.json")).ok();
                    }
                    let options = surgvla::export::SourceOptions {
                        fps: Some(5),
                        ..Default::default()
                    };
                    if let Ok(mut source) = surgvla::export::open_source_with(&copy, &options) {
                        for episode in source.by_ref() {
                            if episode.is_err() {
                                break;
                            }
                        }
                    }
                }
            }
        }
    }
}

/// `--replay` re-simulates every episode: the good dataset replays to its own frames and
/// success; a changed action (still a valid number, 0/1 gripper) is caught by the replay alone;
/// formats without episodes to replay and datasets without provenance exit 2.
#[test]
fn replay_confirms_recorded_frames_and_catches_changed_actions() {
    let c = corpus();
    let (code, out, err) = surgvla(&["validate", path(&c.lerobot), "--replay"]);
    assert_eq!(code, 0, "{out}{err}");
    let (code, _, err) = surgvla(&["validate", path(&c.rlds), "--replay"]);
    assert_eq!(code, 0, "rlds: {err}");
    let (_copy, report) = broken(&c.lerobot, |r| {
        rewrite_parquet(&r.join(DATA), |b| {
            // Every step commands the jaws open: nothing can be grasped.
            let column = map_vectors(&b, "action", |_, v| v[6] = 1.0);
            with_column(b, "action", column)
        });
        edit_json(&r.join("meta/stats.json"), |v| {
            v["action"]["min"][6] = 1.0.into();
            v["action"]["mean"][6] = 1.0.into();
        });
        let (code, out, err) = surgvla(&["validate", path(r), "--replay", "--json"]);
        assert_eq!(code, 1, "{err}");
        let json: serde_json::Value = serde_json::from_str(&out).expect("json");
        let errors = json["errors"].as_array().expect("errors");
        assert!(
            errors
                .iter()
                .any(|e| e["check"] == "replay" && e["episode"] == 0),
            "{errors:#?}"
        );
    });
    assert!(
        report.valid,
        "the change is invisible without --replay: {:#?}",
        report.errors
    );
    // A dataset judged by other success rules: frames and states replayed, success not
    // judged, a warning says so.
    let (_copy, _) = broken(&c.lerobot, |r| {
        edit_json(&r.join("meta/surgvla.json"), |v| {
            assert_eq!(
                v["collection"]["success_rules"],
                surgvla::task::success::RULE_SET
            );
            v["collection"]["success_rules"] = "surgvla-older".into();
        });
        let (code, out, err) = surgvla(&["validate", path(r), "--replay", "--json"]);
        assert_eq!(code, 0, "{out}{err}");
        let json: serde_json::Value = serde_json::from_str(&out).expect("json");
        let warnings = json["warnings"].as_array().expect("warnings");
        assert!(
            warnings.iter().any(|w| w["check"] == "replay"
                && w["message"]
                    .as_str()
                    .is_some_and(|m| m.contains("surgvla-older") && m.contains("not judged"))),
            "{warnings:#?}"
        );
    });
    let (code, _, err) = surgvla(&["validate", path(&c.zarr), "--replay"]);
    assert_eq!(code, 2, "{err}");
    let (_copy, _) = broken(&c.lerobot, |r| {
        std::fs::remove_file(r.join("meta/surgvla.json")).expect("rm");
        let (code, _, err) = surgvla(&["validate", path(r), "--replay"]);
        assert_eq!(code, 2, "{err}");
        assert!(err.contains("no surgvla collection metadata"), "{err}");
    });
}

/// `convert --verify` compares every frame of the output with the input (and can fail: a frame
/// changed after conversion is found); `--without` leaves features out of the output, and the
/// verification compares what both sides hold; v3.0 -> v2.1 -> v3.0 and RLDS -> LeRobot verify.
#[test]
fn convert_verifies_every_frame_and_leaves_features_out() {
    let c = corpus();
    let out = temp_root("verify-out");
    let lean = out.join("v21");
    let (code, stdout, err) = surgvla(&[
        "convert",
        path(&c.lerobot),
        "--to",
        "lerobot",
        "--lerobot-version",
        "2.1",
        "--without",
        "depth,environment_state",
        "--out",
        path(&lean),
        "--verify",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("verified"), "{stdout}");
    let info: serde_json::Value =
        serde_json::from_slice(&std::fs::read(lean.join("meta/info.json")).expect("info"))
            .expect("json");
    assert_eq!(info["codebase_version"], "v2.1");
    assert!(info["features"].get("observation.images.depth").is_none());
    assert!(
        info["features"]
            .get("observation.environment_state")
            .is_none()
    );
    for (input, to, name) in [(&lean, "lerobot", "v30"), (&c.rlds, "lerobot", "from-rlds")] {
        let target = out.join(name);
        let (code, _, err) = surgvla(&[
            "convert",
            path(input),
            "--to",
            to,
            "--out",
            path(&target),
            "--verify",
        ]);
        assert_eq!(code, 0, "{name}: {err}");
    }
    // A frame changed after conversion: the comparison finds it.
    let (_copy, _) = broken(&out.join("from-rlds"), |r| {
        rewrite_parquet(&r.join(DATA), |b| {
            let column = map_vectors(&b, "observation.state", |row, v| {
                if row == 3 {
                    v[0] += 1e-3
                }
            });
            with_column(b, "observation.state", column)
        });
        let mut source = surgvla::export::open_source(&c.lerobot).expect("source");
        let mut target = surgvla::export::open_source(r).expect("target");
        let verification =
            surgvla::export::convert::verify(source.as_mut(), target.as_mut()).expect("verify");
        assert_eq!(verification.episodes, 2);
        assert_eq!(
            verification.differences,
            ["episode 0 frame 3: state differs"],
            "{verification:?}"
        );
    });
}

/// The committed MCAP JSON channel schemas are what the recorder writes. After an intended
/// change, regenerate with `cargo run --release -- schema --format mcap >
/// schemas/mcap_json_channels.json`.
#[test]
fn mcap_json_channel_schema_snapshot_matches_the_recorder() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("schemas/mcap_json_channels.json");
    let committed: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&path).expect("schema file")).expect("json");
    assert_eq!(
        committed,
        surgvla::export::mcap::messages::json_channel_schemas()
    );
}

/// The card (README.md) against the data: counts that disagree are an error naming it, a card
/// that is not ours is an error, and a dataset of ours without one gets a warning only.
#[test]
fn the_dataset_card_is_checked_against_the_data() {
    let root = temp_root("validate-card");
    let (code, _, err) = surgvla(&[
        "collect",
        "--tasks",
        "T1-1",
        "--episodes-per-task",
        "2",
        "--format",
        "ply",
        "--out",
        path(&root),
    ]);
    assert_eq!(code, 0, "{err}");
    let card = std::fs::read_to_string(root.join("README.md")).expect("card");
    assert!(card.contains("| T1-1 | 1 | 2 |"), "{card}");
    // The manifest stops listing the card, so that only the card's own check can speak.
    let manifest_path = root.join("surgvla_manifest.json");
    let mut manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&manifest_path).expect("manifest")).expect("json");
    manifest["files"]
        .as_array_mut()
        .expect("files")
        .retain(|f| f["path"] != "README.md");
    std::fs::write(&manifest_path, manifest.to_string()).expect("manifest");
    let (code, out, _) = surgvla(&["validate", path(&root)]);
    assert_eq!(code, 0, "{out}");
    std::fs::write(
        root.join("README.md"),
        card.replace("| T1-1 | 1 | 2 |", "| T1-1 | 1 | 5 |"),
    )
    .expect("card");
    let (code, out, _) = surgvla(&["validate", path(&root)]);
    assert_eq!(code, 1, "{out}");
    assert!(
        out.contains("README.md: [card] says 5 episodes, the dataset holds 2"),
        "{out}"
    );
    std::fs::write(root.join("README.md"), "# my notes\n").expect("card");
    let (code, out, _) = surgvla(&["validate", path(&root)]);
    assert_eq!(code, 1, "{out}");
    assert!(out.contains("[card] has no tasks table"), "{out}");
    std::fs::remove_file(root.join("README.md")).expect("remove");
    let (code, out, _) = surgvla(&["validate", path(&root)]);
    assert_eq!(code, 0, "a missing card is a warning: {out}");
    assert!(out.contains("warning: README.md: [card]"), "{out}");
}

/// `info --plot` draws a readable dataset (the chart's pixels are tested beside its code) and
/// refuses a format surgvla does not read back as episodes.
#[test]
fn info_plot_draws_readable_datasets() {
    let c = corpus();
    let plot = temp_root("info-plot");
    std::fs::create_dir_all(&*plot).expect("dir");
    let png = plot.join("lerobot.png");
    let (code, _, err) = surgvla(&["info", path(&c.lerobot), "--plot", path(&png)]);
    assert_eq!(code, 0, "{err}");
    let bytes = std::fs::read(&png).expect("png");
    assert_eq!(&bytes[1..4], b"PNG");
    let again = plot.join("again.png");
    let (code, _, err) = surgvla(&["info", path(&c.lerobot), "--plot", path(&again)]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(std::fs::read(&again).expect("png"), bytes, "deterministic");
    let (code, _, err) = surgvla(&["info", path(&c.zarr), "--plot", path(&plot.join("z.png"))]);
    assert_eq!(code, 2, "{err}");
}

/// docs/validate.md's table of checks is every [`Check`], with its name and what it verifies:
/// a check added to the code is documented or this fails. After adding one:
/// `SURGVLA_UPDATE_DOCS=1 cargo test --release --test all -- check_docs`.
#[test]
fn check_docs_list_every_check() {
    use surgvla::export::check::Check;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/validate.md");
    let text = std::fs::read_to_string(&path).expect("docs/validate.md");
    let (begin, end) = (
        "<!-- checks: generated from src/export/check.rs -->\n",
        "<!-- end of checks -->",
    );
    let start = text.find(begin).expect("the checks' start marker") + begin.len();
    let stop = start + text[start..].find(end).expect("the checks' end marker");
    let mut table = String::from("\n| Check | What it verifies |\n|---|---|\n");
    for check in Check::ALL {
        table.push_str(&format!("| `{}` | {} |\n", check.name(), check.what()));
    }
    table.push('\n');
    let mut fresh = text.clone();
    fresh.replace_range(start..stop, &table);
    if std::env::var_os("SURGVLA_UPDATE_DOCS").is_some() && fresh != text {
        std::fs::write(&path, &fresh).expect("write docs/validate.md");
        return;
    }
    assert!(
        fresh == text,
        "docs/validate.md's checks differ from Check::ALL: SURGVLA_UPDATE_DOCS=1 cargo test --release --test all -- check_docs"
    );
}
