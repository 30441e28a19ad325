//! The LeRobot v3.0 writer: round trip through our own reader, metadata, file roll-over, crash
//! safety and bad input. (The real lerobot loader is exercised by `tests/interop/`.)

use crate::util::{info, temp_root};
use surgvla::collect::record::{RecordOptions, episode_seed, record_episode};
use surgvla::episode::Episode;
use surgvla::export::INCOMPLETE_MARKER;
use surgvla::export::lerobot::read::{data_files, read_frames, read_parquet, schema_metadata};
use surgvla::export::lerobot::{LeRobotOptions, LeRobotWriter};
use surgvla::export::{EpisodeSink, ExportError};
use surgvla::media::tiff::decode_f32_tiff;
use surgvla::policy::ExpertLibrary;
use surgvla::task::TaskId;

fn episodes(count: u64, max_steps: u32) -> Vec<Episode> {
    let options = RecordOptions {
        max_steps: Some(max_steps),
        ..RecordOptions::default()
    };
    let tasks = [
        TaskId::GauzePick,
        TaskId::NeedlePickDistractors,
        TaskId::Hemostasis,
    ];
    let library = ExpertLibrary::builtin().expect("built-in plans");
    (0..count)
        .map(|i| {
            let task = tasks[i as usize % tasks.len()];
            record_episode(&library, task, episode_seed(9, task, i), i, &options).expect("record")
        })
        .collect()
}

fn write(
    root: &std::path::Path,
    episodes: &[Episode],
    options: LeRobotOptions,
) -> surgvla::export::Summary {
    write_with(root, &info(false), episodes, options)
}

fn write_with(
    root: &std::path::Path,
    info: &surgvla::export::DatasetInfo,
    episodes: &[Episode],
    options: LeRobotOptions,
) -> surgvla::export::Summary {
    let mut writer: Box<dyn EpisodeSink> =
        Box::new(LeRobotWriter::create(root, info, options).expect("create"));
    for episode in episodes {
        writer
            .write_batch(std::slice::from_ref(episode))
            .expect("write episode");
    }
    let summary = writer.finish().expect("finish");
    assert_eq!(writer.finish().expect("finish twice"), summary);
    summary
}

fn decode_png(bytes: &[u8]) -> Vec<u8> {
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder.read_info().expect("png header");
    let mut buffer = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut buffer).expect("png frame");
    buffer.truncate(info.buffer_size());
    buffer
}

#[test]
fn frames_round_trip_bit_exact() {
    let root = temp_root("roundtrip");
    let recorded = episodes(3, 7);
    let summary = write_with(&root, &info(true), &recorded, LeRobotOptions::default());
    assert_eq!(summary.episodes, 3);
    let keys = [
        "observation.images.endoscope",
        "observation.images.depth",
        "observation.images.mask",
    ];
    let stored = read_frames(&root, &keys).expect("read back");
    let steps: Vec<_> = recorded
        .iter()
        .flat_map(|e| {
            e.steps
                .iter()
                .enumerate()
                .map(move |(i, s)| (e.meta.index, i, s))
        })
        .collect();
    assert_eq!(stored.len(), steps.len());
    assert_eq!(summary.frames as usize, steps.len());
    for (k, (frame, (episode, i, step))) in stored.iter().zip(&steps).enumerate() {
        assert_eq!(frame.index, k as i64);
        assert_eq!(
            (frame.episode_index, frame.frame_index),
            (*episode as i64, *i as i64)
        );
        assert_eq!(frame.timestamp, (*i as f64 / 5.0) as f32);
        assert_eq!(frame.state, step.state.to_vec());
        assert_eq!(frame.action, step.action.to_vec());
        assert_eq!(frame.environment_state, step.environment_state.to_vec());
        assert_eq!(decode_png(&frame.images[0].1), step.rgb);
        let (w, h, depth) = decode_f32_tiff(&frame.images[1].1).expect("tiff");
        assert_eq!((w, h), (224, 224));
        assert_eq!(
            depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
            step.depth_m.iter().map(|d| d.to_bits()).collect::<Vec<_>>()
        );
        assert_eq!(decode_png(&frame.images[2].1), step.mask);
    }
}

#[test]
fn metadata_follows_the_lerobot_layout() {
    let root = temp_root("meta");
    let recorded = episodes(3, 5);
    write(&root, &recorded, LeRobotOptions::default());
    assert!(!root.join(INCOMPLETE_MARKER).exists());
    let info: serde_json::Value =
        serde_json::from_slice(&std::fs::read(root.join("meta/info.json")).expect("info"))
            .expect("json");
    assert_eq!(info["codebase_version"], "v3.0");
    assert_eq!(info["total_episodes"], 3);
    assert_eq!(info["total_frames"], 15);
    assert_eq!(info["total_tasks"], 3);
    assert_eq!(info["splits"]["train"], "0:3");
    assert_eq!(info["robot_type"], "dvrk_psm");
    let keys: Vec<&String> = info["features"]
        .as_object()
        .expect("features")
        .keys()
        .collect();
    assert_eq!(
        keys,
        [
            "observation.images.endoscope",
            "observation.images.depth",
            "observation.state",
            "observation.environment_state",
            "action",
            "timestamp",
            "frame_index",
            "episode_index",
            "index",
            "task_index"
        ]
    );
    assert_eq!(
        info["features"]["observation.images.depth"]["info"]["depth_unit"],
        "m"
    );
    // The data columns follow the features' order.
    let batch = &read_parquet(&data_files(&root).expect("files")[0]).expect("data")[0];
    let columns: Vec<String> = batch
        .schema()
        .fields()
        .iter()
        .map(|f| f.name().clone())
        .collect();
    assert_eq!(columns.iter().collect::<Vec<_>>(), keys);
    // tasks.parquet is a pandas frame indexed by the task string.
    let pandas = schema_metadata(&root.join("meta/tasks.parquet"), "pandas")
        .expect("read")
        .expect("pandas metadata");
    let pandas: serde_json::Value = serde_json::from_str(&pandas).expect("json");
    assert_eq!(pandas["index_columns"], serde_json::json!(["task"]));
    // Episodes: positional, contiguous from/to indices, stats with quantiles.
    let episodes_table =
        &read_parquet(&root.join("meta/episodes/chunk-000/file-000.parquet")).expect("episodes")[0];
    let int = |name: &str| {
        episodes_table
            .column_by_name(name)
            .and_then(|c| c.as_any().downcast_ref::<arrow_array::Int64Array>())
            .expect(name)
            .values()
            .to_vec()
    };
    assert_eq!(int("episode_index"), [0, 1, 2]);
    assert_eq!(int("dataset_from_index"), [0, 5, 10]);
    assert_eq!(int("dataset_to_index"), [5, 10, 15]);
    assert!(episodes_table.column_by_name("stats/action/q99").is_some());
    assert!(
        episodes_table
            .column_by_name("stats/observation.images.endoscope/mean")
            .is_some()
    );
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(root.join("meta/stats.json")).expect("stats"))
            .expect("json");
    assert_eq!(stats["action"]["count"], serde_json::json!([15]));
    assert_eq!(
        stats["observation.images.endoscope"]["mean"]
            .as_array()
            .expect("3 channels")
            .len(),
        3
    );
}

#[test]
fn output_is_a_pure_function_of_the_episodes() {
    let recorded = episodes(2, 4);
    let (a, b) = (temp_root("pure-a"), temp_root("pure-b"));
    write(&a, &recorded, LeRobotOptions::default());
    write(&b, &recorded, LeRobotOptions::default());
    for file in [
        "data/chunk-000/file-000.parquet",
        "meta/info.json",
        "meta/stats.json",
        "meta/tasks.parquet",
        "meta/episodes/chunk-000/file-000.parquet",
    ] {
        assert_eq!(
            std::fs::read(a.join(file)).expect("a"),
            std::fs::read(b.join(file)).expect("b"),
            "{file}"
        );
    }
}

#[test]
fn data_files_roll_over_by_size() {
    let root = temp_root("rollover");
    // Each episode of 25 frames is over 1 MB, so every episode closes its file.
    let recorded = episodes(3, 25);
    let summary = write(
        &root,
        &recorded,
        LeRobotOptions {
            data_file_size_mb: 1,
            ..LeRobotOptions::default()
        },
    );
    let files = data_files(&root).expect("files");
    assert_eq!(files.len(), 3, "{files:?}");
    assert_eq!(summary.episodes, 3);
    let table =
        &read_parquet(&root.join("meta/episodes/chunk-000/file-000.parquet")).expect("episodes")[0];
    let file_index = table
        .column_by_name("data/file_index")
        .and_then(|c| c.as_any().downcast_ref::<arrow_array::Int64Array>())
        .expect("file index");
    assert_eq!(file_index.values().to_vec(), [0, 1, 2]);
}

#[test]
fn an_unfinished_dataset_is_obviously_incomplete() {
    let root = temp_root("crash");
    {
        let mut writer =
            LeRobotWriter::create(&root, &info(false), LeRobotOptions::default()).expect("create");
        writer
            .write_batch(std::slice::from_ref(&episodes(1, 3)[0]))
            .expect("write");
        // Dropped without finish: the process "died" here.
    }
    assert!(root.join(INCOMPLETE_MARKER).exists());
    assert!(
        !root.join("meta/info.json").exists(),
        "LeRobot must refuse it"
    );
    assert!(
        data_files(&root).expect("list").is_empty(),
        "no data file under its final name"
    );
    // validate and info say so in one finding, with the command that finishes it.
    let options = surgvla::export::validate::ValidateOptions::default();
    for quick in [false, true] {
        let options = surgvla::export::validate::ValidateOptions {
            quick,
            ..options.clone()
        };
        let report = surgvla::export::validate::validate(&root, &options).expect("validate");
        assert!(!report.valid);
        assert_eq!(report.errors.len(), 1, "{:?}", report.errors);
        let finding = &report.errors[0];
        assert_eq!(finding.check, "interrupted");
        assert!(finding.message.contains("--resume"), "{}", finding.message);
        assert!(
            finding.message.contains("meta/info.json"),
            "{}",
            finding.message
        );
    }
    // And a new dataset will not be written over it (once the dropped writer's lock is gone).
    let attempt = crate::util::unless_briefly_locked(|| {
        LeRobotWriter::create(&root, &info(false), LeRobotOptions::default())
    });
    match attempt {
        Err(ExportError::NotEmpty { path, interrupted }) => {
            assert_eq!(path, *root);
            assert!(interrupted, "the error must say it can be resumed");
        }
        other => panic!("expected NotEmpty, got {:?}", other.err()),
    }
}

#[test]
fn bad_episodes_are_rejected_with_a_reason() {
    let root = temp_root("bad");
    let mut writer =
        LeRobotWriter::create(&root, &info(false), LeRobotOptions::default()).expect("create");
    let mut episode = episodes(1, 3).remove(0);
    episode.steps[1].rgb.truncate(100);
    let error = writer
        .write_batch(std::slice::from_ref(&episode))
        .expect_err("wrong image size");
    assert!(error.to_string().contains("episode 0 step 1"), "{error}");
    let mut later = episodes(2, 2).remove(1);
    later.meta.index = 5;
    let error = writer
        .write_batch(std::slice::from_ref(&later))
        .expect_err("out of order");
    assert!(error.to_string().contains("episode index 5"), "{error}");
}

/// The committed schema is what the writer declares. After an intended change, regenerate with
/// `cargo run --release -- schema --with-mask > schemas/lerobot_features.json`.
#[test]
fn schema_snapshot_matches_the_features() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("schemas/lerobot_features.json");
    let committed: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&path).expect("schema file")).expect("json");
    let features = info(true).features;
    assert_eq!(
        committed,
        surgvla::export::lerobot::features_json(&features)
    );
}

#[test]
fn video_mode_writes_one_growing_mp4_and_its_spans() {
    use surgvla::export::lerobot::VideoOptions;
    for (video, codec) in [
        (VideoOptions::default(), "av1"),
        (VideoOptions::h264(), "h264"),
    ] {
        let root = temp_root("video");
        let recorded = episodes(3, 6);
        let options = LeRobotOptions {
            video: Some(video),
            ..LeRobotOptions::default()
        };
        let summary = write(&root, &recorded, options);
        assert_eq!(summary.frames, 18);
        let mp4 = root.join("videos/observation.images.endoscope/chunk-000/file-000.mp4");
        let bytes = std::fs::read(&mp4).expect("mp4 written");
        assert_eq!(&bytes[4..8], b"ftyp");
        let info: serde_json::Value =
            serde_json::from_slice(&std::fs::read(root.join("meta/info.json")).expect("info"))
                .expect("json");
        let rgb = &info["features"]["observation.images.endoscope"];
        assert_eq!(rgb["dtype"], "video");
        assert_eq!(rgb["info"]["video.codec"], codec);
        // The RGB column is not in the parquet; depth still is.
        let batch = &read_parquet(&data_files(&root).expect("files")[0]).expect("data")[0];
        assert!(
            batch
                .column_by_name("observation.images.endoscope")
                .is_none()
        );
        assert!(batch.column_by_name("observation.images.depth").is_some());
        let table = &read_parquet(&root.join("meta/episodes/chunk-000/file-000.parquet"))
            .expect("episodes")[0];
        let floats = |name: &str| {
            table
                .column_by_name(name)
                .and_then(|c| c.as_any().downcast_ref::<arrow_array::Float64Array>())
                .expect(name)
                .values()
                .to_vec()
        };
        assert_eq!(
            floats("videos/observation.images.endoscope/from_timestamp"),
            [0.0, 1.2, 2.4]
        );
        assert_eq!(
            floats("videos/observation.images.endoscope/to_timestamp"),
            [1.2, 2.4, 3.6]
        );
    }
}

#[test]
fn video_files_roll_over_by_their_samples_and_close_with_the_data_file() {
    use surgvla::export::lerobot::VideoOptions;
    // The muxer holds a file's samples until it closes, so its size on disk says nothing: the
    // writer counts the samples. A video limit of 0 MB fills each file with one episode, while
    // the data files (100 MB) would hold all three; the data file closes with its video.
    let root = temp_root("video-rollover");
    let recorded = episodes(3, 6);
    let options = LeRobotOptions {
        video: Some(VideoOptions {
            file_size_mb: 0,
            ..VideoOptions::h264()
        }),
        ..LeRobotOptions::default()
    };
    write(&root, &recorded, options);
    let whole = temp_root("video-whole");
    let one_file = LeRobotOptions {
        video: Some(VideoOptions::h264()),
        ..LeRobotOptions::default()
    };
    write(&whole, &recorded, one_file);
    let videos = root.join("videos/observation.images.endoscope/chunk-000");
    for file in 0..3 {
        assert!(
            videos.join(format!("file-{file:03}.mp4")).exists(),
            "{file}"
        );
    }
    assert!(!videos.join("file-003.mp4").exists());
    assert_eq!(data_files(&root).expect("files").len(), 3);
    let table =
        &read_parquet(&root.join("meta/episodes/chunk-000/file-000.parquet")).expect("episodes")[0];
    let ints = |name: &str| {
        (table.column_by_name(name))
            .and_then(|c| c.as_any().downcast_ref::<arrow_array::Int64Array>())
            .expect(name)
            .values()
            .to_vec()
    };
    let key = "videos/observation.images.endoscope";
    assert_eq!(ints(&format!("{key}/file_index")), [0, 1, 2]);
    assert_eq!(ints("data/file_index"), [0, 1, 2]);
    let from = (table.column_by_name(&format!("{key}/from_timestamp")))
        .and_then(|c| c.as_any().downcast_ref::<arrow_array::Float64Array>())
        .expect("from");
    assert_eq!(from.values().to_vec(), [0.0, 0.0, 0.0]);
    // Read back, each episode's samples are the ones written into a single file.
    let samples = |root: &std::path::Path| -> Vec<Vec<Vec<u8>>> {
        let source = surgvla::export::open_source(root).expect("open");
        source
            .map(|e| {
                let e = e.expect("episode");
                let video = e
                    .encoded_video("observation.images.endoscope")
                    .expect("video");
                video.frames.iter().map(|f| f.data.clone()).collect()
            })
            .collect()
    };
    let rolled = samples(&root);
    assert_eq!(rolled.len(), 3);
    assert!(rolled.iter().all(|frames| frames.len() == 6));
    assert_eq!(rolled, samples(&whole));
}

#[test]
fn version_2_1_writes_one_file_per_episode_and_jsonl_metadata() {
    use surgvla::export::lerobot::{LeRobotVersion, VideoOptions};
    let root = temp_root("v21");
    let recorded = episodes(2, 4);
    let options = LeRobotOptions {
        version: LeRobotVersion::V21,
        video: Some(VideoOptions::default()),
        ..LeRobotOptions::default()
    };
    write(&root, &recorded, options);
    for e in 0..2 {
        assert!(
            root.join(format!("data/chunk-000/episode_{e:06}.parquet"))
                .exists()
        );
        assert!(
            root.join(format!(
                "videos/chunk-000/observation.images.endoscope/episode_{e:06}.mp4"
            ))
            .exists()
        );
    }
    let info: serde_json::Value =
        serde_json::from_slice(&std::fs::read(root.join("meta/info.json")).expect("info"))
            .expect("json");
    assert_eq!(info["codebase_version"], "v2.1");
    assert_eq!(info["total_chunks"], 1);
    assert_eq!(info["total_videos"], 2);
    let episodes_jsonl =
        std::fs::read_to_string(root.join("meta/episodes.jsonl")).expect("episodes.jsonl");
    let first: serde_json::Value =
        serde_json::from_str(episodes_jsonl.lines().next().expect("a line")).expect("json");
    assert_eq!(first["episode_index"], 0);
    assert_eq!(first["length"], 4);
    let stats_line = std::fs::read_to_string(root.join("meta/episodes_stats.jsonl"))
        .expect("episodes_stats.jsonl");
    let stats: serde_json::Value =
        serde_json::from_str(stats_line.lines().next().expect("a line")).expect("json");
    assert_eq!(stats["stats"]["action"]["count"], serde_json::json!([4]));
    assert_eq!(
        std::fs::read_to_string(root.join("meta/tasks.jsonl"))
            .expect("tasks")
            .lines()
            .count(),
        2
    );
}

#[test]
fn batched_video_encoding_writes_the_same_bytes_as_one_by_one() {
    use surgvla::export::lerobot::VideoOptions;
    let recorded = episodes(3, 5);
    let options = LeRobotOptions {
        video: Some(VideoOptions::default()),
        ..LeRobotOptions::default()
    };
    let (one, batch) = (temp_root("one-by-one"), temp_root("batched"));
    write(&one, &recorded, options.clone());
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("pool");
    pool.install(|| {
        let mut writer: Box<dyn EpisodeSink> =
            Box::new(LeRobotWriter::create(&batch, &info(false), options).expect("create"));
        writer.write_batch(&recorded).expect("batch");
        writer.finish().expect("finish");
    });
    for file in [
        "videos/observation.images.endoscope/chunk-000/file-000.mp4",
        "data/chunk-000/file-000.parquet",
        "meta/episodes/chunk-000/file-000.parquet",
        "meta/stats.json",
    ] {
        assert_eq!(
            std::fs::read(one.join(file)).expect("one"),
            std::fs::read(batch.join(file)).expect("batch"),
            "{file}"
        );
    }
}

#[test]
fn episodes_encoded_apart_write_the_same_bytes_as_batches() {
    // Image mode (PNG, TIFF, statistics made by the detached encoder on other threads) and
    // video mode, each against the sink's own batches.
    use surgvla::export::lerobot::VideoOptions;
    let recorded = episodes(4, 6);
    for (name, options) in [
        ("image", LeRobotOptions::default()),
        (
            "video",
            LeRobotOptions {
                video: Some(VideoOptions::default()),
                ..LeRobotOptions::default()
            },
        ),
    ] {
        let (batched, apart) = (
            temp_root(&format!("batched-{name}")),
            temp_root(&format!("apart-{name}")),
        );
        write(&batched, &recorded, options.clone());
        let mut writer: Box<dyn EpisodeSink> =
            Box::new(LeRobotWriter::create(&apart, &info(false), options).expect("create"));
        let encoder = writer.pipelined().expect("LeRobot encodes apart").encoder;
        let encoded: Vec<_> = std::thread::scope(|scope| {
            let jobs: Vec<_> = recorded
                .iter()
                .map(|episode| {
                    let encoder = encoder.clone();
                    scope.spawn(move || encoder.encode(episode).expect("encode"))
                })
                .collect();
            jobs.into_iter()
                .map(|job| job.join().expect("encoder thread"))
                .collect()
        });
        // Appended in two calls, as a producer hands them over when they are ready.
        let mut pairs: Vec<_> = recorded.iter().cloned().zip(encoded).collect();
        let rest = pairs.split_off(1);
        let sink = writer.pipelined().expect("LeRobot encodes apart").sink;
        sink.write_encoded(pairs).expect("first");
        sink.write_encoded(rest).expect("rest");
        writer.finish().expect("finish");
        assert_eq!(
            crate::util::tree(&batched),
            crate::util::tree(&apart),
            "{name}"
        );
        // An episode out of order is refused, encoded or not.
        let other = temp_root(&format!("refused-{name}"));
        let mut writer: Box<dyn EpisodeSink> = Box::new(
            LeRobotWriter::create(&other, &info(false), LeRobotOptions::default()).expect("create"),
        );
        let own = writer.pipelined().expect("LeRobot encodes apart");
        let encoded = own.encoder.encode(&recorded[1]).expect("encode");
        let error = (own.sink)
            .write_encoded(vec![(recorded[1].clone(), encoded)])
            .expect_err("out of order");
        assert!(error.to_string().contains("expected"), "{error}");
        // What another sink's encoder made is refused: its ticket is not this sink's.
        let foreign = encoder.encode(&recorded[0]).expect("encode");
        let sink = writer.pipelined().expect("LeRobot encodes apart").sink;
        let error = sink
            .write_encoded(vec![(recorded[0].clone(), foreign)])
            .expect_err("another sink's");
        assert!(error.to_string().contains("another sink"), "{error}");
    }
}

#[test]
fn episodes_encoded_frame_by_frame_write_the_same_bytes_as_batches() {
    // The stream `collect` uses: each step's pixels taken as it is recorded, encoded in
    // batches, the episode then appended without pixels. One episode longer than a batch.
    let mut recorded = episodes(3, 6);
    let mut long = recorded[0].clone();
    long.steps = std::iter::repeat_n(recorded[0].steps.clone(), 15)
        .flatten()
        .collect();
    recorded[0] = long;
    let (batched, streamed) = (temp_root("batched-stream"), temp_root("streamed"));
    write(&batched, &recorded, LeRobotOptions::default());
    let mut writer: Box<dyn EpisodeSink> = Box::new(
        LeRobotWriter::create(&streamed, &info(false), LeRobotOptions::default()).expect("create"),
    );
    let encoder = writer.pipelined().expect("LeRobot encodes apart").encoder;
    let mut pairs = Vec::new();
    let mut handed_back = 0;
    for episode in &recorded {
        let mut frames = encoder
            .frames(episode.steps.len())
            .expect("image mode streams");
        let mut kept = episode.clone();
        for step in &mut kept.steps {
            handed_back += frames.push(step).expect("push").len();
            assert!(
                step.rgb.is_empty() && step.depth_m.is_empty(),
                "pixels taken"
            );
        }
        let encoded = frames.finish(&kept).expect("finish");
        pairs.push((kept, encoded));
    }
    assert!(
        handed_back > 0,
        "a long episode's buffers come back to be drawn into"
    );
    let sink = writer.pipelined().expect("LeRobot encodes apart").sink;
    sink.write_encoded(pairs).expect("write");
    writer.finish().expect("finish");
    assert_eq!(crate::util::tree(&batched), crate::util::tree(&streamed));

    // A step of the wrong size is refused by the stream, and by the whole-episode encoder
    // (the sink leaves the images' sizes to them).
    let mut frames = encoder.frames(1).expect("image mode streams");
    let mut step = recorded[1].steps[0].clone();
    step.depth_m.pop();
    assert!(frames.push(&mut step).is_err());
    let mut short = recorded[1].clone();
    short.steps[2].rgb.truncate(10);
    assert!(encoder.encode(&short).is_err());

    // Video mode encodes whole episodes only.
    let video = temp_root("video-stream");
    let mut writer = LeRobotWriter::create(
        &video,
        &info(false),
        LeRobotOptions {
            video: Some(surgvla::export::lerobot::VideoOptions::default()),
            ..LeRobotOptions::default()
        },
    )
    .expect("create");
    let pipelined = EpisodeSink::pipelined(&mut writer).expect("LeRobot encodes apart");
    assert!(pipelined.encoder.frames(6).is_none());
}

#[test]
fn an_interrupted_dataset_resumes_to_the_same_bytes() {
    use surgvla::export::lerobot::VideoOptions;
    for video in [None, Some(VideoOptions::h264())] {
        // 25-frame episodes are over 1 MB: every episode completes a data file and a checkpoint.
        let recorded = episodes(4, 25);
        let options = LeRobotOptions {
            data_file_size_mb: 1,
            video,
            ..LeRobotOptions::default()
        };
        let (whole, interrupted) = (temp_root("whole"), temp_root("interrupted"));
        write(&whole, &recorded, options.clone());
        {
            let mut writer =
                LeRobotWriter::create(&interrupted, &info(false), options.clone()).expect("create");
            for episode in &recorded[..2] {
                writer
                    .write_batch(std::slice::from_ref(episode))
                    .expect("write");
            }
            // Killed here, plus a stray partial file from the episode in flight.
            std::fs::write(
                interrupted.join("data/chunk-000/.file-002.parquet.partial"),
                b"half",
            )
            .expect("stray");
        }
        assert!(
            LeRobotWriter::create(&interrupted, &info(false), options.clone()).is_err(),
            "not silently overwritten"
        );
        let mut writer =
            LeRobotWriter::resume(&interrupted, &info(false), options.clone()).expect("resume");
        // Image mode completes a 1 MB data file (and a checkpoint) per episode; in video mode the
        // parquet holds no RGB, so fewer checkpoints: resume from wherever the last one was.
        let next = writer.next_episode_index() as usize;
        if video.is_none() {
            assert_eq!(next, 2);
        }
        assert!(next <= 2);
        for episode in &recorded[next..] {
            writer
                .write_batch(std::slice::from_ref(episode))
                .expect("write");
        }
        writer.finish().expect("finish");
        let (a, b) = (crate::util::tree(&whole), crate::util::tree(&interrupted));
        assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
        for (file, bytes) in &a {
            assert!(b[file] == *bytes, "{file}");
        }
        // A complete dataset cannot be resumed.
        assert!(LeRobotWriter::resume(&whole, &info(false), options).is_err());
    }
}

/// Another tool's features (FeatureKind::Other: a 14-D float vector, a one-value int64, a
/// camera's encoded PNG, a float64 vector kept float64) and its per-episode values go through
/// the LeRobot writer and reader unchanged, in v3.0 and v2.1, images byte for byte; such a
/// dataset gets no surgvla metadata and validates.
#[test]
fn other_features_round_trip_unchanged() {
    use surgvla::episode::{Dtype, FeatureValue};
    let (mut dataset, mut episodes) = crate::util::foreign_dataset();
    let mut doubles = dataset.features[0].clone();
    (doubles.name, doubles.dtype, doubles.shape) =
        ("observation.joints".into(), Dtype::Float64, vec![3]);
    doubles.info.clear();
    dataset.features.push(doubles);
    for episode in &mut episodes {
        let index = episode.meta.index;
        for (k, step) in episode.steps.iter_mut().enumerate() {
            // Doubles no float32 holds.
            let value = 1.0 / 3.0 + (index * 10 + k as u64) as f64 * 1e-12;
            step.other
                .push(FeatureValue::Float64(vec![value, -value, value * 1e9]));
        }
        episode.meta.fields.insert(
            "episode_metadata/file_path".into(),
            format!("run_{index}.h5").into(),
        );
        episode
            .meta
            .fields
            .insert("episode_metadata/score".into(), (index as f64 / 4.0).into());
    }
    for version in [
        surgvla::export::lerobot::LeRobotVersion::V30,
        surgvla::export::lerobot::LeRobotVersion::V21,
    ] {
        let root = temp_root("other-features");
        let options = LeRobotOptions {
            version,
            ..LeRobotOptions::default()
        };
        let mut writer = LeRobotWriter::create(&root, &dataset, options).expect("writer");
        writer.write_batch(&episodes).expect("write");
        writer.finish().expect("finish");
        assert!(!root.join("meta/surgvla.json").exists());
        let mut source = surgvla::export::open_source(&root).expect("source");
        assert_eq!(source.info().features, dataset.features);
        for expected in &episodes {
            let read = source.next().expect("episode").expect("readable");
            assert_eq!(read.meta.instruction, expected.meta.instruction);
            let others: Vec<_> = read.steps.iter().map(|s| s.other.clone()).collect();
            let wanted: Vec<_> = expected.steps.iter().map(|s| s.other.clone()).collect();
            assert_eq!(others, wanted, "{version:?}");
            assert_eq!(read.meta.fields, expected.meta.fields, "{version:?}");
        }
        let declared: Vec<String> = (source.info().episode_fields.iter())
            .map(|f| f.key.clone())
            .collect();
        assert_eq!(
            declared,
            ["episode_metadata/file_path", "episode_metadata/score"]
        );
        assert!(source.next().is_none());
        let report = surgvla::export::validate::validate(&root, &Default::default()).expect("runs");
        assert!(report.valid, "{version:?}: {:#?}", report.errors);
        if version == surgvla::export::lerobot::LeRobotVersion::V30 {
            // Declared from the first row there is, behind an empty first file of the table.
            let table = root.join("meta/episodes/chunk-000");
            let (first, second) = (
                table.join("file-000.parquet"),
                table.join("file-001.parquet"),
            );
            std::fs::rename(&first, &second).expect("rename");
            let none = read_parquet(&second).expect("read")[0].slice(0, 0);
            let mut bytes = Vec::new();
            let mut writer = parquet::arrow::ArrowWriter::try_new(&mut bytes, none.schema(), None)
                .expect("writer");
            writer.write(&none).expect("write");
            writer.close().expect("close");
            std::fs::write(&first, bytes).expect("write");
            let source = surgvla::export::open_source(&root).expect("source");
            let keys: Vec<String> = (source.info().episode_fields.iter())
                .map(|f| f.key.clone())
                .collect();
            assert_eq!(keys, declared);
        }
    }
}

/// A video dataset's MP4 read back through the demuxer and decoded (issue 25's first slice),
/// H.264 and AV1: one picture per frame, at the dataset's size, near the frames that were
/// encoded (the codecs are lossy; decoding itself is exact, so the figure is stable).
#[test]
fn video_decodes_to_the_recorded_frames() {
    use surgvla::episode::VideoCodec;
    use surgvla::export::lerobot::VideoOptions;
    use surgvla::media::decode::{decode_av1, decode_h264, rgb_from_yuv420};
    use surgvla::media::demux::VideoReader;
    let recorded = episodes(2, 12);
    for (codec, video) in [
        (VideoCodec::H264, VideoOptions::h264()),
        (VideoCodec::Av1, VideoOptions::default()),
    ] {
        let root = temp_root("lerobot-decode");
        let options = LeRobotOptions {
            video: Some(video),
            ..LeRobotOptions::default()
        };
        write(&root, &recorded, options);
        let path = root.join("videos/observation.images.endoscope/chunk-000/file-000.mp4");
        let mut reader = VideoReader::open(&path).expect("mp4");
        assert_eq!(reader.codec, codec);
        let samples = reader.all().expect("samples");
        let pictures = match codec {
            VideoCodec::H264 => decode_h264(&samples, "file-000.mp4"),
            VideoCodec::Av1 => decode_av1(&samples, "file-000.mp4", 8192),
        }
        .expect("decode");
        let frames: Vec<&Vec<u8>> = recorded
            .iter()
            .flat_map(|e| e.steps.iter().map(|s| &s.rgb))
            .collect();
        assert_eq!(pictures.len(), frames.len(), "{codec:?}");
        for (i, (picture, rgb)) in pictures.iter().zip(frames).enumerate() {
            assert_eq!((picture.width_px, picture.height_px), (224, 224));
            let decoded = rgb_from_yuv420(picture).expect("planes");
            let mean = rgb
                .iter()
                .zip(&decoded)
                .map(|(a, b)| f64::from(a.abs_diff(*b)))
                .sum::<f64>()
                / rgb.len() as f64;
            assert!(mean < 3.0, "{codec:?} frame {i}: mean difference {mean}");
        }
    }
}

#[test]
fn a_reader_takes_the_episodes_table_a_batch_at_a_time_and_keeps_each_row_with_its_episode() {
    use surgvla::export::lerobot::{Codec, VideoOptions};
    let root = temp_root("rows-in-batches");
    // More episodes than one 64-row batch of the table; each row's seed and video span must
    // reach its own episode across the batch boundary.
    let recorded = episodes(70, 2);
    let options = LeRobotOptions {
        video: Some(VideoOptions {
            codec: Codec::H264,
            ..VideoOptions::default()
        }),
        ..LeRobotOptions::default()
    };
    write(&root, &recorded, options);
    let mut source = surgvla::export::open_source(&root).expect("source");
    for expected in &recorded {
        let read = source.next().expect("an episode").expect("readable");
        let meta = |e: &Episode| (e.meta.index, e.meta.seed, e.meta.attempts, e.meta.success);
        assert_eq!(meta(&read), meta(expected));
        let video = &read.encoded[0];
        assert!(
            video.shown.is_none(),
            "episode {}: its own span",
            read.meta.index
        );
        assert_eq!(video.frames.len(), expected.steps.len());
    }
    assert!(source.next().is_none());
}

/// `skim` reads the episodes table without its statistics columns; a whole episode asked for
/// after skimming, skipping or at a batch boundary still gets its row whole (its video's pixel
/// statistics among it): the same episodes as a reader that only ever took whole ones.
#[test]
fn episodes_taken_after_skimming_still_carry_their_statistics() {
    use surgvla::export::lerobot::{Codec, VideoOptions};
    let root = temp_root("skim-then-take");
    let options = LeRobotOptions {
        video: Some(VideoOptions {
            codec: Codec::H264,
            ..VideoOptions::default()
        }),
        ..LeRobotOptions::default()
    };
    write(&root, &episodes(70, 2), options);
    let whole: Vec<Episode> = surgvla::export::open_source(&root)
        .expect("source")
        .map(|e| e.expect("readable"))
        .collect();
    assert_eq!(whole.len(), 70);
    for episode in &whole {
        let videos: Vec<_> = (episode.encoded.iter())
            .filter(|e| matches!(e.encoding, surgvla::episode::ImageEncoding::Video(_)))
            .collect();
        assert!(
            !videos.is_empty() && videos.iter().all(|v| v.pixel_stats.is_some()),
            "a video's episodes carry its pixel statistics: {:?}",
            (episode.encoded.iter())
                .map(|e| (&e.feature, &e.encoding, e.pixel_stats.is_some()))
                .collect::<Vec<_>>()
        );
    }
    for (skimmed, skipped) in [(0, 0), (3, 0), (65, 0), (64, 2), (0, 69)] {
        let mut source = surgvla::export::open_source(&root).expect("source");
        for expected in &whole[..skimmed] {
            let skim = source.skim().expect("an episode").expect("skimmed");
            assert_eq!(skim.meta, expected.meta);
            assert_eq!(skim.steps, expected.steps.len() as u64);
        }
        for _ in 0..skipped {
            source.skip_episode().expect("an episode").expect("skipped");
        }
        for expected in &whole[skimmed + skipped..] {
            let read = source.next().expect("an episode").expect("readable");
            // (Not assert_eq: an episode's Debug is megabytes.)
            assert!(
                &read == expected,
                "skimmed {skimmed}, skipped {skipped}: episode {} differs",
                expected.meta.index
            );
        }
        assert!(source.next().is_none());
    }
}

#[test]
fn a_manifest_made_stale_by_another_tools_rewrite_is_a_warning_and_damage_stays_an_error() {
    let root = temp_root("stale-manifest");
    let mut writer =
        LeRobotWriter::create(&root, &info(false), LeRobotOptions::default()).expect("create");
    writer.write_batch(&episodes(2, 3)).expect("write");
    writer.finish().expect("finish");
    let options = surgvla::export::validate::ValidateOptions::default();
    let validate = || surgvla::export::validate::validate(&root, &options).expect("validate");
    // Another tool rewrites the metadata (lerobot-edit-dataset's modify_tasks edits in place).
    let info_path = root.join("meta/info.json");
    let info_json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&info_path).expect("read")).expect("json");
    std::fs::write(&info_path, serde_json::to_vec(&info_json).expect("json")).expect("write");
    let report = validate();
    assert!(report.valid, "{:?}", report.errors);
    assert!(
        (report.warnings.iter()).any(|w| w.check == "manifest" && w.message.contains("stale")),
        "{:?}",
        report.warnings
    );
    // Without the metadata rewritten, a changed file is damage.
    let mut writer = {
        std::fs::remove_dir_all(&root).ok();
        LeRobotWriter::create(&root, &info(false), LeRobotOptions::default()).expect("create")
    };
    writer.write_batch(&episodes(2, 3)).expect("write");
    writer.finish().expect("finish");
    let stats = root.join("meta/stats.json");
    let mut bytes = std::fs::read(&stats).expect("read");
    bytes.push(b' ');
    std::fs::write(&stats, bytes).expect("write");
    let report = validate();
    assert!(!report.valid);
    assert!(
        report.errors.iter().any(|e| e.check == "checksum"),
        "{:?}",
        report.errors
    );
}
