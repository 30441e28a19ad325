//! `surgvla edit`: episodes kept and dropped by every kind of selector, splits (folders and
//! info.json), features renamed and removed, instructions changed; video copied sample for
//! sample (the bytes compared), statistics recomputed exactly over what is kept; an episode
//! starting mid-GOP refused by name, then encoded again on request; dry runs write nothing;
//! a killed edit resumes to the uninterrupted bytes; the user's mistakes exit 2.

use crate::util::{kill_after_checkpoint, surgvla, temp_root, tree};
use crate::validate::{rewrite_parquet, with_column};
use arrow_array::{Array, ArrayRef, Float64Array};
use std::path::Path;
use std::sync::{Arc, OnceLock};
use surgvla::episode::Episode;

fn text(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// Six AV1 episodes (T1-1 and T2-1, three each), made once for the module.
fn video_input() -> &'static Path {
    static ROOT: OnceLock<std::path::PathBuf> = OnceLock::new();
    ROOT.get_or_init(|| {
        let root = crate::util::shared_root("edit-video-input");
        collect(&root, &["T1-1,T2-1", "3", "--video", "av1"]);
        root
    })
}

/// `collect --tasks TASKS --episodes-per-task N [FLAGS...] --out out`, which must succeed
/// (`args`: the tasks, the count, then any flags).
fn collect(out: &Path, args: &[&str]) {
    let [tasks, count, flags @ ..] = args else {
        panic!("collect needs the tasks and a count: {args:?}");
    };
    let mut all = vec!["collect", "--tasks", tasks, "--episodes-per-task", count];
    all.extend(flags);
    all.extend(["--out", text(out)]);
    let (code, _, err) = surgvla(&all);
    assert_eq!(code, 0, "{all:?}: {err}");
}

fn episodes(root: &Path) -> Vec<Episode> {
    let source = surgvla::export::open_source(root).expect("open");
    source.map(|e| e.expect("episode")).collect()
}

fn info_json(root: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(root.join("meta/info.json")).expect("info"))
        .expect("json")
}

/// Output episode k is input episode `kept[k]`: instruction, steps bit for bit, video samples
/// byte for byte.
fn assert_holds(out: &[Episode], input: &[Episode], kept: &[usize]) {
    assert_eq!(out.len(), kept.len());
    for (k, (episode, &i)) in out.iter().zip(kept).enumerate() {
        let original = &input[i];
        assert_eq!(episode.meta.index, out[0].meta.index + k as u64);
        assert_eq!(episode.meta.seed, original.meta.seed, "episode {k}");
        assert_eq!(episode.meta.instruction, original.meta.instruction);
        assert_eq!(episode.steps.len(), original.steps.len());
        for (a, b) in episode.steps.iter().zip(&original.steps) {
            assert_eq!(a.action.map(f32::to_bits), b.action.map(f32::to_bits));
            assert_eq!(a.state.map(f32::to_bits), b.state.map(f32::to_bits));
            assert_eq!(a.depth_m, b.depth_m);
        }
        let video = |e: &Episode| {
            let v = e
                .encoded_video("observation.images.endoscope")
                .expect("video");
            v.frames.iter().map(|f| f.data.clone()).collect::<Vec<_>>()
        };
        assert!(
            video(episode) == video(original),
            "episode {k}: samples differ"
        );
    }
}

#[test]
fn dropped_episodes_leave_and_the_rest_are_copied_with_exact_statistics() {
    let input = video_input();
    let out = temp_root("edit-drop");
    let (code, stdout, err) = surgvla(&[
        "edit",
        text(input),
        "--drop",
        "1,3-4",
        "--out",
        text(&out),
        "--verify",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(
        stdout.contains("keeping 3 of 6 episodes; dropping 1, 3, 4"),
        "{stdout}"
    );
    assert!(stdout.contains("verified"), "{stdout}");
    let (original, edited) = (episodes(input), episodes(&out));
    assert_holds(&edited, &original, &[0, 2, 5]);
    // The statistics are those of the kept frames: quantiles exact (numpy's linear rule).
    let actions: Vec<f32> = edited
        .iter()
        .flat_map(|e| e.steps.iter().map(|s| s.action[0]))
        .collect();
    let mut sorted = actions.clone();
    sorted.sort_by(f32::total_cmp);
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("meta/stats.json")).expect("stats"))
            .expect("json");
    let action = &stats["action"];
    assert_eq!(action["count"][0], actions.len());
    assert_eq!(action["min"][0].as_f64(), Some(f64::from(sorted[0])));
    let position = 0.9 * (sorted.len() - 1) as f64;
    let (low, t) = (position.floor() as usize, position.fract());
    let q90 = f64::from(sorted[low]) * (1.0 - t) + f64::from(sorted[low + 1]) * t;
    assert!((action["q90"][0].as_f64().expect("q90") - q90).abs() < 1e-6);
    let info = info_json(&out);
    assert_eq!(info["total_episodes"], 3);
    assert_eq!(info["splits"]["train"], "0:3");
    let (code, _, err) = surgvla(&["validate", text(&out)]);
    assert_eq!(code, 0, "{err}");
}

/// The data files of `root` written again with at most `rows` rows per row group, which then
/// start and end mid-episode, and with or without statistics (other writers' layouts).
fn regroup(root: &Path, rows: usize, statistics: bool) {
    use parquet::file::properties::{EnabledStatistics, WriterProperties};
    for file in surgvla::export::lerobot::read::data_files(root).expect("data files") {
        let batches = surgvla::export::lerobot::read::read_parquet(&file).expect("read");
        let enabled = if statistics {
            EnabledStatistics::Chunk
        } else {
            EnabledStatistics::None
        };
        let properties = WriterProperties::builder()
            .set_max_row_group_row_count(Some(rows))
            .set_statistics_enabled(enabled)
            .build();
        let mut bytes = Vec::new();
        let mut writer =
            parquet::arrow::ArrowWriter::try_new(&mut bytes, batches[0].schema(), Some(properties))
                .expect("writer");
        for batch in &batches {
            writer.write(batch).expect("write");
        }
        writer.close().expect("close");
        std::fs::write(&file, bytes).expect("write file");
    }
}

#[test]
fn row_groups_that_are_not_one_episode_each_read_and_edit_alike() {
    let input = video_input();
    let original = episodes(input);
    // Groups of 7 and 25 rows (several episodes each, or one episode across several), and one
    // group per file without the statistics that say which episode a group holds.
    for (rows, statistics) in [(7, true), (25, true), (100_000, false)] {
        let root = temp_root("edit-regrouped");
        for (relative, bytes) in tree(input) {
            let path = root.join(relative);
            std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
            std::fs::write(path, bytes).expect("copy");
        }
        regroup(&root, rows, statistics);
        let all: Vec<usize> = (0..original.len()).collect();
        assert_holds(&episodes(&root), &original, &all);
        let out = temp_root("edit-regrouped-out");
        let (code, stdout, err) =
            surgvla(&["edit", text(&root), "--drop", "1,4", "--out", text(&out)]);
        assert_eq!(code, 0, "{rows} rows a group: {err}");
        assert!(stdout.contains("keeping 4 of 6 episodes"), "{stdout}");
        assert_holds(&episodes(&out), &original, &[0, 2, 3, 5]);
    }
}

/// A copy of `input` whose data files are written again one row group per episode with zstd
/// in every column (surgvla writes zstd for depth images only): a row group the edit copies
/// keeps zstd.
fn zstd_copy(input: &Path) -> crate::util::TempRoot {
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    use parquet::basic::Compression;
    use parquet::file::properties::WriterProperties;
    let root = temp_root("edit-zstd");
    for (relative, bytes) in tree(input) {
        let path = root.join(relative);
        std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
        std::fs::write(path, bytes).expect("copy");
    }
    for file in surgvla::export::lerobot::read::data_files(&root).expect("data files") {
        let reader = || {
            ParquetRecordBatchReaderBuilder::try_new(std::fs::File::open(&file).expect("open"))
                .expect("reader")
        };
        let groups = reader().metadata().num_row_groups();
        let schema = reader().schema().clone();
        let properties = WriterProperties::builder()
            .set_compression(Compression::ZSTD(Default::default()))
            .build();
        let mut bytes = Vec::new();
        let mut writer = parquet::arrow::ArrowWriter::try_new(&mut bytes, schema, Some(properties))
            .expect("writer");
        for group in 0..groups {
            for batch in reader()
                .with_row_groups(vec![group])
                .build()
                .expect("build")
            {
                writer.write(&batch.expect("batch")).expect("write");
            }
            writer.flush().expect("one group per episode");
        }
        writer.close().expect("close");
        std::fs::write(&file, bytes).expect("write file");
    }
    root
}

/// The compression of each column chunk of `root`'s data files, and whether it has a
/// dictionary, by column path, per group.
fn codecs(root: &Path) -> Vec<Vec<(String, parquet::basic::Compression, bool)>> {
    use parquet::file::reader::FileReader;
    let mut all = Vec::new();
    for file in surgvla::export::lerobot::read::data_files(root).expect("data files") {
        let reader = parquet::file::reader::SerializedFileReader::new(
            std::fs::File::open(&file).expect("open"),
        )
        .expect("footer");
        for group in reader.metadata().row_groups() {
            all.push(
                (group.columns().iter())
                    .map(|c| {
                        let dictionary = c.dictionary_page_offset().is_some();
                        (c.column_path().string(), c.compression(), dictionary)
                    })
                    .collect(),
            );
        }
    }
    all
}

#[test]
fn kept_row_groups_are_copied_as_stored_and_read_as_an_edit_that_decodes() {
    use parquet::basic::Compression;
    let original = episodes(video_input());
    let input = zstd_copy(video_input());
    // The same input without the depth images' exact statistics: its edit must read the
    // pixels (to count them) and writes every row again.
    let decoding = temp_root("edit-decoding-input");
    for (relative, bytes) in tree(&input) {
        let path = decoding.join(relative);
        std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
        std::fs::write(path, bytes).expect("copy");
    }
    let table = decoding.join("meta/episodes/chunk-000/file-000.parquet");
    rewrite_parquet(&table, |batch| {
        let rows = batch.num_rows();
        let nulls: ArrayRef = Arc::new(arrow_array::StringArray::new_null(rows));
        with_column(batch, "surgvla/pixel_stats/observation.images.depth", nulls)
    });
    let (copied, decoded) = (temp_root("edit-copied"), temp_root("edit-decoded"));
    for (from, to) in [(&*input, &copied), (&*decoding, &decoded)] {
        let (code, _, err) = surgvla(&["edit", text(from), "--drop", "1,3-4", "--out", text(to)]);
        assert_eq!(code, 0, "{err}");
    }
    // Copied: every column but the five surgvla numbers anew keeps the input's zstd; those
    // five are stored uncompressed (no codec made per episode), and those whose values differ
    // row by row without a dictionary.
    let renumbered = [
        "timestamp",
        "frame_index",
        "episode_index",
        "index",
        "task_index",
    ];
    let groups = codecs(&copied);
    assert_eq!(groups.len(), 3, "one row group per kept episode");
    for group in &groups {
        for (column, codec, dictionary) in group {
            let anew = renumbered.contains(&column.as_str());
            let distinct = ["timestamp", "frame_index", "index"].contains(&column.as_str());
            assert_eq!(*dictionary, !distinct, "{column}: a dictionary");
            let expected = if anew {
                Compression::UNCOMPRESSED
            } else {
                Compression::ZSTD(Default::default())
            };
            assert_eq!(
                std::mem::discriminant(codec),
                std::mem::discriminant(&expected),
                "{column}: {codec:?}"
            );
        }
    }
    // Written again: surgvla's own codecs (zstd for the depth images only, snappy for the
    // vectors and indices: a zstd codec costs a reader more to make than it saves on them).
    for (column, codec, _) in codecs(&decoded).iter().flatten() {
        let zstd = matches!(codec, Compression::ZSTD(_));
        assert_eq!(
            zstd,
            column == "observation.images.depth.bytes",
            "{column}: {codec:?}"
        );
        if column == "observation.state.list.item" {
            assert_eq!(*codec, Compression::SNAPPY);
        }
    }
    // Both read as the input's episodes 0, 2 and 5, renumbered, with the same statistics.
    assert_holds(&episodes(&copied), &original, &[0, 2, 5]);
    assert_holds(&episodes(&decoded), &original, &[0, 2, 5]);
    let stats = |root: &Path| std::fs::read(root.join("meta/stats.json")).expect("stats");
    assert_eq!(text_of(&stats(&copied)), text_of(&stats(&decoded)));
    let (code, _, err) = surgvla(&["validate", text(&copied)]);
    assert_eq!(code, 0, "{err}");
}

/// Where a video feature has no exact pixel statistics (a dataset lerobot wrote), its
/// per-episode statistics are the episodes table's own, carried to the kept episodes' rows:
/// the table's statistics columns are read for the video features (only).
#[test]
fn a_video_features_stored_statistics_travel_without_its_exact_ones() {
    let input = temp_root("edit-summary-input");
    for (relative, bytes) in tree(video_input()) {
        let path = input.join(relative);
        std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
        std::fs::write(path, bytes).expect("copy");
    }
    let table = |root: &Path| root.join("meta/episodes/chunk-000/file-000.parquet");
    let video = "observation.images.endoscope";
    rewrite_parquet(&table(&input), |batch| {
        let nulls: ArrayRef = Arc::new(arrow_array::StringArray::new_null(batch.num_rows()));
        with_column(batch, &format!("surgvla/pixel_stats/{video}"), nulls)
    });
    let out = temp_root("edit-summary");
    let (code, _, err) = surgvla(&["edit", text(&input), "--drop", "1,4", "--out", text(&out)]);
    assert_eq!(code, 0, "{err}");
    let read = |root: &Path| {
        surgvla::export::lerobot::read::read_parquet(&table(root)).expect("episodes table")
    };
    let (before, after) = (read(&input), read(&out));
    let (before, after) = (&before[0], &after[0]);
    let stats: Vec<String> = (before.schema().fields().iter())
        .map(|f| f.name().clone())
        .filter(|name| name.starts_with(&format!("stats/{video}/")))
        .collect();
    assert_eq!(stats.len(), 10, "{stats:?}");
    for name in &stats {
        let (was, now) = (
            before.column_by_name(name).expect("input column"),
            after.column_by_name(name).expect("output column"),
        );
        for (row, kept) in [0, 2, 3, 5].into_iter().enumerate() {
            assert_eq!(
                now.slice(row, 1).to_data(),
                was.slice(kept, 1).to_data(),
                "{name}: episode {kept}"
            );
        }
    }
}

fn text_of(bytes: &[u8]) -> &str {
    std::str::from_utf8(bytes).expect("utf-8")
}

#[test]
fn selectors_splits_renames_and_instructions_compose() {
    let input = video_input();
    let original = episodes(input);
    // By task and length.
    let shortest = original
        .iter()
        .map(|e| e.steps.len())
        .min()
        .expect("episodes");
    let out = temp_root("edit-select");
    let (code, _, err) = surgvla(&[
        "edit",
        text(input),
        "--keep",
        "task=t2-1",
        "--drop",
        &format!("length={shortest}"),
        "--keep",
        "0",
        "--out",
        text(&out),
    ]);
    assert_eq!(code, 0, "{err}");
    let kept: Vec<usize> = (0..6)
        .filter(|i| *i == 0 || original[*i].meta.task_code == "T2-1")
        .filter(|i| original[*i].steps.len() != shortest)
        .collect();
    assert_holds(&episodes(&out), &original, &kept);

    // Splits as folders, each saying its name; seeded and stratified by task.
    let split = temp_root("edit-split");
    let run = |out: &Path, extra: &[&str]| {
        let mut args = vec![
            "edit",
            text(input),
            "--split",
            "train=0.67,val=0.33",
            "--seed",
            "3",
            "--out",
            text(out),
        ];
        args.extend(extra);
        surgvla(&args)
    };
    let (code, stdout, err) = run(&split, &["--verify"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(stdout.matches("verified").count(), 2, "{stdout}");
    let (train, val) = (episodes(&split.join("train")), episodes(&split.join("val")));
    assert_eq!((train.len(), val.len()), (4, 2));
    for task in ["T1-1", "T2-1"] {
        assert_eq!(val.iter().filter(|e| e.meta.task_code == task).count(), 1);
    }
    assert_eq!(info_json(&split.join("val"))["splits"]["val"], "0:2");
    let card = std::fs::read_to_string(split.join("val/README.md")).expect("card");
    assert!(
        card.contains("Edited with `surgvla edit`: 2 of the input's 6 episodes; split `train=0.67,val=0.33` (seed 3)"),
        "{card}"
    );
    // The same seed, one dataset with the splits in info.json, episodes grouped by split.
    let inside = temp_root("edit-split-info");
    let (code, _, err) = run(&inside, &["--splits-in-info"]);
    assert_eq!(code, 0, "{err}");
    let splits = &info_json(&inside)["splits"];
    assert_eq!(
        (&splits["train"], &splits["val"]),
        (&"0:4".into(), &"4:6".into())
    );
    let grouped = episodes(&inside);
    let seeds = |e: &[Episode]| e.iter().map(|e| e.meta.seed).collect::<Vec<_>>();
    assert_eq!(seeds(&grouped[..4]), seeds(&train));
    assert_eq!(seeds(&grouped[4..]), seeds(&val));

    // The camera renamed, an instruction replaced, depth removed.
    let renamed = temp_root("edit-rename");
    let old = &original[0].meta.instruction;
    let (code, _, err) = surgvla(&[
        "edit",
        text(input),
        "--rename-feature",
        "observation.images.endoscope=observation.images.image",
        "--map-tasks",
        &format!("{old}=lift it"),
        "--remove-feature",
        "depth",
        "--out",
        text(&renamed),
    ]);
    assert_eq!(code, 0, "{err}");
    let features = info_json(&renamed)["features"].clone();
    assert!(
        features.get("observation.images.image").is_some(),
        "{features}"
    );
    assert!(features.get("observation.images.endoscope").is_none());
    assert!(features.get("observation.images.depth").is_none());
    let edited = episodes(&renamed);
    for (a, b) in edited.iter().zip(&original) {
        let expected = if b.meta.instruction == *old {
            "lift it"
        } else {
            &b.meta.instruction
        };
        assert_eq!(a.meta.instruction, expected);
        let samples = |e: &Episode, key: &str| e.encoded_video(key).expect(key).frames.clone();
        assert!(
            samples(a, "observation.images.image") == samples(b, "observation.images.endoscope")
        );
    }
}

#[test]
fn mistakes_exit_2_and_a_dry_run_writes_nothing() {
    let input = video_input();
    let out = temp_root("edit-mistakes");
    let target = out.join("result");
    for (args, expected) in [
        (
            vec!["--drop", "operator=ann"],
            "no episode has a field \"operator\"",
        ),
        (vec!["--keep", "99"], "keeps none"),
        (vec!["--drop", "7-2"], "ends before it starts"),
        (vec!["--split", "train=0.5,val=0.4"], "add up to"),
        (
            vec!["--rename-feature", "action=act"],
            "whose name surgvla's readers look for",
        ),
        (
            vec!["--rename-feature", "nothing=x"],
            "has no feature nothing",
        ),
        (vec!["--remove-feature", "action"], "keeps"),
    ] {
        let mut all = vec!["edit", text(input), "--out", text(&target)];
        all.extend(&args);
        let (code, _, err) = surgvla(&all);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(expected), "{args:?}: {err}");
        assert!(!target.exists(), "{args:?} wrote something");
    }
    let (code, stdout, err) = surgvla(&[
        "edit",
        text(input),
        "--drop",
        "success=true",
        "--keep",
        "0-2",
        "--out",
        text(&target),
    ]);
    assert_eq!(code, 2, "every episode succeeded: {stdout} {err}");
    let (code, stdout, err) = surgvla(&[
        "edit",
        text(input),
        "--split",
        "train=0.5,val=0.5",
        "--dry-run",
        "--out",
        text(&target),
    ]);
    assert_eq!(code, 0, "{err}");
    // Three episodes a task: each task's odd one goes to the first split.
    assert!(stdout.contains("would write 4 episodes"), "{stdout}");
    assert!(stdout.contains("would write 2 episodes"), "{stdout}");
    assert!(stdout.contains("encode again: none"), "{stdout}");
    assert!(!target.exists(), "a dry run wrote {}", target.display());
}

/// Episode 1's video span moved one frame later: it starts on a frame that is not a keyframe
/// (as when episodes are cut from one continuous recording).
fn mid_gop(input: &Path, root: &Path) {
    let copy = tree(input);
    for (name, bytes) in copy {
        let path = root.join(&name);
        std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
        std::fs::write(path, bytes).expect("write");
    }
    std::fs::remove_file(root.join("meta/surgvla_manifest.json")).expect("manifest");
    let fps = info_json(root)["fps"].as_f64().expect("fps");
    let file = root.join("meta/episodes/chunk-000/file-000.parquet");
    rewrite_parquet(&file, |batch| {
        let mut batch = batch;
        for side in ["from", "to"] {
            let name = format!("videos/observation.images.endoscope/{side}_timestamp");
            let column = batch.column_by_name(&name).expect("span column");
            let values = column.as_any().downcast_ref::<Float64Array>().expect("f64");
            let shifted: Float64Array = (0..values.len())
                .map(|i| Some(values.value(i) + if i == 1 { 1.0 / fps } else { 0.0 }))
                .collect();
            batch = with_column(batch, &name, Arc::new(shifted) as ArrayRef);
        }
        batch
    });
}

#[test]
fn an_episode_starting_mid_gop_is_named_then_encoded_again_on_request() {
    let root = temp_root("edit-gop");
    let input = root.join("input");
    mid_gop(video_input(), &input);
    let out = root.join("out");
    let (code, _, err) = surgvla(&["edit", text(&input), "--drop", "0", "--out", text(&out)]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("input episode 1") && err.contains("--allow-reencode"),
        "{err}"
    );
    assert!(!out.exists(), "a refused edit left {}", out.display());
    let (code, stdout, _) = surgvla(&[
        "edit",
        text(&input),
        "--drop",
        "0",
        "--dry-run",
        "--out",
        text(&out),
    ]);
    assert_eq!(code, 0);
    assert!(stdout.contains("encode again: 1\n"), "{stdout}");
    let (code, stdout, err) = surgvla(&[
        "edit",
        text(&input),
        "--drop",
        "0",
        "--allow-reencode",
        "--verify",
        "--out",
        text(&out),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(
        stdout.contains("encoded again: episode 0's observation.images.endoscope"),
        "{stdout}"
    );
    assert!(stdout.contains("verified"), "{stdout}");
    // Only that episode was encoded again: the others' samples are the input's.
    let (original, edited) = (episodes(&input), episodes(&out));
    assert_holds(&edited[1..], &original, &[2, 3, 4, 5]);
    let first = edited[0]
        .encoded_video("observation.images.endoscope")
        .expect("video");
    assert!(first.frames[0].keyframe && first.shown.is_none());
    assert_eq!(first.frames.len(), original[1].steps.len());
    let (code, _, err) = surgvla(&["validate", text(&out)]);
    assert_eq!(code, 0, "{err}");
}

/// A killed edit resumes to the bytes of an uninterrupted one; a different edit into the same
/// folder is refused.
#[test]
fn a_killed_edit_resumes_to_the_uninterrupted_bytes() {
    let root = temp_root("edit-killed");
    let input = root.join("input");
    collect(&input, &["T1-1", "8", "--data-file-mb", "1"]);
    let edit = |out: &Path, drop: &str, extra: &[&str]| {
        let mut args = vec!["edit", text(&input), "--drop", drop, "--out", text(out)];
        args.extend(extra);
        args.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let reference = root.join("reference");
    let args = edit(&reference, "2", &[]);
    let (code, _, err) = surgvla(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(code, 0, "{err}");
    let killed = root.join("killed");
    let args = edit(&killed, "2", &["--threads", "1"]);
    kill_after_checkpoint(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        &killed,
    );
    let other = edit(&killed, "3", &["--resume"]);
    let (code, _, err) = surgvla(&other.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(code, 2, "another edit resumed: {err}");
    let again = edit(&killed, "2", &["--resume"]);
    let (code, _, err) = surgvla(&again.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(code, 0, "{err}");
    assert!(tree(&killed) == tree(&reference), "resumed edit differs");
}

/// Files another tool wrote beside the data, and info.json keys surgvla has no model for, are
/// carried over as they are.
#[test]
fn metadata_other_tools_wrote_is_carried_over() {
    let root = temp_root("edit-carry");
    let input = root.join("input");
    for (name, bytes) in tree(video_input()) {
        let path = input.join(&name);
        std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
        std::fs::write(path, bytes).expect("write");
    }
    let mut info = info_json(&input);
    info["open_h"] = serde_json::json!({"institution": "somewhere", "arms": 2});
    std::fs::write(
        input.join("meta/info.json"),
        serde_json::to_vec_pretty(&info).expect("json"),
    )
    .expect("info");
    std::fs::write(input.join("meta/README.md"), "# Open-H contribution\n").expect("readme");
    let out = root.join("out");
    let (code, _, err) = surgvla(&["edit", text(&input), "--drop", "0", "--out", text(&out)]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(info_json(&out)["open_h"], info["open_h"]);
    assert_eq!(
        std::fs::read(out.join("meta/README.md")).expect("carried"),
        b"# Open-H contribution\n"
    );
    let manifest = std::fs::read_to_string(out.join("meta/surgvla_manifest.json")).expect("m");
    assert!(
        manifest.contains("meta/README.md"),
        "listed in the manifest"
    );
    let (code, _, err) = surgvla(&["validate", text(&out)]);
    assert_eq!(code, 0, "{err}");
}

/// RLDS is edited as RLDS: the same name, version and shard size, the kept episodes' records
/// (their PNG images copied, not encoded again).
#[test]
fn an_rlds_dataset_is_edited_in_its_own_format() {
    let root = temp_root("edit-rlds");
    let input = root.join("input");
    collect(&input, &["T1-1", "3", "--format", "rlds"]);
    let out = root.join("out");
    let (code, stdout, err) = surgvla(&[
        "edit",
        text(&input),
        "--drop",
        "1",
        "--verify",
        "--out",
        text(&out),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("verified"), "{stdout}");
    let (original, edited) = (episodes(&input), episodes(&out));
    assert_eq!(edited.len(), 2);
    for (a, b) in edited.iter().zip([&original[0], &original[2]]) {
        assert_eq!(a.meta.seed, b.meta.seed);
        assert_eq!(a.steps.len(), b.steps.len());
        assert!(
            a.steps
                .iter()
                .zip(&b.steps)
                .all(|(x, y)| x.rgb == y.rgb && x.action == y.action)
        );
    }
    let names = |root: &Path| {
        let mut names: Vec<String> = tree(root)
            .into_keys()
            .filter(|n| n.contains("tfrecord") || n.ends_with("features.json"))
            .collect();
        names.sort();
        names
    };
    assert_eq!(names(&out), names(&input));
}

/// An RLDS dataset split by `edit` is one TFDS dataset per split, each holding its episodes in
/// the split it is named after (what `as_dataset(split="val")` reads), read back, validated and
/// converted with that name.
#[test]
fn an_rlds_split_is_written_under_its_own_split_name() {
    let root = temp_root("edit-rlds-split");
    let input = root.join("input");
    collect(&input, &["T1-1", "3", "--format", "rlds"]);
    let out = root.join("out");
    let (code, _, err) = surgvla(&[
        "edit",
        text(&input),
        "--split",
        "train=0,val=1+2",
        "--out",
        text(&out),
    ]);
    assert_eq!(code, 0, "{err}");
    let original = episodes(&input);
    for (split, kept) in [("train", vec![0]), ("val", vec![1, 2])] {
        let folder = out.join(split);
        let shards: Vec<String> = (tree(&folder).into_keys())
            .filter(|n| n.contains(".tfrecord-"))
            .collect();
        let shard = format!("surgvla_benchmark-{split}.tfrecord-00000-of-00001");
        assert!(
            shards.len() == 1 && shards[0].ends_with(&shard),
            "{shards:?}"
        );
        let version = folder.join("surgvla_benchmark/1.0.0");
        let dataset_info: serde_json::Value = serde_json::from_slice(
            &std::fs::read(version.join("dataset_info.json")).expect("dataset_info"),
        )
        .expect("json");
        assert_eq!(dataset_info["splits"][0]["name"], split);
        // The card's snippet and the OpenVLA guide read the split by its name.
        let read_as = format!("as_dataset(split=\"{split}\")");
        for doc in ["README.md", "OPENVLA.md"] {
            let text = std::fs::read_to_string(folder.join(doc)).expect("doc");
            assert_eq!(
                text.contains(&read_as),
                doc == "README.md" || split != "train",
                "{split} {doc}"
            );
        }
        let edited = episodes(&folder);
        let seeds: Vec<u64> = edited.iter().map(|e| e.meta.seed).collect();
        let expected: Vec<u64> = kept.iter().map(|&i| original[i].meta.seed).collect();
        assert_eq!(seeds, expected, "{split}");
        let (code, stdout, err) = surgvla(&["validate", text(&folder)]);
        assert_eq!(code, 0, "{split}: {stdout}{err}");
    }
    // Converted, the split keeps its name (LeRobot's info.json `splits`).
    let lerobot = root.join("val-lerobot");
    let (code, _, err) = surgvla(&[
        "convert",
        text(&out.join("val")),
        "--to",
        "lerobot",
        "--out",
        text(&lerobot),
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        info_json(&lerobot)["splits"],
        serde_json::json!({"val": "0:2"})
    );
    // One RLDS dataset holds one split: recording several in it is refused, nothing written.
    let one = root.join("one");
    let (code, _, err) = surgvla(&[
        "edit",
        text(&input),
        "--split",
        "train=0,val=1+2",
        "--splits-in-info",
        "--out",
        text(&one),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("--splits-in-info") && err.contains("RLDS"),
        "{err}"
    );
    assert!(!one.exists());
}
