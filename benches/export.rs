//! Criterion benches of the exporters.
//!
//! `export/pointcloud/frame_{1024,512}`: one recorded 224 x 224 frame (T1-1, mid-episode) to a
//! cloud of 1024 or 512 points (back-projection, crop to the workspace with 20 mm margins, 3 mm
//! voxel grid, farthest point sampling), one core.
//!
//! `export/rlds/{1,2}_threads`: the same episodes into RLDS (RGB PNG + uint16 depth PNG at the
//! fast PNG level, state, action, object poses; TFRecord framing and CRCs). Throughput is in
//! steps.
//!
//! `export/lerobot/video_{av1,h264}/{1,2}_threads`: the same with the RGB camera as AV1 or H.264
//! MP4.
//! `export/lerobot/image/{1,2}_threads`: writing 224 x 224 episodes (RGB PNG + float depth TIFF,
//! state, action, object poses) into a LeRobot v3.0 dataset in image mode, on a rayon pool of one
//! and of two threads. Throughput is in frames. The episodes are recorded once beforehand, so
//! simulation and rendering are not measured.

// Tests and benches fail by unwrapping, expecting and panicking (denied in the library).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use surgvla::collect::record::{RecordOptions, episode_seed, record_episode};
use surgvla::collect::run::{CollectOptions, dataset_info};
use surgvla::episode::{Episode, FeatureSet};
use surgvla::export::lerobot::{LeRobotOptions, LeRobotWriter, VideoOptions};
use surgvla::export::rlds::{RldsOptions, RldsWriter};
use surgvla::export::{DatasetInfo, EpisodeSink};
use surgvla::policy::ExpertLibrary;
use surgvla::task::TaskId;

/// Eight recorded episodes (one per task, 25 steps each) and their dataset info.
fn episodes() -> (Vec<Episode>, DatasetInfo) {
    let options = RecordOptions {
        max_steps: Some(25),
        ..RecordOptions::default()
    };
    let library = ExpertLibrary::builtin().expect("built-in plans");
    let episodes: Vec<_> = (0..8u64)
        .map(|i| {
            let task = TaskId::ALL[i as usize];
            record_episode(&library, task, episode_seed(1, task, i), i, &options).expect("record")
        })
        .collect();
    let info = dataset_info(&CollectOptions::default(), FeatureSet::default(), &library);
    (episodes, info)
}

/// Times `write` (which makes a dataset in the folder it is given) on rayon pools of one and of
/// two threads.
fn on_pools(
    c: &mut Criterion,
    group: &str,
    steps: usize,
    write: impl Fn(&std::path::Path) -> surgvla::export::Summary + Sync,
) {
    let mut group = c.benchmark_group(group);
    group.throughput(Throughput::Elements(steps as u64));
    group.sample_size(10);
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        let root = std::env::temp_dir().join(format!(
            "surgvla-bench-export-{}-{threads}",
            std::process::id()
        ));
        group.bench_function(format!("{threads}_threads"), |b| {
            b.iter(|| {
                std::fs::remove_dir_all(&root).ok();
                pool.install(|| write(&root))
            })
        });
        std::fs::remove_dir_all(&root).ok();
    }
    group.finish();
}

fn bench_rlds(c: &mut Criterion) {
    let (episodes, info) = episodes();
    let steps: usize = episodes.iter().map(|e| e.steps.len()).sum();
    on_pools(c, "export/rlds", steps, |root| {
        let mut writer = RldsWriter::create(root, &info, RldsOptions::default()).expect("create");
        writer.write_batch(&episodes).expect("write");
        writer.finish().expect("finish")
    });
}

fn bench_pointcloud(c: &mut Criterion) {
    use surgvla::export::pointcloud::{Aabb, CloudOptions, frame_cloud};
    let (episodes, info) = episodes();
    let episode = &episodes[0];
    let step = &episode.steps[episode.steps.len() / 2];
    let workspace = surgvla::sim::control::Workspace::reference();
    let crop = Aabb {
        min_m: workspace.min_m,
        max_m: workspace.max_m,
    }
    .grown(0.02);
    let mut group = c.benchmark_group("export/pointcloud");
    for points in [1024, 512] {
        let options = CloudOptions {
            points,
            ..CloudOptions::new(crop)
        };
        let cloud = frame_cloud(&info.camera, step, &options);
        assert!(
            cloud.valid == points,
            "a full cloud: {} points",
            cloud.valid
        );
        group.bench_function(format!("frame_{points}"), |b| {
            b.iter(|| frame_cloud(&info.camera, step, &options))
        });
    }
    group.finish();
}

fn bench_lerobot(c: &mut Criterion) {
    let (episodes, info) = episodes();
    let frames: usize = episodes.iter().map(|e| e.steps.len()).sum();
    for (mode, video) in [
        ("image", None),
        ("video_av1", Some(VideoOptions::default())),
        ("video_h264", Some(VideoOptions::h264())),
    ] {
        on_pools(c, &format!("export/lerobot/{mode}"), frames, |root| {
            let mut writer = LeRobotWriter::create(
                root,
                &info,
                LeRobotOptions {
                    video,
                    ..LeRobotOptions::default()
                },
            )
            .expect("create");
            writer.write_batch(&episodes).expect("write");
            writer.finish().expect("finish")
        });
    }
}

criterion_group!(benches, bench_lerobot, bench_rlds, bench_pointcloud);
criterion_main!(benches);
