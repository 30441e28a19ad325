//! The sink contract: what every format's `EpisodeSink` (and `EpisodeSource`) must do, run for
//! each format through `open_sink` / `open_source`. A new format adds its options to `formats()`.

use crate::util::{info, temp_root, tree};
use std::path::Path;
use surgvla::collect::record::{RecordOptions, episode_seed, record_episode};
use surgvla::episode::Episode;
use surgvla::export::lerobot::{LeRobotOptions, LeRobotVersion};
use surgvla::export::mcap::McapOptions;
use surgvla::export::pointcloud::files::CloudFileFormat;
use surgvla::export::pointcloud::{CloudFileOptions, CloudSettings};
use surgvla::export::rlds::RldsOptions;
use surgvla::export::rlds::record::depth_to_mm;
use surgvla::export::zarr::ZarrOptions;
use surgvla::export::{BUILTIN_FORMATS, DatasetInfo, SinkOptions, open_sink, open_source};
use surgvla::policy::ExpertLibrary;
use surgvla::task::TaskId;

/// A format under test.
struct Format {
    name: &'static str,
    options: Box<dyn SinkOptions>,
    /// A folder the format owns, where a stray file of an interrupted run is left.
    data_folder: &'static str,
    /// Depth is stored in whole millimetres (RLDS), not as float metres.
    depth_in_mm: bool,
    /// The format has an `EpisodeSource` (point clouds and zarr are written only).
    readable: bool,
}

/// Every format, with options that make files roll and checkpoint often.
fn formats() -> Vec<Format> {
    vec![
        Format {
            name: "lerobot-3.0",
            options: Box::new(LeRobotOptions {
                data_file_size_mb: 1,
                ..LeRobotOptions::default()
            }),
            data_folder: "data",
            depth_in_mm: false,
            readable: true,
        },
        Format {
            name: "lerobot-2.1",
            options: Box::new(LeRobotOptions {
                version: LeRobotVersion::V21,
                ..LeRobotOptions::default()
            }),
            data_folder: "data",
            depth_in_mm: false,
            readable: true,
        },
        Format {
            name: "rlds",
            options: Box::new(RldsOptions {
                shard_size_mb: 1,
                ..RldsOptions::default()
            }),
            data_folder: "surgvla_benchmark/1.0.0",
            depth_in_mm: true,
            readable: true,
        },
        Format {
            name: "zarr",
            options: Box::new(ZarrOptions {
                images: true,
                mask_channel: true,
                ..ZarrOptions::default()
            }),
            data_folder: "data/img",
            depth_in_mm: false,
            readable: false,
        },
        Format {
            name: "mcap",
            options: Box::new(McapOptions::default()),
            data_folder: "",
            depth_in_mm: false,
            readable: false,
        },
        Format {
            name: "ply",
            options: Box::new(CloudFileOptions {
                format: CloudFileFormat::Ply,
                settings: CloudSettings::default(),
            }),
            data_folder: "episode_000003",
            depth_in_mm: false,
            readable: false,
        },
        Format {
            name: "pcd",
            options: Box::new(CloudFileOptions {
                format: CloudFileFormat::Pcd,
                settings: CloudSettings::default(),
            }),
            data_folder: "episode_000003",
            depth_in_mm: false,
            readable: false,
        },
    ]
}

#[test]
fn the_contract_runs_every_registered_format() {
    // A format registered without an entry in `formats()` fails here, and so does an entry
    // whose options write another format than its name says.
    let under_test = formats();
    for format in BUILTIN_FORMATS {
        assert!(
            under_test.iter().any(|f| f.options.format() == *format),
            "{} is registered but not in the sink contract's formats()",
            format.name()
        );
    }
    for format in &under_test {
        assert!(
            format.name.starts_with(format.options.format().name()),
            "{} writes {}",
            format.name,
            format.options.format().name()
        );
        assert_eq!(
            format.readable,
            format.options.format().capabilities().reads,
            "{}",
            format.name
        );
    }
}

fn episodes(count: u64) -> Vec<Episode> {
    let options = RecordOptions {
        max_steps: Some(25),
        ..RecordOptions::default()
    };
    let library = ExpertLibrary::builtin().expect("plans");
    let tasks = [TaskId::NeedlePick, TaskId::VesselClipping];
    (0..count)
        .map(|i| {
            let task = tasks[i as usize % 2];
            let mut episode = record_episode(&library, task, episode_seed(4, task, i), i, &options)
                .expect("record");
            episode.meta.attempts = 1 + i as u32;
            episode
        })
        .collect()
}

fn write_all(root: &Path, info: &DatasetInfo, options: &dyn SinkOptions, episodes: &[Episode]) {
    let mut sink = open_sink(root, info, options, false).expect("open");
    sink.write_batch(episodes).expect("write");
    let summary = sink.finish().expect("finish");
    assert_eq!(summary.episodes, episodes.len() as u64);
    assert_eq!(
        sink.finish().expect("finish twice"),
        summary,
        "finish is safe twice"
    );
}

#[test]
fn every_sink_keeps_the_contract() {
    let recorded = episodes(4);
    let info = info(true);
    for format in formats() {
        let (name, options) = (format.name, format.options.as_ref());
        // Episodes out of order and episodes that do not match the features are rejected.
        let bad = temp_root("contract-bad");
        let mut sink = open_sink(&bad, &info, options, false).expect("open");
        let error = sink
            .write_batch(std::slice::from_ref(&recorded[1]))
            .expect_err("out of order");
        assert!(
            error.to_string().contains("episode index 1"),
            "{name}: {error}"
        );
        let mut broken = recorded[0].clone();
        broken.steps[2].mask.clear();
        assert!(
            sink.write_batch(std::slice::from_ref(&broken)).is_err(),
            "{name}: a step without its mask"
        );

        // One thread and two threads write the same bytes.
        let mut trees = Vec::new();
        for threads in [1, 2] {
            let root = temp_root("contract-threads");
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| write_all(&root, &info, options, &recorded));
            trees.push(tree(&root));
        }
        assert!(trees[0] == trees[1], "{name}: 1 and 2 threads differ");

        // Interrupted after two episodes (a stray partial file in flight), resumed: the same bytes.
        let interrupted = temp_root("contract-resume");
        {
            let mut sink = open_sink(&interrupted, &info, options, false).expect("open");
            sink.write_batch(&recorded[..2]).expect("write");
            let folder = interrupted.join(format.data_folder);
            std::fs::create_dir_all(&folder).expect("data");
            std::fs::write(folder.join(".stray.partial"), b"half").expect("stray");
        }
        assert!(
            open_sink(&interrupted, &info, options, false).is_err(),
            "{name}: not overwritten"
        );
        let mut sink = open_sink(&interrupted, &info, options, true).expect("resume");
        let next = sink.next_episode_index() as usize;
        assert!(next <= 2, "{name}");
        sink.write_batch(&recorded[next..]).expect("write rest");
        sink.finish().expect("finish");
        assert!(
            tree(&interrupted) == trees[0],
            "{name}: resumed differs from uninterrupted"
        );

        if !format.readable {
            continue;
        }
        // The source reads back the same episodes, provenance included.
        let mut source = open_source(&interrupted).expect("source");
        assert_eq!(source.len(), 4, "{name}");
        assert_eq!(source.info().features, info.features, "{name}");
        assert_eq!(source.info().camera, info.camera, "{name}");
        assert_eq!(source.info().collection, info.collection, "{name}");
        for expected in &recorded {
            let read = source.next().expect("an episode").expect("readable");
            assert_eq!(read.meta.index, expected.meta.index, "{name}");
            assert_eq!(read.meta.instruction, expected.meta.instruction, "{name}");
            assert_eq!(
                (
                    read.meta.seed,
                    &read.meta.task_code,
                    read.meta.level,
                    read.meta.attempts,
                    read.meta.success
                ),
                (
                    expected.meta.seed,
                    &expected.meta.task_code,
                    expected.meta.level,
                    expected.meta.attempts,
                    expected.meta.success
                ),
                "{name}"
            );
            assert_eq!(read.steps.len(), expected.steps.len(), "{name}");
            for (a, b) in read.steps.iter().zip(&expected.steps) {
                assert!(a.rgb == b.rgb && a.mask == b.mask, "{name}: images");
                if format.depth_in_mm {
                    let mm: Vec<f32> = b
                        .depth_m
                        .iter()
                        .map(|&d| f32::from(depth_to_mm(d)) / 1000.0)
                        .collect();
                    assert_eq!(a.depth_m, mm, "{name}: depth");
                } else {
                    assert_eq!(a.depth_m, b.depth_m, "{name}: depth");
                }
                assert_eq!((a.state, a.action), (b.state, b.action), "{name}");
                assert_eq!(a.environment_state, b.environment_state, "{name}");
            }
        }
        assert!(
            source.next().is_none(),
            "{name}: nothing after the last episode"
        );
    }
}

#[test]
fn a_source_refuses_an_incomplete_dataset_by_name() {
    let root = temp_root("contract-incomplete");
    let options = formats().remove(0).options;
    let mut sink = open_sink(&root, &info(false), options.as_ref(), false).expect("open");
    sink.write_batch(&episodes(1)).expect("write");
    let error = open_source(&root).err().expect("no info.json yet");
    let message = error.to_string();
    assert!(
        message.contains(&root.display().to_string()) && message.contains("info.json"),
        "{message}"
    );
}

/// zarr's partial chunks are rewritten when they fill, after the checkpoint that recorded them:
/// a kill right after the first checkpoint, in the middle of the next chunk, and while
/// finishing each resumes to the uninterrupted bytes.
#[test]
fn zarr_resumes_after_a_kill_at_each_point() {
    use surgvla::export::zarr::CHECKPOINT_EPISODES;
    let info = info(true);
    let options = Box::new(ZarrOptions {
        images: true,
        ..ZarrOptions::default()
    });
    // Short episodes (25 steps): 16 of them end a checkpoint mid-chunk (400 rows: chunk 4 is
    // empty, so one more row group of 25 makes a partial chunk rewritten by the next episodes).
    let one = episodes(1).remove(0);
    let count = CHECKPOINT_EPISODES as usize + 6;
    let recorded: Vec<Episode> = (0..count)
        .map(|i| {
            let mut episode = one.clone();
            episode.meta.index = i as u64;
            episode.steps.truncate(21 + i % 4);
            episode
        })
        .collect();
    let reference = temp_root("zarr-reference");
    write_all(&reference, &info, options.as_ref(), &recorded);
    let expected = tree(&reference);
    let checkpoint = CHECKPOINT_EPISODES as usize;
    // (episodes written before the kill, whether the kill came during finish)
    for (written, finishing) in [
        (checkpoint, false),
        (checkpoint + 3, false),
        (checkpoint + 5, false),
        (count, true),
    ] {
        let root = temp_root("zarr-killed");
        {
            let mut sink = open_sink(&root, &info, options.as_ref(), false).expect("open");
            for episode in &recorded[..written] {
                sink.write_batch(std::slice::from_ref(episode))
                    .expect("write");
            }
            if finishing {
                // Killed just before the marker goes: the finish's files are written, the
                // marker (with its checkpoint) and the journals it names are still there.
                let hidden: Vec<(std::path::PathBuf, Vec<u8>)> = std::fs::read_dir(&*root)
                    .expect("dir")
                    .flatten()
                    .map(|e| e.path())
                    .filter(|p| {
                        p.file_name()
                            .is_some_and(|n| n.to_string_lossy().starts_with('.'))
                    })
                    .filter(|p| p.is_file())
                    .map(|p| {
                        let bytes = std::fs::read(&p).expect("hidden file");
                        (p, bytes)
                    })
                    .collect();
                sink.finish().expect("finish");
                for (path, bytes) in hidden {
                    std::fs::write(&path, bytes).expect("put back");
                }
            }
        }
        let mut sink = open_sink(&root, &info, options.as_ref(), true)
            .unwrap_or_else(|e| panic!("resume after {written} episodes: {e}"));
        let next = sink.next_episode_index() as usize;
        assert!(next <= written, "{written}: resumes at {next}");
        for episode in &recorded[next..] {
            sink.write_batch(std::slice::from_ref(episode))
                .expect("write rest");
        }
        sink.finish().expect("finish");
        assert!(
            tree(&root) == expected,
            "killed after {written} episodes (finishing: {finishing}): resumed differs"
        );
    }
}
