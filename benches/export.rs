//! Criterion benches of the exporters.
//!
//! `export/lerobot/video_{av1,h264}/{1,2}_threads`: the same with the RGB camera as AV1 or H.264
//! MP4.
//! `export/lerobot/image/{1,2}_threads`: writing 224 x 224 episodes (RGB PNG + float depth TIFF,
//! state, action, object poses) into a LeRobot v3.0 dataset in image mode, on a rayon pool of one
//! and of two threads. Throughput is in frames. The episodes are recorded once beforehand, so
//! simulation and rendering are not measured.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use surgvla::collect::record::{RecordOptions, episode_seed, record_episode};
use surgvla::collect::run::{CollectOptions, dataset_info};
use surgvla::episode::FeatureSet;
use surgvla::export::EpisodeSink;
use surgvla::export::lerobot::{LeRobotOptions, LeRobotWriter, VideoOptions};
use surgvla::policy::ExpertLibrary;
use surgvla::task::TaskId;

fn bench_lerobot(c: &mut Criterion) {
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
    let frames: usize = episodes.iter().map(|e| e.steps.len()).sum();
    let info = dataset_info(
        &CollectOptions::default(),
        FeatureSet::default(),
        &surgvla::policy::ExpertLibrary::builtin().expect("plans"),
    );
    for (mode, video) in [
        ("image", None),
        ("video_av1", Some(VideoOptions::default())),
        ("video_h264", Some(VideoOptions::h264())),
    ] {
        let mut group = c.benchmark_group(format!("export/lerobot/{mode}"));
        group.throughput(Throughput::Elements(frames as u64));
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
                    pool.install(|| {
                        let mut writer = LeRobotWriter::create(
                            &root,
                            &info,
                            LeRobotOptions {
                                video,
                                ..LeRobotOptions::default()
                            },
                        )
                        .expect("create");
                        writer.write_batch(&episodes).expect("write");
                        writer.finish().expect("finish")
                    })
                })
            });
            std::fs::remove_dir_all(&root).ok();
        }
        group.finish();
    }
}

criterion_group!(benches, bench_lerobot);
criterion_main!(benches);
