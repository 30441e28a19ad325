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
//! `export/decode/{av1,h264}`: demuxing, decoding and converting to RGB every frame of the
//! same episodes' 224 x 224 video, one thread (`scripts/bench_decode.sh` sets PyAV beside it).
//!
//! `export/frame/{png_adaptive,png_paeth,png_surgvla,stats_rgb,stats_rgb_since,stats_depth,stats_depth_since}`:
//! one recorded frame's RGB PNG with either filter choice at the fast level (the `png` crate)
//! and through surgvla's own fast path (the same bytes as `png_paeth`), and its RGB and depth
//! statistics, one core; `stats_{rgb,depth}_since` take the frame and the next one in turn, each
//! after the other (what `collect` does frame after frame: pixels counted only where changed).
//!
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

/// The MP4 files `export/decode` decodes: the eight episodes' RGB camera as LeRobot video
/// (AV1 by rav1e, H.264 by openh264), kept in the bench's target folder so that
/// `scripts/bench_decode.sh` times PyAV (and torchcodec) on the same files.
fn decode_inputs() -> Vec<(&'static str, std::path::PathBuf, usize)> {
    let (episodes, info) = episodes();
    let frames: usize = episodes.iter().map(|e| e.steps.len()).sum();
    let base = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("bench-video");
    [
        ("av1", VideoOptions::default()),
        ("h264", VideoOptions::h264()),
    ]
    .into_iter()
    .map(|(name, video)| {
        let root = base.join(name);
        std::fs::remove_dir_all(&root).ok();
        let options = LeRobotOptions {
            video: Some(video),
            ..LeRobotOptions::default()
        };
        let mut writer = LeRobotWriter::create(&root, &info, options).expect("create");
        writer.write_batch(&episodes).expect("write");
        writer.finish().expect("finish");
        let mp4 = root.join("videos/observation.images.endoscope/chunk-000/file-000.mp4");
        (name, mp4, frames)
    })
    .collect()
}

/// `export/decode/{av1,h264}`: every frame of a 224 x 224 MP4 demuxed, decoded and converted
/// to RGB, on one thread. Throughput is in frames.
fn bench_decode(c: &mut Criterion) {
    use surgvla::media::decode::{MAX_DECODED_SIDE_PX, decode_span_each, rgb_from_yuv420};
    use surgvla::media::demux::VideoReader;
    let mut group = c.benchmark_group("export/decode");
    group.sample_size(10);
    for (name, mp4, frames) in decode_inputs() {
        group.throughput(Throughput::Elements(frames as u64));
        group.bench_function(name, |b| {
            b.iter(|| {
                let mut reader = VideoReader::open(&mp4).expect("open");
                let span = reader
                    .decodable(f64::NEG_INFINITY, f64::INFINITY)
                    .expect("span");
                let mut bytes = 0usize;
                let count = decode_span_each::<surgvla::media::MediaError>(
                    reader.codec,
                    &span.samples,
                    "bench",
                    MAX_DECODED_SIDE_PX,
                    &mut |picture| {
                        bytes += rgb_from_yuv420(&picture).expect("planes").len();
                        Ok(())
                    },
                )
                .expect("decode");
                assert_eq!((count, bytes), (frames, frames * 224 * 224 * 3));
            })
        });
    }
    group.finish();
}

/// One recorded frame's per-frame encoding work, one core (issue 27's levers): the RGB PNG at
/// the fast level with the adaptive filter choice and with Paeth on every row (what surgvla
/// writes), and the image statistics of the RGB and the depth.
fn bench_frame_work(c: &mut Criterion) {
    let (episodes, _) = episodes();
    let step = &episodes[0].steps[episodes[0].steps.len() / 2];
    let mut group = c.benchmark_group("export/frame");
    group.throughput(Throughput::Elements(1));
    for (name, filter) in [
        ("png_adaptive", png::Filter::Adaptive),
        ("png_paeth", png::Filter::Paeth),
    ] {
        group.bench_function(name, |b| {
            b.iter(|| {
                let mut out = Vec::new();
                let mut encoder = png::Encoder::new(&mut out, 224, 224);
                encoder.set_color(png::ColorType::Rgb);
                encoder.set_depth(png::BitDepth::Eight);
                encoder.set_compression(png::Compression::Fast);
                encoder.set_filter(filter);
                let mut writer = encoder.write_header().expect("header");
                writer.write_image_data(&step.rgb).expect("png");
                writer.finish().expect("finish");
                out.len()
            })
        });
    }
    group.bench_function("png_surgvla", |b| {
        b.iter(|| {
            surgvla::files::encode_png(
                224,
                224,
                surgvla::files::PngPixels::Rgb8,
                &step.rgb,
                surgvla::files::PngLevel::Fast,
            )
            .expect("png")
        })
    });
    group.bench_function("stats_rgb", |b| {
        b.iter(|| {
            let mut stats = surgvla::export::stats::ImageStats::unit_scaled(3);
            stats.push_u8(&step.rgb);
            stats
        })
    });
    group.bench_function("stats_rgb_since", |b| {
        let next = &episodes[0].steps[episodes[0].steps.len() / 2 + 1];
        let mut stats = surgvla::export::stats::ImageStats::unit_scaled(3);
        let mut counts = stats.empty_histograms();
        let mut last = surgvla::export::stats::LastFrame::default();
        let mut frames = [&step.rgb, &next.rgb].into_iter().cycle();
        b.iter(|| {
            let mut part = stats.without_histograms();
            part.push_u8_counting_since(frames.next().expect("cycles"), &mut counts, &mut last);
            stats.merge(&part);
        })
    });
    group.bench_function("stats_depth_since", |b| {
        let next = &episodes[0].steps[episodes[0].steps.len() / 2 + 1];
        let mut stats = surgvla::export::stats::ImageStats::depth();
        let mut counts = stats.empty_histograms();
        let mut last = surgvla::export::stats::LastFrame::default();
        let mut frames = [&step.depth_m, &next.depth_m].into_iter().cycle();
        b.iter(|| {
            let mut part = stats.without_histograms();
            let frame = frames.next().expect("cycles");
            part.push_depth_counting_since(frame, &mut counts, &mut last);
            stats.merge(&part);
        })
    });
    group.bench_function("stats_depth", |b| {
        let mut stats = surgvla::export::stats::ImageStats::depth();
        let mut counts = stats.empty_histograms();
        b.iter(|| {
            let mut part = stats.without_histograms();
            part.push_depth_counting(&step.depth_m, &mut counts);
            stats.merge(&part);
        })
    });
    group.finish();
}

criterion_group!(
    benches,
    bench_lerobot,
    bench_rlds,
    bench_pointcloud,
    bench_decode,
    bench_frame_work
);
criterion_main!(benches);
